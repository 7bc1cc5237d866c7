"""The Ray engine (docs/architecture.md section 10): a pool of actors that each build one
context (a loaded renderer, an ONNX Runtime session), fed from a work queue.

- **Sized to the cluster's free CPUs**: never more actors than can be scheduled now, and an
  actor gets work only once it has started and reported itself (``describe``), so a busy or
  shrinking cluster slows a stage down but never hangs it.
- **Retries**: a sample whose actor died (its process killed, its node lost) goes back to
  the queue and the actor is replaced; that is safe because outputs are deterministic and
  the driver writes them atomically. A sample that kills ``MAX_ATTEMPTS`` workers, an
  actor that does not start within ``start_timeout_s`` with none left, or any other Ray
  failure ends the stage with ``EngineError`` (exit 1), keeping every finished row.
- **Same bytes everywhere**: each actor first reports its node, the versions of what makes
  bytes and what its stage probes (Mitsuba loads its llvm variant); one that differs from
  the driver is refused before it takes an item, naming the node.
- **Code ships with the job** when joining an existing cluster (``runtime_env``
  ``working_dir``): nodes need the dependencies (the ``[cluster]`` extra), not this repository.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from core.engines import WORKER_CPUS_ENV, EngineError, environment, prepare_worker, upload
from core.progress import console

#: a sample is tried on at most this many workers before the stage gives up on it
MAX_ATTEMPTS = 3
#: seconds to wait for a free CPU before saying the cluster has none
FREE_CPU_WAIT_S = 15.0
REPOSITORY = Path(__file__).resolve().parents[2]
#: what the job's working_dir leaves behind (workspaces, environments, caches)
SHIPPING_EXCLUDES = [".git", ".venv", "data", "**/__pycache__", "*.egg-info", ".pytest_cache", ".ruff_cache",
                     "bench/results"]


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise EngineError("--engine ray needs Ray: pip install -e '.[cluster]' (or `make setup`)") from None
    return ray


def runtime_env() -> dict[str, Any]:
    """The code of this checkout, shipped to every node of a cluster this process joins."""
    return {"working_dir": str(REPOSITORY), "excludes": SHIPPING_EXCLUDES}


def reachable(address: str) -> None:
    """Fail fast on a ``host:port`` nothing listens at (Ray itself keeps retrying for minutes)."""
    host, _, port = address.rpartition(":")
    if not host or "://" in address or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=10).close()
    except OSError as error:
        reason = error.strerror or str(error)
        raise EngineError(f"cannot join the Ray cluster at {address!r}: nothing answers there ({reason}); start "
                          "it with `ray start --head` or check the address") from None


def connect(address: str, cpus: int) -> None:
    """Join the cluster at ``address`` (``auto``, ``host:port`` or ``ray://host:10001``)
    with this checkout's code, or start a local one with ``cpus`` CPUs; a cluster this
    process already joined is reused."""
    ray = _ray()
    if ray.is_initialized():
        return
    if address.startswith("ray://"):
        raise EngineError(f"--ray-address {address}: Ray Client addresses are not supported (the driver writes "
                          "the workspace, so it runs beside the cluster); run the command on a node of the cluster "
                          "with --ray-address auto, or give the head's host:6379")
    reachable(address)
    try:
        if address:
            ray.init(address=address, log_to_driver=False, runtime_env=runtime_env())
        else:
            ray.init(num_cpus=max(1, cpus), include_dashboard=False, log_to_driver=False)
    except Exception as error:  # noqa: BLE001 - any failure to join is the user's to fix
        where = f"the Ray cluster at {address!r}" if address else "a local Ray cluster"
        raise EngineError(f"cannot join {where}: {' '.join(str(error).split())[:300]}") from None


def _actor_class(ray: Any) -> Any:
    @ray.remote
    class Worker:
        """Reports where it runs and with what (``describe``), then holds one context, built
        on its first item: a node that cannot make the driver's bytes is refused before."""

        def __init__(self, packed: tuple[Callable[..., Any], tuple[Any, ...], Callable[[], dict[str, str]] | None,
                                         Any]) -> None:
            self.factory, self.args, self.probe, self.remote = packed
            cpus = ray.get_runtime_context().get_assigned_resources().get("CPU", 1)
            os.environ[WORKER_CPUS_ENV] = str(max(1, int(round(cpus))))
            prepare_worker()
            self.context: Any = None

        def describe(self) -> dict[str, Any]:
            report = {"host": socket.gethostname(), "node": ray.get_runtime_context().get_node_id()[:12],
                      "pid": os.getpid(), "cpus": int(os.environ[WORKER_CPUS_ENV]), **environment()}
            if self.probe is not None:
                try:
                    report.update(self.probe())
                except Exception as error:  # noqa: BLE001 - reported to the driver, which refuses the node
                    report["probe_error"] = " ".join(str(error).split())[:300]
            return report

        def call(self, method: str, item: Any) -> Any:
            if self.context is None:
                self.context = self.factory(*self.args)
            result = getattr(self.context, method)(item)
            return upload(result, self.remote) if self.remote is not None else result

    return Worker


class _Slot:
    """One actor of the pool and the items it holds."""

    def __init__(self, actor: Any, ready: Any) -> None:
        self.actor, self.ready_ref = actor, ready
        self.started = time.monotonic()
        self.ready = False
        self.done = 0
        self.in_flight: set[Any] = set()


def _refusal(report: dict[str, Any], expected: dict[str, str]) -> str | None:
    wrong = [f"{key} {report.get(key)!r} (driver: {value!r})" for key, value in expected.items()
             if report.get(key) != value]
    if "probe_error" in report:
        wrong.insert(0, report["probe_error"])
    if not wrong:
        return None
    return (f"refusing the Ray worker on {report.get('host')} (node {report.get('node')}): {', '.join(wrong)}; "
            "install the driver's versions there (pip install -e '.[cluster]' from the same checkout; Debian "
            "libllvm19 for Mitsuba's llvm variant)")


def _cause(error: Exception) -> Exception:
    """The exception a worker's method raised, when Ray wraps one."""
    cause = getattr(error, "cause", None)
    return cause if isinstance(cause, Exception) else error


def map_ray(factory: Callable[..., Any], args: tuple[Any, ...], method: str, items: list[Any], *,
            workers: int, max_tasks: int, address: str = "", worker_cpus: int = 1,
            prepare: Callable[[Any], Any] | None = None, probe: Callable[[], dict[str, str]] | None = None,
            expect: dict[str, str] | None = None, start_timeout_s: float = 600.0,
            remote: Any = None) -> Iterator[Any]:
    """Like ``map_local`` on a Ray cluster, with at most ``workers`` actors of ``worker_cpus``
    CPUs each (``workers`` 0: as many as the free CPUs allow). Each actor runs ``probe``
    first; its report must match the driver's ``environment`` and ``expect``. With
    ``remote`` (``manifests.remote.Remote``), actors upload their results' files there and
    return sizes and hashes. See the module docstring."""
    if not items:
        return
    ray = _ray()
    from ray import exceptions as ray_errors

    connect(address, workers * worker_cpus or os.cpu_count() or 1)
    size = min(workers or len(items), len(items), _free_workers(ray, worker_cpus))
    if size < 1:
        raise EngineError(f"the Ray cluster has no free CPU for a worker of {worker_cpus} CPU(s) "
                          f"(free: {ray.available_resources().get('CPU', 0):g}); wait for other jobs or add nodes")
    worker_class = _actor_class(ray).options(num_cpus=worker_cpus, max_restarts=0)
    pool = _Pool(ray, worker_class, ray.put((factory, args, probe, remote)), method, items,
                 prepare or (lambda item: item), max_tasks, start_timeout_s, {**environment(), **(expect or {})},
                 tuple(expect or {}))
    console.print(f"ray: {size} worker(s) of {worker_cpus} CPU(s) for {len(items)} items")
    try:
        pool.start(size)
        yield from pool.results()
    except ray_errors.RayError as error:
        raise EngineError(f"Ray failed: {type(error).__name__}: {' '.join(str(error).split())[:300]}") from None
    finally:
        pool.close()


def _free_workers(ray: Any, worker_cpus: int) -> int:
    """Workers the cluster's free CPUs hold, after a moment for the previous map's actors
    (``ray.kill`` is asynchronous) to give theirs back."""
    free = int(ray.available_resources().get("CPU", 0) // worker_cpus)
    waited = 0.0
    while free < 1 and waited < FREE_CPU_WAIT_S:
        time.sleep(0.25)
        waited += 0.25
        free = int(ray.available_resources().get("CPU", 0) // worker_cpus)
    return free


class _Pool:
    """The actors of one map: started (``start``), given items two at a time (``dispatch``),
    checked when they report ready (``_on_ready``), replaced when they die (``_on_lost``) or
    reach ``max_tasks`` (recycled: a renderer's memory grows with its age); ``results``
    yields each item's result as it finishes."""

    def __init__(self, ray: Any, worker_class: Any, factory_ref: Any, method: str, items: list[Any],
                 prepare: Callable[[Any], Any], max_tasks: int, start_timeout_s: float, expected: dict[str, str],
                 shown: tuple[str, ...]) -> None:
        self.ray, self.worker_class, self.factory_ref, self.method = ray, worker_class, factory_ref, method
        self.items, self.prepare, self.max_tasks, self.start_timeout_s = items, prepare, max_tasks, start_timeout_s
        self.expected, self.shown = expected, shown
        self.queue = list(reversed(range(len(items))))
        self.attempts = [0] * len(items)
        self.start_errors: list[str] = []
        self.slots: list[_Slot] = []
        self.owner: dict[Any, tuple[_Slot, int]] = {}  # task ref -> (slot, item index)

    def start(self, count: int = 1) -> None:
        for _ in range(count):
            actor = self.worker_class.remote(self.factory_ref)
            self.slots.append(_Slot(actor, actor.describe.remote()))

    def retire(self, slot: _Slot, replace: bool) -> None:
        self.slots.remove(slot)
        for ref in slot.in_flight:
            self.owner.pop(ref, None)
        self.ray.kill(slot.actor, no_restart=True)
        if replace and (self.queue or self.owner):
            self.start()

    def close(self) -> None:
        for slot in self.slots:
            self.ray.kill(slot.actor, no_restart=True)

    def dispatch(self) -> None:
        """Items to every ready actor (two in flight each, within its task budget); an actor
        not ready within the start timeout is given up (the cluster shrank, or is busy)."""
        for slot in list(self.slots):
            if slot.ready:
                while self.queue and len(slot.in_flight) < 2 and slot.done + len(slot.in_flight) < self.max_tasks:
                    index = self.queue.pop()
                    ref = slot.actor.call.remote(self.method, self.prepare(self.items[index]))
                    slot.in_flight.add(ref)
                    self.owner[ref] = (slot, index)
            elif time.monotonic() - slot.started > self.start_timeout_s:
                self.retire(slot, replace=False)
        if not self.slots:
            why = (f"the last one failed: {self.start_errors[-1]}" if self.start_errors else
                   f"none was placed within {self.start_timeout_s:.0f} s: the cluster has no free CPU")
            raise EngineError(f"no Ray worker could start ({len(self.queue)} items left); {why}")

    def results(self) -> Iterator[Any]:
        from ray import exceptions as ray_errors

        while self.queue or self.owner:
            self.dispatch()
            waiting = list(self.owner) + [s.ready_ref for s in self.slots if not s.ready]
            ready_refs, _ = self.ray.wait(waiting, num_returns=1, timeout=1.0)
            for ref in ready_refs:
                starting = next((s for s in self.slots if not s.ready and s.ready_ref == ref), None)
                if starting is not None:
                    self._on_ready(starting, ref)
                    continue
                slot, index = self.owner.pop(ref)
                slot.in_flight.discard(ref)
                try:
                    result = self.ray.get(ref)
                except ray_errors.RayTaskError as error:  # the method itself raised: not worth a retry
                    raise _cause(error) from None
                except (ray_errors.RayActorError, ray_errors.ObjectLostError, ray_errors.WorkerCrashedError,
                        ray_errors.NodeDiedError) as error:
                    self._on_lost(slot, index, error)
                    continue
                slot.done += 1
                yield result
                if slot.done >= self.max_tasks and not slot.in_flight:
                    self.retire(slot, replace=True)

    def _on_ready(self, slot: _Slot, ref: Any) -> None:
        """An actor's report: refuse a node that cannot make the driver's bytes; else it takes items."""
        from ray import exceptions as ray_errors

        try:
            report = self.ray.get(ref)
        except ray_errors.RayError as error:
            self.start_errors.append(" ".join(str(_cause(error)).split())[:300])
            self.retire(slot, replace=False)  # died while starting: its node is gone
            return
        refusal = _refusal(report, self.expected)
        if refusal:
            raise EngineError(refusal)
        slot.ready = True
        facts = [f"{report['cpus']} CPU(s)", *(f"{key} {report[key]}" for key in self.shown)]
        console.print(f"ray worker on {report['host']} (node {report['node']}, pid {report['pid']}): "
                      + ", ".join(facts), soft_wrap=True)

    def _on_lost(self, slot: _Slot, index: int, error: Exception) -> None:
        """A dead actor: its items go back to the queue (an item that ended ``MAX_ATTEMPTS``
        actors ends the map), and another actor takes its place."""
        self.attempts[index] += 1
        if self.attempts[index] >= MAX_ATTEMPTS:
            raise EngineError(f"item {index} ended {MAX_ATTEMPTS} Ray workers (last: "
                              f"{type(error).__name__}); the finished rows are kept") from None
        self.queue.append(index)
        for other in list(slot.in_flight):  # the actor is gone: its other items go back too
            self.queue.append(self.owner.pop(other)[1])
        slot.in_flight.clear()
        console.print(f"[yellow]ray: a worker died ({type(error).__name__}); its items go to another worker[/]")
        self.retire(slot, replace=True)
