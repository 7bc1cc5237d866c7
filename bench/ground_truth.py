"""What the per-pixel ground truth costs (``render.ground_truth``; target: below 1.3x a
plain render): seconds per image with it off and on, alternating on one worker so that
both see the same machine, for training images (``render.train_spp``) and twins
(``render.spp``), and the EXR's size.

    python -m bench ground_truth [COUNT]     (default 8 images a row, default profile)
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import report
from core.engines import store, threads_per_worker
from manifests import Workspace
from pipeline.config import load_config
from stages.common.cameras import train_camera
from stages.common.workspace_target import planned_target
from stages.render.jobs import train_jobs
from stages.render.worker import RenderWorker


def main(count: str = "8") -> None:
    n = int(count)
    config = load_config("default", overrides=[f"render.train_count={n + 1}"])
    jobs = train_jobs(config)
    rows = []
    for label, spp in (("training image", config.render.train_spp), ("twin", config.render.spp)):
        with tempfile.TemporaryDirectory() as root:
            target = planned_target(config)
            workers = {on: RenderWorker(train_camera(config), target, spp, config.render.max_depth,
                                        threads_per_worker(1), on) for on in (False, True)}
            for worker in workers.values():  # compile the kernels before timing
                worker.render(jobs[0])
            seconds: dict[bool, list[float]] = {False: [], True: []}
            sizes = []
            for job in jobs[1:]:
                for on in (False, True):
                    started = time.perf_counter()
                    row = store(Workspace(root), workers[on].render(job))
                    seconds[on].append(time.perf_counter() - started)
                    if on and row.get("ground_truth_path"):
                        sizes.append((Path(root) / row["ground_truth_path"]).stat().st_size / 1e6)
        plain, with_truth = float(np.mean(seconds[False])), float(np.mean(seconds[True]))
        rows.append({"images": label, "spp": spp, "size": f"{train_camera(config).width}x{train_camera(config).height}",
                     "plain (s/image)": plain, "with ground truth (s/image)": with_truth,
                     "ratio": with_truth / plain, "EXR (MB/image)": float(np.mean(sizes))})
    report("ground_truth", "cost of the per-pixel ground truth EXR (target: ratio below 1.3)", rows)


if __name__ == "__main__":
    main(*sys.argv[1:])
