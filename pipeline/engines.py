"""Execution engines: map a per-sample function over samples, in this process or in a
pool of spawned worker processes that each build their (expensive) context once.

Workers are started with ``spawn`` (never ``fork``: a renderer that has run cannot be
forked safely) and replaced after ``max_tasks`` samples, which bounds their memory.
Results come back as they complete; order is not preserved.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

_context: Any = None


def _exit_with_parent(parent: int) -> None:
    """A worker whose parent died (killed, crashed) must not linger holding its pipes."""
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(1)


def _initialise(factory: Callable[..., Any], args: tuple[Any, ...], parent: int) -> None:
    global _context
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()
    _context = factory(*args)


def _call(method: str, item: Any) -> Any:
    return getattr(_context, method)(item)


def map_local(factory: Callable[..., Any], args: tuple[Any, ...], method: str, items: list[Any], *,
              workers: int, max_tasks: int) -> Iterator[Any]:
    """Yield ``factory(*args).<method>(item)`` for every item, as results complete.

    With one worker everything runs in this process (easier to debug, no start-up cost).
    At most ``2 * workers`` items are in flight, so an interruption loses little work.
    """
    if workers <= 1 or len(items) <= 1:
        context = factory(*args)
        for item in items:
            yield getattr(context, method)(item)
        return
    executor = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_initialise, initargs=(factory, args, os.getpid()),
                                   max_tasks_per_child=max_tasks)
    pending: set[Future] = set()
    queue = list(reversed(items))
    try:
        while queue or pending:
            while queue and len(pending) < 2 * workers:
                pending.add(executor.submit(_call, method, queue.pop()))
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                yield future.result()
    finally:
        for future in pending:
            future.cancel()
        executor.shutdown(wait=True, cancel_futures=True)


def _ray_actor_class() -> Any:
    import ray

    @ray.remote(num_cpus=1)
    class Worker:
        """A Ray actor holding one context (e.g. a loaded renderer)."""

        def __init__(self, factory: Callable[..., Any], args: tuple[Any, ...]) -> None:
            self.context = factory(*args)

        def call(self, method: str, item: Any) -> Any:
            return getattr(self.context, method)(item)

    return Worker


def connect_ray(address: str, workers: int) -> None:
    """Join the cluster at ``address``, or start a local one with ``workers`` CPUs; a
    cluster this process already joined is reused."""
    import ray

    if ray.is_initialized():
        return
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)


def map_ray(factory: Callable[..., Any], args: tuple[Any, ...], method: str, items: list[Any], *,
            workers: int, max_tasks: int, address: str = "") -> Iterator[Any]:
    """Like ``map_local`` on a Ray cluster: ``workers`` actors each build the context once
    and are replaced after ``max_tasks`` items. Results come back as they complete."""
    import ray

    connect_ray(address, workers)
    worker_class = _ray_actor_class()
    queue = list(reversed(items))
    actors = [worker_class.remote(factory, args) for _ in range(min(workers, len(items)))]
    done_by = [0] * len(actors)
    pending: dict[Any, int] = {}  # object ref -> actor slot
    try:
        while queue or pending:
            for slot in range(len(actors)):
                in_flight = sum(1 for s in pending.values() if s == slot)
                while queue and in_flight < 2 and done_by[slot] + in_flight < max_tasks:
                    pending[actors[slot].call.remote(method, queue.pop())] = slot
                    in_flight += 1
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                slot = pending.pop(ref)
                done_by[slot] += 1
                yield ray.get(ref)
                if done_by[slot] >= max_tasks and not any(s == slot for s in pending.values()):
                    ray.kill(actors[slot])  # recycle: a renderer's memory grows with its age
                    actors[slot], done_by[slot] = worker_class.remote(factory, args), 0
    finally:
        for actor in actors:
            ray.kill(actor)


def map_engine(engine: str, factory: Callable[..., Any], args: tuple[Any, ...], method: str, items: list[Any], *,
               workers: int, max_tasks: int, ray_address: str = "") -> Iterator[Any]:
    """Dispatch to ``map_local`` or ``map_ray``."""
    if engine == "ray":
        return map_ray(factory, args, method, items, workers=workers, max_tasks=max_tasks, address=ray_address)
    return map_local(factory, args, method, items, workers=workers, max_tasks=max_tasks)
