"""Render (synthetic twins): speed, scaling, memory, and the geometry proof.

    python -m bench render              seconds per twin at the default and paper resolutions,
                                        images per minute with one and two local workers, a
                                        worker's memory over 200 renders
    python -m bench render WORKSPACE    on a default-profile workspace after `run --until render`:
                                        IoU of every twin with the mock-up's silhouette in its
                                        testbed capture, at the fused label and at the true pose
"""

from __future__ import annotations

import multiprocessing
import sys
import time
from pathlib import Path

import numpy as np

from bench.common import report
from core.engines import map_local, threads_per_worker
from manifests import Workspace
from pipeline.config import load_config
from stages.common.cameras import train_camera
from stages.common.workspace_target import planned_target
from stages.render.jobs import train_jobs
from stages.render.worker import open_worker


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _seconds_per_image(profile: str, count: int) -> tuple[float, float]:
    config = load_config(profile, overrides=[f"render.train_count={count + 1}"])
    jobs = train_jobs(config)
    started = time.perf_counter()
    target = planned_target(config)
    worker = open_worker(train_camera(config), target, config.render.spp, config.render.max_depth,
                         threads_per_worker(1))
    worker.render(jobs[0])  # scene load and kernel compilation
    first = time.perf_counter() - started
    started = time.perf_counter()
    for job in jobs[1:]:
        worker.render(job)
    return first, (time.perf_counter() - started) / count


def _throughput(workers: int, count: int, threads: int) -> float:
    config = load_config("default", overrides=[f"render.train_count={count}"])
    jobs = train_jobs(config)
    args = (train_camera(config), config.render.spp, config.render.max_depth, threads)
    started = time.perf_counter()
    for _ in map_local(open_worker, args, "render", jobs, workers=workers, max_tasks=1000):
        pass
    return count / (time.perf_counter() - started) * 60


def _memory_child(renders: int, queue: multiprocessing.Queue) -> None:
    config = load_config("default", overrides=[f"render.train_count={renders}", "render.spp=16"])
    target = planned_target(config)
    worker = open_worker(train_camera(config), target, 16, config.render.max_depth, threads_per_worker(1))
    samples = []
    for index, job in enumerate(train_jobs(config), start=1):
        worker.render(job)
        if index in (1, 50, 100, 150, 200) or index == renders:
            samples.append((index, _rss_mb()))
    queue.put(samples)


def speed() -> None:
    rows = []
    for profile, count in (("default", 8), ("paper", 3)):
        first, per_image = _seconds_per_image(profile, count)
        config = load_config(profile)
        rows.append({"what": f"seconds per image, {profile} ({config.camera.width_px}x{config.camera.height_px}, "
                             f"{config.render.spp} spp, one worker, all cores; training-set poses)",
                     "value": per_image})
        rows.append({"what": f"first image incl. scene load and JIT, {profile}", "value": first})
    count = 24
    one, two = _throughput(1, count, threads=1), _throughput(2, count, threads=1)
    both = _throughput(1, count, threads=threads_per_worker(1))
    rows.append({"what": f"images per minute, 1 worker x 1 thread ({count} default images, incl. start-up)",
                 "value": one})
    rows.append({"what": f"images per minute, 2 workers x 1 thread ({count} default images, incl. start-up)",
                 "value": two})
    rows.append({"what": "scaling efficiency of worker processes, 2 vs 1", "value": two / one / 2})
    rows.append({"what": f"images per minute, 1 worker x {threads_per_worker(1)} threads (Dr.Jit's own parallelism)",
                 "value": both})
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    child = context.Process(target=_memory_child, args=(200, queue))
    child.start()
    samples = queue.get()
    child.join()
    for index, rss in samples:
        rows.append({"what": f"worker resident memory after {index} renders (MB, default, 16 spp)", "value": rss})
    report("render_speed", "render: speed, scaling and memory", rows)


def proof(root: str) -> None:
    from bench.overlap import twin_overlap

    workspace = Workspace(root)
    config = load_config(None, workspace.config_path)
    rows = twin_overlap(config, workspace)
    label, truth = np.array([r["iou_label"] for r in rows]), np.array([r["iou_truth"] for r in rows])
    summary = []
    for name, values in (("at the label (all)", label), ("at the true pose", truth)):
        summary.append({"IoU twin mask vs testbed silhouette": name, "n": len(values), "min": float(values.min()),
                        "median": float(np.median(values)), "mean": float(values.mean()),
                        "share >= 0.9": float(np.mean(values >= 0.9))})
    for source in ("fused", "kuka_only"):
        values = np.array([r["iou_label"] for r in rows if r["label_source"] == source])
        if len(values):
            summary.append({"IoU twin mask vs testbed silhouette": f"at the label ({source})", "n": len(values),
                            "min": float(values.min()), "median": float(np.median(values)),
                            "mean": float(values.mean()), "share >= 0.9": float(np.mean(values >= 0.9))})
    report("render_overlap", f"render: twins vs testbed silhouettes ({root})", summary, {"samples": rows})


def main(*args: str) -> None:
    if args:
        proof(args[0])
    else:
        speed()


if __name__ == "__main__":
    main(*sys.argv[1:])
