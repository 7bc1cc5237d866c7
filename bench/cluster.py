"""The Ray engine's scaling and the paper profile's cost model.

    python -m bench cluster [TRAIN_IMAGES]      (default 24)
    python -m bench cluster costs               (the cost model alone)

1. Cost model: CPU-seconds per capture (virtual testbed: 3 of the profile's dataset
   captures), per twin (8 seeded poses 4-10 m away) and per training image (the profile's
   first 12, their Earth backgrounds included) at each profile's resolution, one process
   with one thread (what one Ray worker of one CPU does), after a first item of each.
2. Scaling: the same stage (rendering 4, then TRAIN_IMAGES default-profile training
   images) on a one-node Ray cluster of one CPU and on two nodes of one CPU each, the
   second in its own mount namespace without the workspace (this machine has two cores,
   which the driver shares); efficiency = T(1 node) / (2 x T(2 nodes)) per further image
   (start-up cancels out), and with start-up.
3. Projection: the paper profile's CPU-seconds (its captures, twins and training images at
   the measured costs) over N nodes of C cores at the measured efficiency.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import report
from core.config import Override, with_overrides
from core.config.model import Config
from core.engines.local_cluster import ENV, LocalCluster
from manifests import Workspace
from pipeline.config import load_config
from stages.acquire.virtual.sensor import lens_camera
from stages.common import geometry as g
from stages.common.cameras import train_camera
from stages.common.lens import LensCamera
from stages.common.workspace_target import planned_target
from stages.plan.stage import plan_sample, planned_samples
from stages.render.jobs import RenderJob, train_jobs
from stages.render.worker import RenderWorker

PROFILES = ("smoke", "default", "paper")
#: twins and training images timed a profile (after the first)
_TWINS_DRAWN, _TRAINING_DRAWN = 8, 12


def _capture_seconds(profile: str, count: int) -> float:
    """CPU-seconds of one capture (after the first: scene load and JIT excluded)."""
    from stages.acquire.virtual import VirtualTestbed

    config = load_config(profile)
    items = [item for item in planned_samples(config) if item[0] == "dataset"][: count + 1]
    plans = [plan_sample(config, *item) for item in items]
    with tempfile.TemporaryDirectory() as directory:
        testbed = VirtualTestbed(config, Workspace(directory), plans)
        testbed.capture(plans[0])
        started = time.process_time()
        for plan in plans[1:]:
            testbed.capture(plan)
        return (time.process_time() - started) / count


def twin_poses(count: int) -> list[tuple[list[float], list[float], list[float]]]:
    """``count`` twins' (q_vbs2tango (4,), r_Vo2To_vbs (3,) m, light_dir_cam (3,) unit): the
    target 4-10 m away, full scale, anywhere in the image, in seeded random attitudes and
    lights (a different ``count`` draws other poses). ``bench image_costs`` times these too."""
    rng = np.random.default_rng(60)
    poses = []
    for q in g.random_quats(rng, count):
        depth = rng.uniform(4.0, 10.0)
        centre = np.array([rng.uniform(-0.3, 0.3) * depth, rng.uniform(-0.2, 0.2) * depth, depth])
        light = rng.normal(size=3)
        poses.append(([float(v) for v in q], centre.tolist(), (light / np.linalg.norm(light)).tolist()))
    return poses


def _twin_jobs(count: int) -> list[RenderJob]:
    """``twin_poses`` as render jobs (irradiance 3 W/m^2, no Earth)."""
    return [RenderJob(f"img{i:06d}", "twin", tuple(q), tuple(t), tuple(light), 3.0, False, i)
            for i, (q, t, light) in enumerate(twin_poses(count))]


def _render_seconds(camera: LensCamera, spp: int, max_depth: int, jobs: list[RenderJob]) -> list[float]:
    """CPU-seconds of each synthetic image, ground truth included, of ``jobs`` after the
    first (scene load and compilation excluded)."""
    worker = RenderWorker(camera, planned_target(load_config("default")), spp, max_depth, 1)
    worker.render(jobs[0])
    seconds = []
    for job in jobs[1:]:
        started = time.process_time()
        worker.render(job)
        seconds.append(time.process_time() - started)
    return seconds


def _training_seconds(config: Config) -> tuple[float, float, float]:
    """CPU-seconds of a training image with the Earth, without, and on average at the
    profile's ``render.train_earth_fraction``, from its own first training images (their
    poses and lights; where the drawn images are all of one kind, their mean)."""
    drawn = train_jobs(config)[:_TRAINING_DRAWN + 1]
    seconds = _render_seconds(train_camera(config), config.render.train_spp, config.render.max_depth, drawn)
    earth = [s for s, job in zip(seconds, drawn[1:], strict=True) if job.earth]
    black = [s for s, job in zip(seconds, drawn[1:], strict=True) if not job.earth]
    with_earth = float(np.mean(earth)) if earth else float("nan")
    without = float(np.mean(black)) if black else float("nan")
    if not earth or not black:  # what was drawn is all there is to go by
        return with_earth, without, float(np.mean(seconds))
    share = config.render.train_earth_fraction
    return with_earth, without, share * with_earth + (1 - share) * without


def _render_on(cluster: LocalCluster, root: Path, images: int) -> float:
    """Wall seconds of `speedplus render --set train` on the cluster (a fresh workspace)."""
    command = [sys.executable, "-m", "pipeline.cli", "render", "--profile", "default", "--workspace", str(root),
               "--set", "train", "--count", str(images), "--engine", "ray", "--ray-address", cluster.address,
               "--workers", "0"]
    started = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True, env={**os.environ, **ENV})
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-2000:])
    return time.perf_counter() - started


def main(images: str = "24") -> None:
    from core.engines import prepare_worker

    prepare_worker()  # measured as a worker runs: BLAS on one thread, freed frames reused
    costs = []
    for profile in PROFILES:
        config = load_config(profile)
        samples = len(planned_samples(config))
        per_capture = _capture_seconds(profile, 3)
        per_twin = float(np.mean(_render_seconds(lens_camera(config.camera), config.render.spp,
                                                 config.render.max_depth, _twin_jobs(_TWINS_DRAWN + 1))))
        training = with_overrides(config, [Override.of("render.train_resolution_scale",
                                                       config.reference.resolution_scale, "bench")])
        with_earth, without, per_image = _training_seconds(training)
        dataset = sum(1 for item in planned_samples(config) if item[0] == "dataset")
        cpu_seconds = samples * per_capture + dataset * per_twin + config.reference.images * per_image
        costs.append({"profile": profile, "image": f"{config.camera.width_px}x{config.camera.height_px}",
                      "CPU-s per capture": per_capture, "CPU-s per twin": per_twin,
                      "CPU-s per training image": per_image, "of which with the Earth": with_earth,
                      "without": without, "Earth share": training.render.train_earth_fraction,
                      "captures": samples, "twins (at most)": dataset,
                      "training images": config.reference.images, "CPU-s in all": cpu_seconds})
    report("cluster_costs", "cost model: CPU-seconds per item, one worker of one CPU", costs)
    paper = next(row for row in costs if row["profile"] == "paper")
    if images == "costs":
        speedplus_scale(paper, None)
        return
    count = int(images)

    small = 4
    with tempfile.TemporaryDirectory() as base:
        hidden = Path(base) / "hidden"
        with LocalCluster(head_cpus=1) as cluster:
            one = {n: _render_on(cluster, hidden / f"one-{n}", n) for n in (small, count)}
            cluster.add_node(1, hidden)
            two = {n: _render_on(cluster, hidden / f"two-{n}", n) for n in (small, count)}
    # the marginal images: start-up (Ray, code upload, scene load, JIT) cancels out
    steady_one, steady_two = ((t[count] - t[small]) / (count - small) for t in (one, two))
    efficiency = steady_one / (2 * steady_two)
    scaling = [{"cluster": "1 node x 1 CPU", f"wall s, {small} images": one[small],
                f"wall s, {count} images": one[count], "s per further image": steady_one},
               {"cluster": "2 nodes x 1 CPU (the second without the workspace)", f"wall s, {small} images": two[small],
                f"wall s, {count} images": two[count], "s per further image": steady_two},
               {"cluster": "efficiency: T1 / (2 T2), further images", f"wall s, {small} images": "-",
                f"wall s, {count} images": "-", "s per further image": efficiency},
               {"cluster": "efficiency incl. start-up", f"wall s, {small} images": "-",
                f"wall s, {count} images": one[count] / (2 * two[count]), "s per further image": "-"}]
    report("cluster_scaling", "Ray engine: one node against two (default training images; the driver shares the "
           "2 cores)", scaling)

    projection = []
    for nodes in (1, 4, 16, 64):
        for cores in (16,):
            wall = paper["CPU-s in all"] / (nodes * cores * efficiency)
            projection.append({"nodes x cores": f"{nodes} x {cores}", "paper profile wall (min)": wall / 60,
                               "assumes efficiency": efficiency})
    report("cluster_projection", "paper profile: projected wall time (CPU-seconds / (nodes x cores x efficiency))",
           projection, {"efficiency": efficiency, "paper_cpu_seconds": paper["CPU-s in all"]})
    speedplus_scale(paper, efficiency)


#: SPEED+ itself (Park et al. 2022): its testbed images (lightbox and sunlamp) and its
#: synthetic ones, all at 1920 x 1200
SPEEDPLUS_CAPTURES, SPEEDPLUS_SYNTHETIC = 9_531, 59_960


def speedplus_scale(paper: dict, efficiency: float | None) -> None:
    """SPEED+'s own scale from the paper profile's measured per-image costs: its captures at
    the cost of a dataset capture, its synthetic images at a twin's (1920 x 1200, the
    render's samples), on one 16-core machine and on docs/cluster.md's clusters of 16-core
    nodes, at the scaling's measured efficiency (1: ideal, where only the costs were run)."""
    cpu_seconds = SPEEDPLUS_CAPTURES * paper["CPU-s per capture"] + SPEEDPLUS_SYNTHETIC * paper["CPU-s per twin"]
    used = 1.0 if efficiency is None else efficiency
    rows = [{"machine": f"{nodes} x 16 cores", "hours": cpu_seconds / (nodes * 16 * used) / 3600,
             "assumes efficiency": used} for nodes in (1, 4, 16)]
    rows.insert(0, {"machine": "1 core", "hours": cpu_seconds / 3600, "assumes efficiency": 1.0})
    report("speedplus_scale", f"SPEED+ at its own scale ({SPEEDPLUS_CAPTURES} captures, {SPEEDPLUS_SYNTHETIC} "
           "synthetic images at 1920 x 1200): projected wall time", rows,
           {"cpu_seconds": cpu_seconds, "captures": SPEEDPLUS_CAPTURES, "synthetic": SPEEDPLUS_SYNTHETIC,
            "per_capture_cpu_s": paper["CPU-s per capture"], "per_synthetic_cpu_s": paper["CPU-s per twin"]})
