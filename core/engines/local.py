"""The local engine: a pool of spawned worker processes that each build their (expensive)
context once (docs/architecture.md section 10).

Workers are started with ``spawn`` (never ``fork``: a renderer that has run cannot be
forked safely) and replaced after ``max_tasks`` samples, which bounds their memory.
Results come back as they complete; order is not preserved.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
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
    from core.engines import prepare_worker

    prepare_worker()
    # Ctrl-C reaches the whole process group: the driver stops the pool and says what was
    # kept; a worker's KeyboardInterrupt traceback would only bury that line
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()
    _context = factory(*args)


def _call(method: str, item: Any) -> Any:
    return getattr(_context, method)(item)


def map_local(factory: Callable[..., Any], args: tuple[Any, ...], method: str, items: list[Any], *,
              workers: int, max_tasks: int, prepare: Callable[[Any], Any] | None = None) -> Iterator[Any]:
    """Yield ``factory(*args).<method>(prepare(item))`` for every item, as results complete.

    With one worker everything runs in this process (easier to debug, no start-up cost).
    At most ``2 * workers`` items are in flight, so an interruption loses little work and
    ``prepare`` (run here, just before an item is sent: reading its image) holds little memory.
    """
    prepare = prepare or (lambda item: item)
    if workers <= 1 or len(items) <= 1:
        context = factory(*args)
        for item in items:
            yield getattr(context, method)(prepare(item))
        return
    executor = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_initialise, initargs=(factory, args, os.getpid()),
                                   max_tasks_per_child=max_tasks)
    pending: set[Future] = set()
    queue = list(reversed(items))
    try:
        while queue or pending:
            while queue and len(pending) < 2 * workers:
                pending.add(executor.submit(_call, method, prepare(queue.pop())))
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                yield future.result()
    finally:
        for future in pending:
            future.cancel()
        executor.shutdown(wait=True, cancel_futures=True)
