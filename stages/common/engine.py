"""The engine as a stage asks for it: ``pipeline.engines.map_engine`` with the ``run``
section's engine, workers and cluster settings (docs/architecture.md section 10)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

from pipeline.config import Config
from pipeline.engines import map_engine
from stages.common.mitsuba_adapter import PREFERRED_VARIANT


def map_config(config: Config, factory: Callable[..., Any], args: tuple[Any, ...], method: str, items: list[Any],
               *, renders: bool, prepare: Callable[[Any], Any] | None = None) -> Iterator[Any]:
    """``factory(*args).<method>(prepare(item))`` for every item on ``config.run``'s engine;
    a context that ``renders`` must report Mitsuba's fast variant on a cluster (a node that
    would fall back to ``scalar_rgb`` is refused)."""
    run = config.run
    workers = run.workers if run.workers or run.engine == "ray" else os.cpu_count() or 1
    return map_engine(run.engine, factory, args, method, items, workers=workers,
                      max_tasks=run.worker_max_tasks, ray_address=run.ray_address, worker_cpus=run.worker_cpus,
                      prepare=prepare, expect={"mitsuba_variant": PREFERRED_VARIANT} if renders else None,
                      start_timeout_s=run.start_timeout_s)
