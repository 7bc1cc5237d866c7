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

from pipeline.engines import WORKER_CPUS_ENV, EngineError, environment, upload
from pipeline.progress import console

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

    prepare = prepare or (lambda item: item)
    connect(address, workers * worker_cpus or os.cpu_count() or 1)
    free = int(ray.available_resources().get("CPU", 0) // worker_cpus)
    waited = 0.0
    # ray.kill is asynchronous: the actors of the map just before (the previous model of
    # evaluate) give their CPUs back a moment after they are killed
    while free < 1 and waited < FREE_CPU_WAIT_S:
        time.sleep(0.25)
        waited += 0.25
        free = int(ray.available_resources().get("CPU", 0) // worker_cpus)
    size = min(workers or len(items), len(items), free)
    if size < 1:
        raise EngineError(f"the Ray cluster has no free CPU for a worker of {worker_cpus} CPU(s) "
                          f"(free: {ray.available_resources().get('CPU', 0):g}); wait for other jobs or add nodes")
    expected = {**environment(), **(expect or {})}
    worker_class = _actor_class(ray).options(num_cpus=worker_cpus, max_restarts=0)
    factory_ref = ray.put((factory, args, probe, remote))  # one copy in the object store for every actor

    def start() -> _Slot:
        actor = worker_class.remote(factory_ref)
        return _Slot(actor, actor.describe.remote())

    queue = list(reversed(range(len(items))))
    attempts = [0] * len(items)
    start_errors: list[str] = []
    slots = [start() for _ in range(size)]
    owner: dict[Any, tuple[_Slot, int]] = {}  # task ref -> (slot, item index)
    console.print(f"ray: {size} worker(s) of {worker_cpus} CPU(s) for {len(items)} items")

    def retire(slot: _Slot, replace: bool) -> None:
        slots.remove(slot)
        for ref in slot.in_flight:
            owner.pop(ref, None)
        ray.kill(slot.actor, no_restart=True)
        if replace and (queue or owner):
            slots.append(start())

    try:
        while queue or owner:
            for slot in list(slots):
                if slot.ready:
                    while queue and len(slot.in_flight) < 2 and slot.done + len(slot.in_flight) < max_tasks:
                        index = queue.pop()
                        ref = slot.actor.call.remote(method, prepare(items[index]))
                        slot.in_flight.add(ref)
                        owner[ref] = (slot, index)
                elif time.monotonic() - slot.started > start_timeout_s:
                    retire(slot, replace=False)  # unschedulable now (the cluster shrank, or is busy)
            if not slots:
                why = (f"the last one failed: {start_errors[-1]}" if start_errors else
                       f"none was placed within {start_timeout_s:.0f} s: the cluster has no free CPU")
                raise EngineError(f"no Ray worker could start ({len(queue)} items left); {why}")
            waiting = list(owner) + [s.ready_ref for s in slots if not s.ready]
            ready_refs, _ = ray.wait(waiting, num_returns=1, timeout=1.0)
            for ref in ready_refs:
                starting = next((s for s in slots if not s.ready and s.ready_ref == ref), None)
                if starting is not None:
                    try:
                        report = ray.get(ref)
                    except ray_errors.RayError as error:
                        start_errors.append(" ".join(str(_cause(error)).split())[:300])
                        retire(starting, replace=False)  # died while starting: its node is gone
                        continue
                    refusal = _refusal(report, expected)
                    if refusal:
                        raise EngineError(refusal)
                    starting.ready = True
                    facts = [f"{report['cpus']} CPU(s)", *(f"{key} {report[key]}" for key in expect or {})]
                    console.print(f"ray worker on {report['host']} (node {report['node']}, pid {report['pid']}): "
                                  + ", ".join(facts), soft_wrap=True)
                    continue
                slot, index = owner.pop(ref)
                slot.in_flight.discard(ref)
                try:
                    result = ray.get(ref)
                except ray_errors.RayTaskError as error:  # the method itself raised: not worth a retry
                    raise _cause(error) from None
                except (ray_errors.RayActorError, ray_errors.ObjectLostError, ray_errors.WorkerCrashedError,
                        ray_errors.NodeDiedError) as error:
                    attempts[index] += 1
                    if attempts[index] >= MAX_ATTEMPTS:
                        raise EngineError(f"item {index} ended {MAX_ATTEMPTS} Ray workers (last: "
                                          f"{type(error).__name__}); the finished rows are kept") from None
                    queue.append(index)
                    for other in list(slot.in_flight):  # the actor is gone: its other items go back too
                        queue.append(owner.pop(other)[1])
                    slot.in_flight.clear()
                    console.print(f"[yellow]ray: a worker died ({type(error).__name__}); its items go to "
                                  "another worker[/]")
                    retire(slot, replace=True)
                    continue
                slot.done += 1
                yield result
                if slot.done >= max_tasks and not slot.in_flight:
                    retire(slot, replace=True)  # recycle: a renderer's memory grows with its age
    except ray_errors.RayError as error:
        raise EngineError(f"Ray failed: {type(error).__name__}: {' '.join(str(error).split())[:300]}") from None
    finally:
        for slot in slots:
            ray.kill(slot.actor, no_restart=True)
