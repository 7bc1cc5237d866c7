"""Execution engines: map a per-sample method over samples, in this process, in spawned
local processes (``local``) or on a Ray cluster (``cluster``) (docs/architecture.md section 10).

Workers never touch the workspace. A per-sample call returns ``Produced``: the value for
the driver (a manifest row, a record) and the bytes of the files it made, by workspace
path. The driver writes them (``store``) before the row, each atomically, so any cluster
works without a shared filesystem, an interrupted stage never leaves a row without its
files, and the bytes do not depend on the engine, the worker count or the finishing order.
When the workspace lives on object storage, Ray workers upload their files themselves
(``upload``) and return their sizes and hashes, which the driver checks (``store``).
"""

from __future__ import annotations

import dataclasses
import os
import platform
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any, Literal

from core.engines.local import map_local
from manifests import Workspace
from manifests.files import write_bytes_atomic
from manifests.remote import Remote
from manifests.store import StoredFile
from speedplus.errors import InputError

#: set in a Ray worker to the CPUs Ray reserved for it: its renderer uses that many threads
WORKER_CPUS_ENV = "SPEEDPLUS_WORKER_CPUS"

#: distributions whose versions decide the bytes a worker makes: every worker must match the
#: driver (this repository's own code ships with the job)
PINNED_DISTRIBUTIONS = ("mitsuba", "drjit", "numpy", "opencv-contrib-python-headless",
                        "onnxruntime", "OpenImageIO")

__all__ = ["EngineError", "Produced", "environment", "map_engine", "map_local", "reserved_cpus", "store",
           "threads_per_worker", "upload"]


class EngineError(InputError):
    """The cluster cannot run the stage (unreachable, no free CPU, a worker that would make
    other bytes, a sample that keeps killing its worker); exit code 1, with what to do."""


@dataclass(frozen=True)
class Produced:
    """What one per-sample call returns: ``value`` for the driver and ``files`` it made
    (workspace-relative path -> bytes), which the driver writes."""

    value: Any
    files: dict[str, bytes | StoredFile] = field(default_factory=dict)


def store(workspace: Workspace, produced: Produced) -> Any:
    """Write ``produced``'s files into the workspace (each atomically; a path that would
    leave it is refused), or check those a worker uploaded to the workspace's store, and
    return its value, which may then be recorded."""
    for relpath, data in produced.files.items():
        if isinstance(data, StoredFile):
            workspace.store.accept(relpath, data)
        else:
            write_bytes_atomic(workspace.resolve(relpath), data)
    return produced.value


def upload(result: Any, remote: Remote) -> Any:
    """``result`` (a dataclass with ``files``: path -> bytes) with its files uploaded to
    ``remote`` and replaced by their sizes and hashes: what a worker sends back instead of
    the bytes when the workspace lives on object storage."""
    files = getattr(result, "files", None)
    if not files or not dataclasses.is_dataclass(result):
        return result
    return dataclasses.replace(result, files={relpath: remote.put(relpath, data) if isinstance(data, bytes) else data
                                              for relpath, data in files.items()})


def environment() -> dict[str, str]:
    """Python and the versions of ``PINNED_DISTRIBUTIONS`` in this process."""
    versions = {"python": platform.python_version()}
    for name in PINNED_DISTRIBUTIONS:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def threads_per_worker(workers: int) -> int:
    """Threads for each of ``workers`` workers sharing this machine's cores (``workers`` 0:
    one worker a core, as ``run.workers`` reads it): more threads than cores only contend
    (two evaluate workers of two ONNX Runtime threads each on two cores: 141 s against
    103 s with one thread each)."""
    cores = os.cpu_count() or 1
    return max(1, cores // (workers or cores))


def single_threaded_blas() -> None:
    """Hold the BLAS libraries (NumPy's and SciPy's OpenBLAS) of this process to one thread,
    whatever share of the cores it is given: OpenBLAS splits its sums by thread, so with a
    thread per core calibrate's bytes changed with ``run.workers`` and with the machine; and
    its threads spin while they wait: beside two busy processes, the smoke profile's
    calibrate took a median 141 s (78.5-142.3, 3 runs) with a thread per core against
    10.6 s (10.4-10.6) with one, and idle 8.5 s (8.4-8.6) against 7.1 s (7.0-8.0) (2 cores;
    ``python -m bench threads``). The pipeline's BLAS work is small solves that more
    threads do not speed up; ONNX Runtime, torch and Mitsuba take their threads from the
    worker's share (``threads_per_worker``, ``reserved_cpus``)."""
    from threadpoolctl import threadpool_limits

    global _limits
    for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[variable] = "1"  # the libraries loaded later in this process, and its children
    _limits = threadpool_limits(limits=1, user_api="blas")  # those loaded already


_limits: Any = None  # kept: the limit holds while its object lives

#: glibc's mallopt parameters (malloc.h) and the values ``keep_freed_memory`` sets (C ints)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD_BYTES, _TRIM_THRESHOLD_BYTES = 1 << 30, (1 << 31) - 1


def keep_freed_memory() -> bool:
    """Let this process reuse the memory it frees instead of giving it back to the system
    (glibc's ``mallopt``): arrays under 1 GiB come from the heap, and the heap is trimmed only
    when 2 GiB lie free at its top. A render or capture allocates frames of 9-100 MB an image;
    by default each is a fresh ``mmap`` returned on free, and every page of the next one
    faults in again (2,300-4,600 page faults a twin at 1920 x 1200, 130-250 with this). At
    1920 x 1200 a twin 1.62 -> 1.46 CPU-s, a training image 1.15 -> 1.02 (``bench
    image_costs``), a capture 4.5-4.7 -> 4.1-4.2 (docs/development.md, Speed). The same
    bytes (the default profile's run compared file by file); the process keeps its peak size
    (a twin's worker 690 -> 730 MB). Frames a thread other than the main one allocates come
    from that thread's arena, which glibc caps at 64 MiB, and stay mappings. False where the
    C library has no ``mallopt`` or refuses a value: the process then runs as it did."""
    import ctypes

    try:  # the C library already loaded into this process (find_library would run ldconfig)
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    mmap_set = mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)
    trim_set = mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD_BYTES)
    return bool(mmap_set) and bool(trim_set)


def prepare_worker() -> None:
    """What a worker process sets first (each local worker, each Ray actor): BLAS on one
    thread (``single_threaded_blas``, as the driver) and freed memory kept for reuse
    (``keep_freed_memory``). Not the driver: a short process pays more for its first frames
    from the heap (4 kB page faults where a fresh mapping takes huge pages) than reuse gives
    back; the smoke chain, which runs in its driver, took 19.4-19.8 s with it and 18.6-19.1 s
    without (three runs each, alternating)."""
    single_threaded_blas()
    keep_freed_memory()


def reserved_cpus(default: int) -> int:
    """The CPUs reserved for this worker by the cluster, else ``default``."""
    value = os.environ.get(WORKER_CPUS_ENV, "")
    return int(value) if value.isdigit() and int(value) > 0 else default


def map_engine(engine: Literal["local", "ray"], factory: Callable[..., Any], args: tuple[Any, ...], method: str,
               items: list[Any], *, workers: int, max_tasks: int, ray_address: str = "", worker_cpus: int = 1,
               prepare: Callable[[Any], Any] | None = None, probe: Callable[[], dict[str, str]] | None = None,
               expect: dict[str, str] | None = None, start_timeout_s: float = 600.0,
               remote: Remote | None = None) -> Iterator[Any]:
    """``factory(*args).<method>(prepare(item))`` for every item, as results complete, on
    ``map_local`` or ``cluster.map_ray`` (each Ray worker runs ``probe`` first; its report
    must match the driver's ``environment`` and ``expect``; with ``remote``, it uploads its
    results' files there itself)."""
    if engine == "ray":
        from core.engines.cluster import map_ray

        return map_ray(factory, args, method, items, workers=workers, max_tasks=max_tasks, address=ray_address,
                       worker_cpus=worker_cpus, prepare=prepare, probe=probe, expect=expect,
                       start_timeout_s=start_timeout_s, remote=remote)
    return map_local(factory, args, method, items, workers=workers, max_tasks=max_tasks, prepare=prepare)
