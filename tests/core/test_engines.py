"""The engines' contract without a cluster: the local pool, the driver's file writes and
the checks a Ray worker's report goes through (tests/core/test_cluster.py runs Ray)."""

import pickle

import pytest

from core.engines import Produced, environment, map_local, store
from core.engines.cluster import _refusal
from manifests import Workspace
from manifests.workspace import PathEscapeError


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


class Refaults:
    """A worker's page faults on a frame allocated a second time, once freed; and whether
    this process's C library takes ``keep_freed_memory``'s values (asked after measuring)."""

    def work(self, _: int) -> tuple[int, bool]:
        import resource

        import numpy as np

        def faults() -> int:
            before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            frame = np.ones(64 << 18, np.float32)  # 64 MB, every page written, as a render's frame
            del frame
            return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

        faults()
        again = faults()
        from core.engines import keep_freed_memory

        return again, keep_freed_memory()


def test_a_worker_reuses_the_frames_it_frees():
    """Issue 60: a render's 9-100 MB frames were each a fresh mapping whose pages all faulted
    in again (2,300-4,600 faults a twin at 1920 x 1200, a tenth of its time). A local worker
    is set up to reuse them (``prepare_worker``: ``keep_freed_memory``), as Ray's actors are:
    the second frame faults in no page. A fresh 64 MB mapping takes at least 32 faults, even
    in 2 MB huge pages."""
    for again, taken in map_local(Refaults, (), "work", [0, 1], workers=2, max_tasks=5):
        assert taken and again < 32, again
