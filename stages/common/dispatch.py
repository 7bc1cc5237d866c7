"""The engine as a stage asks for it: ``core.engines.map_engine`` with the ``run``
section's engine, workers and cluster settings (docs/architecture.md section 11)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

from core.config import Config
from core.engines import map_engine
from manifests.remote import Remote
from stages.common.mitsuba_adapter import PREFERRED_VARIANT, mitsuba_variant


def map_config(config: Config, factory: Callable[..., Any], args: tuple[Any, ...], method: str, items: list[Any],
               *, renders: bool, prepare: Callable[[Any], Any] | None = None,
               remote: Remote | None = None) -> Iterator[Any]:
    """``factory(*args).<method>(prepare(item))`` for every item on ``config.run``'s engine;
    on a cluster, a worker that ``renders`` must load Mitsuba's fast variant first (a node
    without LLVM is refused before it takes an item), and uploads its files to ``remote``,
    the workspace's store, when it has one (``core.engines.store`` checks them)."""
    run = config.run
    workers = run.workers if run.workers or run.engine == "ray" else os.cpu_count() or 1
    return map_engine(run.engine, factory, args, method, items, workers=workers,
                      max_tasks=run.worker_max_tasks, ray_address=run.ray_address, worker_cpus=run.worker_cpus,
                      prepare=prepare, probe=mitsuba_variant if renders else None,
                      expect={"mitsuba_variant": PREFERRED_VARIANT} if renders else None,
                      start_timeout_s=run.start_timeout_s, remote=remote)
