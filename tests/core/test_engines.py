"""The engines' contract without a cluster: the local pool, the driver's file writes and
the checks a Ray worker's report goes through (tests/core/test_cluster.py runs Ray)."""

import pickle
import subprocess
import sys
from pathlib import Path

import pytest

from core.engines import Produced, environment, map_local, store
from core.engines.cluster import _refusal
from manifests import Workspace
from manifests.workspace import PathEscapeError

REPOSITORY = Path(__file__).resolve().parents[2]


class Squares:
    """A worker context: squares numbers and 'writes' one file per item."""

    def __init__(self, offset: int) -> None:
        self.offset = offset

    def work(self, item: int) -> Produced:
        return Produced({"item": item, "value": item * item + self.offset}, {f"out/{item}.txt": str(item).encode()})


def test_every_item_once_whatever_the_workers(tmp_path):
    for workers in (1, 2):
        got = sorted(p.value["value"] for p in map_local(Squares, (1,), "work", list(range(7)), workers=workers,
                                                         max_tasks=2))
        assert got == [i * i + 1 for i in range(7)]


def test_prepare_runs_in_the_driver_before_each_item_is_sent():
    sent = []

    def prepare(item: int) -> int:
        sent.append(item)
        return item + 10

    got = sorted(p.value["item"] for p in map_local(Squares, (0,), "work", [1, 2, 3], workers=2, max_tasks=10,
                                                    prepare=prepare))
    assert got == [11, 12, 13] and sorted(sent) == [1, 2, 3]


def test_the_driver_writes_the_files_inside_the_workspace_only(tmp_path):
    ws = Workspace(tmp_path / "w")
    value = store(ws, Produced({"a": 1}, {"images/x.png": b"png"}))
    assert value == {"a": 1} and (ws.root / "images" / "x.png").read_bytes() == b"png"
    with pytest.raises(PathEscapeError):
        store(ws, Produced({}, {"../outside.png": b"no"}))
    assert not (tmp_path / "outside.png").exists()


def test_a_worker_with_another_variant_or_versions_is_refused():
    expected = {**environment(), "mitsuba_variant": "llvm_ad_rgb"}
    report = {**expected, "host": "node7", "node": "abc123"}
    assert _refusal(report, expected) is None
    message = _refusal({**report, "mitsuba_variant": "scalar_rgb", "numpy": "1.0"}, expected)
    assert "node7" in message and "scalar_rgb" in message and "numpy '1.0'" in message and "libllvm19" in message


def test_errors_cross_process_boundaries_with_their_message():
    from manifests import ManifestError
    from speedplus.errors import FileError

    for error in (ManifestError("a.parquet", "bad", row=2, column="q"), FileError("images/x.png", "truncated")):
        again = pickle.loads(pickle.dumps(error))
        assert type(again) is type(error) and str(again) == str(error)


class BlasThreads:
    """A worker context that reports its BLAS libraries' thread counts."""

    def work(self, item: int) -> list[int]:
        import scipy.linalg  # noqa: F401 - SciPy's own OpenBLAS, loaded after the limit was set
        from threadpoolctl import threadpool_info

        return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_blas_runs_on_one_thread_in_every_worker_and_the_driver():
    """Issue 42: the arms' fit spun a BLAS thread per core in every process; beside another
    job, calibrate took 141 s instead of 10.6 s (``python -m bench threads``). One thread,
    not a share of the cores: OpenBLAS's sums then give the same bytes whatever the workers."""
    from core.engines import single_threaded_blas

    for item in map_local(BlasThreads, (), "work", [0, 1, 2], workers=2, max_tasks=5):
        assert len(item) >= 2 and set(item) == {1}  # NumPy's and SciPy's
    single_threaded_blas()
    assert set(BlasThreads().work(0)) == {1}


_REFAULTS = r"""
import resource, sys
import numpy as np
from core.engines import keep_freed_memory

def faults(megabytes):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    frame = np.ones(megabytes << 18, np.float32)  # every page written, as a render's frame
    del frame
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

kept = sys.argv[1] == "keep" and keep_freed_memory()
first, again = faults(64), faults(64)
print(kept, first, again)
"""


@pytest.mark.parametrize("policy", ["keep", "default"])
def test_a_process_reuses_the_frames_it_frees(policy):
    """Issue 60: a render's 9-100 MB frames were each a fresh mapping whose pages all faulted
    in again (4,270-4,590 faults a twin at 1920 x 1200, 10% of its time);
    ``keep_freed_memory`` (``prepare_process``: the driver, local workers and Ray actors)
    lets the next frame reuse the pages. Beside it, the C library's default, which the
    measure must tell apart. A process of its own: the setting holds for the whole process."""
    result = subprocess.run([sys.executable, "-c", _REFAULTS, policy], capture_output=True, text=True,
                            cwd=REPOSITORY, check=True)
    kept, first, again = result.stdout.split()
    assert int(first) > 0
    if policy == "keep":
        assert kept == "True" and int(again) <= int(first) // 4, result.stdout
    else:
        assert int(again) >= int(first) // 2, result.stdout
