"""What one image costs at a profile's resolution, this tree against an earlier commit, in
one run: twins (black space, the profile's ``render.spp``), training images (the profile's
own first jobs: their poses, lights and Earth backgrounds, ``render.train_spp``), each with
its ground truth, and the virtual testbed's captures (the profile's first dataset captures,
``virtual.spp``, with their ground truth), in one process with one thread (a worker of one
CPU, set up as that code's workers are: ``core.engines.prepare_worker``).

    python -m bench image_costs [REF] [--profile paper] [--images 24] [--rounds 2] [--kinds twin,training,capture]

The two codes run in turns (REF, this tree; then this tree, REF; ...), each a fresh process per kind,
so that the machine's drift falls on both; every image after the first two of a process
is timed (scene load and compilation excluded). A twin's pose is drawn 4-10 m away, full
scale, anywhere in the image, from a fixed seed (``bench.cluster.twin_poses``, drawn here and
handed to both codes): the same images for both; the captures are the profile's first
dataset rows as each code plans them (the same sample ids). Mean and its standard error
per kind, and the ratio of the means. A training image's is weighed at the profile's share
of Earth backgrounds (``render.train_earth_fraction``), not at the sample's: an image over
the Earth costs two to three of one over black space, and 24 images hold what share they
draw; the two kinds' own means and ratios beside it.
Results: bench/results/image_costs.json.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.cluster import twin_poses
from bench.common import report
from bench.identity import REPO, worktree_env

#: runs in the code under test (its own modules), prints [[cpu_seconds, earth], ...]
_CHILD = r"""
import json, sys, time
import numpy as np
from pipeline.config import load_config
from stages.acquire.virtual.sensor import lens_camera
from stages.common.cameras import train_camera
from stages.common.workspace_target import planned_target
from stages.render.jobs import RenderJob, train_jobs
from stages.render.worker import RenderWorker

kind, profile, count = sys.argv[1], sys.argv[2], int(sys.argv[3])
import core.engines
# set up as that code's workers set themselves up (prepare_worker; before it, the BLAS limit)
getattr(core.engines, "prepare_worker", getattr(core.engines, "single_threaded_blas", lambda: None))()
config = load_config(profile)
target = planned_target(config)
if kind == "capture":
    import tempfile
    from manifests import Workspace
    from stages.acquire.virtual import VirtualTestbed
    from stages.plan.stage import plan_sample, planned_samples
    jobs = [plan_sample(config, *item) for item in planned_samples(config) if item[0] == "dataset"][:count + 2]
    if len(jobs) < count + 2:
        sys.exit(f"the {profile} profile plans {len(jobs)} dataset captures, fewer than {count + 2}")
    folder = tempfile.TemporaryDirectory()
    render = VirtualTestbed(config, Workspace(folder.name), jobs).capture
elif kind == "training":
    jobs = train_jobs(config, target)[:count + 2]
    render = RenderWorker(train_camera(config), target, config.render.train_spp, config.render.max_depth, 1).render
else:
    jobs = [RenderJob(f"img{i:06d}", "twin", tuple(q), tuple(t), tuple(light), 3.0, False, i)
            for i, (q, t, light) in enumerate(json.loads(sys.argv[4]))]
    render = RenderWorker(lens_camera(config.camera), target, config.render.spp, config.render.max_depth, 1).render
for job in jobs[:2]:
    render(job)
seconds = []
for job in jobs[2:]:
    started = time.process_time()
    render(job)
    seconds.append([time.process_time() - started, bool(getattr(job, "earth", False))])
print(json.dumps(seconds))
"""


def _costs(code: Path, kind: str, profile: str, images: int) -> list[list]:
    # the twins' poses from this tree (bench.cluster.twin_poses), the same for every code
    poses = json.dumps(twin_poses(images + 2))
    done = subprocess.run([sys.executable, "-c", _CHILD, kind, profile, str(images), poses], cwd=code,
                          env=worktree_env(code), capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{code}: {kind} images failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


#: what an image can be: a twin, a training image, a virtual testbed's capture
KINDS = ("twin", "training", "capture")


def _summary(seconds: list[float]) -> str:
    if not seconds:
        return "-"
    error = statistics.stdev(seconds) / len(seconds) ** 0.5 if len(seconds) > 1 else float("nan")
    return f"{statistics.mean(seconds):.3f} +- {error:.3f} (n={len(seconds)})"


def _at_share(training: list[list], fraction: float) -> tuple[float, float] | None:
    """Mean CPU-s of a training image and its standard error, the Earth's and black space's
    means weighed ``fraction`` : 1 - ``fraction``; None where a weighed kind has no image."""
    parts = []
    for weight, earth in ((fraction, True), (1.0 - fraction, False)):
        seconds = [s for s, over_earth in training if over_earth == earth]
        if weight == 0.0:
            continue
        if len(seconds) < 2:
            return None
        parts.append((weight * statistics.mean(seconds),
                      (weight * statistics.stdev(seconds)) ** 2 / len(seconds)))
    return sum(mean for mean, _ in parts), sum(variance for _, variance in parts) ** 0.5


def main(*args: str) -> None:
    ref = args[0] if args and not args[0].startswith("--") else None
    pairs = args[1:] if ref else args
    if len(pairs) % 2:
        sys.exit(f"image_costs: option {pairs[-1]} wants a value\n{__doc__}")
    options = dict(zip(pairs[0::2], pairs[1::2], strict=True))
    unknown = sorted(set(options) - {"--profile", "--images", "--rounds", "--kinds"})
    if unknown:
        sys.exit(f"image_costs: unknown option {unknown[0]}\n{__doc__}")
    profile = options.get("--profile", "paper")
    try:
        images, rounds = int(options.get("--images", 24)), int(options.get("--rounds", 2))
    except ValueError:
        sys.exit(f"image_costs: --images and --rounds take whole numbers\n{__doc__}")
    if images < 2 or rounds < 1:
        sys.exit("image_costs: --images at least 2 (a spread needs two), --rounds at least 1")
    kinds = tuple(dict.fromkeys(options.get("--kinds", ",".join(KINDS)).split(",")))
    if not kinds or not set(kinds) <= set(KINDS):
        sys.exit(f"image_costs: --kinds takes some of {', '.join(KINDS)}, comma-separated\n{__doc__}")
    codes: dict[str, Path] = {"this tree": REPO}
    with tempfile.TemporaryDirectory(prefix="speedplus-image-costs-") as scratch:
        if ref is not None:
            tree = Path(scratch) / "tree"
            added = subprocess.run(["git", "worktree", "add", "--detach", str(tree), ref], cwd=REPO,
                                   capture_output=True, text=True)
            if added.returncode != 0:
                sys.exit(f"image_costs: cannot check out {ref!r}: {added.stderr.strip()}")
            codes = {ref: tree, **codes}
        try:
            measured: dict[tuple[str, str], list[list]] = {}
            for round_ in range(rounds):
                # the first code of a round may fill a kernel cache the second then finds: turns
                for name, code in list(codes.items())[::1 if round_ % 2 == 0 else -1]:
                    for kind in kinds:
                        measured.setdefault((name, kind), []).extend(_costs(code, kind, profile, images))
        finally:
            if ref is not None:
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=REPO, check=False)
    from pipeline.config import load_config

    fraction = load_config(profile).render.train_earth_fraction
    # the training images weighed at the profile's share only where every code's can be: a
    # ratio of a weighed mean to a sample's would mean nothing
    weighable = all(_at_share(measured.get((name, "training"), []), fraction) is not None for name in codes)
    rows, means = [], {}
    for name in codes:
        seconds = {kind: measured.get((name, kind), []) for kind in KINDS}
        training = seconds["training"]
        means[name] = {kind: statistics.mean(s for s, _ in values) for kind, values in seconds.items() if values}
        for label, earth in (("with the Earth", True), ("black space", False)):
            kept = [s for s, over_earth in training if over_earth == earth]
            if kept:
                means[name][label] = statistics.mean(kept)
        weighed = _at_share(training, fraction) if weighable else None
        if weighed is not None:
            means[name]["training"] = weighed[0]
        unweighed = _summary([s for s, _ in training]) + (" (the sample's share)" if training else "")
        rows.append({"code": name, "CPU-s a twin": _summary([s for s, _ in seconds["twin"]]),
                     "CPU-s a training image": (f"{weighed[0]:.3f} +- {weighed[1]:.3f} (at {fraction:.0%} Earth)"
                                                if weighed else unweighed),
                     "with the Earth": _summary([s for s, earth in training if earth]),
                     "black space": _summary([s for s, earth in training if not earth]),
                     "CPU-s a capture": _summary([s for s, _ in seconds["capture"]])})
    if ref is not None:
        labels = (*KINDS, "with the Earth", "black space")
        ratio = {kind: f"{means[ref][kind] / means['this tree'][kind]:.2f}x"
                 if kind in means[ref] and kind in means["this tree"] else "-" for kind in labels}
        rows.append({"code": f"{ref} / this tree", "CPU-s a twin": ratio["twin"],
                     "CPU-s a training image": ratio["training"], "with the Earth": ratio["with the Earth"],
                     "black space": ratio["black space"], "CPU-s a capture": ratio["capture"]})
    report("image_costs", f"CPU-seconds an image at the {profile} profile's resolution (one worker of one CPU, "
           "ground truth included)", rows, {"profile": profile, "images": images, "rounds": rounds, "ref": ref,
                                                "kinds": list(kinds), "train_earth_fraction": fraction})
