"""Acquire (virtual testbed): seconds per capture for each session type, a worker's peak
memory, and, on a complete default-profile workspace, ChArUco detection and the pixel
agreement of detected corners with the hidden truth.

    python -m bench acquire [CAPTURES_PER_SESSION]      (default 6)
    python -m bench acquire WORKSPACE                    (e.g. data/default after acquire)
    python -m bench acquire BEFORE AFTER                 (two acquisitions of one plan and seed)

The last compares the ChArUco corners detected in the calibration images of two
acquisitions of the same plan and seed made by two versions of the renderer (``bench
pipeline REF`` keeps them as ROOT/before and ROOT/after): how far each corner moved against
how far either lies from the truth (its noise), and the mean shift, which a change of the
images' statistics would show and noise would not.
"""

from __future__ import annotations

import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bench.common import report
from manifests import Workspace, read_manifest
from pipeline.config import load_config
from stages.common import geometry as g
from stages.common.patterns import PatternSpec, detect
from stages.plan.stage import plan_sample, planned_samples


def timing(per_session: int = 6) -> None:
    from stages.acquire.virtual import VirtualTestbed

    config = load_config("default", overrides=["run.workers=1"])
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        items = planned_samples(config)
        # the session timeline (thermal drift, backlash) is laid out from the whole plan
        testbed = VirtualTestbed(config, Workspace(directory), [plan_sample(config, *item) for item in items])
        started = time.perf_counter()
        testbed.capture(plan_sample(config, *items[0]))  # scene load and kernel compilation
        rows.append({"what": "first capture (scene load, JIT)", "captures": 1,
                     "seconds_per_capture": time.perf_counter() - started})
        for session, chosen in (("calibration", items[1:1 + per_session]),
                                ("dataset", [i for i in items if i[0] == "dataset"][:per_session])):
            plans = [plan_sample(config, *item) for item in chosen]
            started = time.perf_counter()
            for plan in plans:
                testbed.capture(plan)
            rows.append({"what": f"{session} capture (default profile, {config.camera.width_px}x"
                                 f"{config.camera.height_px}, {config.virtual.spp} spp)",
                         "captures": len(plans), "seconds_per_capture": (time.perf_counter() - started) / len(plans)})
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rows.append({"what": "peak resident memory of the worker (MB)", "captures": "-", "seconds_per_capture": peak_mb})
    report("acquire_timing", "acquire: one worker using all cores", rows)


def _corners(ws: Workspace) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per calibration capture: (ids (N,), detected (N, 2) px, true (N, 2) px) of its ChArUco corners."""
    session = json.loads(ws.session_path.read_text())
    spec = PatternSpec.from_json(session["pattern"])
    camera_matrix, dist = np.array(session["camera"]["K"]), np.array(session["camera"]["dist"])
    target_from_board = g.transform_from_qt(spec.target_from_pattern_q, spec.target_from_pattern_t)
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    out = {}
    for row in read_manifest(ws, "captures").to_pylist():
        if row["session"] != "calibration":
            continue
        corners, ids = detect(cv2.imread(str(ws.resolve(row["image_path"])), cv2.IMREAD_GRAYSCALE), spec)
        ids = np.ravel(ids).astype(int)
        true = truth[row["sample_id"]]
        cam_from_target = g.transform_from_qt(true["cam_from_target_q"], true["cam_from_target_t"])
        expected = (g.project(cam_from_target @ target_from_board, spec.object_points()[ids], camera_matrix, dist)
                    if len(ids) else np.zeros((0, 2)))
        out[row["sample_id"]] = (ids, np.reshape(corners, (-1, 2)), np.reshape(expected, (-1, 2)))
    return out


def detection(root: str) -> None:
    captures = _corners(Workspace(root))
    counts = np.array([len(ids) for ids, _, _ in captures.values()])
    errors = np.concatenate([np.linalg.norm(found - true, axis=1) for _, found, true in captures.values()])
    rows = [{"metric": "calibration captures", "value": len(counts)},
            {"metric": "with >= 6 ChArUco corners (fraction)", "value": float(np.mean(counts >= 6))},
            {"metric": "corners per capture (median)", "value": float(np.median(counts))},
            {"metric": "detected vs true corner, median (px)", "value": float(np.median(errors))},
            {"metric": "detected vs true corner, 95th percentile (px)", "value": float(np.percentile(errors, 95))}]
    report("acquire_detection", f"acquire: ChArUco detection in {Path(root).name}", rows)


def _by_corner(ws: Workspace) -> dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]:
    """{(sample_id, corner id): (detected (2,), true (2,)) px}."""
    return {(sample, int(i)): (c, e) for sample, (ids, found, true) in _corners(ws).items()
            for i, c, e in zip(ids, found, true, strict=True)}


def moved(before_root: str, after_root: str) -> None:
    before, after = _by_corner(Workspace(before_root)), _by_corner(Workspace(after_root))
    both = sorted(set(before) & set(after))
    if len(both) < 2:
        sys.exit(f"{before_root} and {after_root}: {len(both)} corners detected in both; nothing to compare")
    shift = np.array([after[k][0] - before[k][0] for k in both])  # (N, 2) px
    error_before = np.array([np.linalg.norm(before[k][0] - before[k][1]) for k in both])
    error_after = np.array([np.linalg.norm(after[k][0] - after[k][1]) for k in both])
    distance = np.linalg.norm(shift, axis=1)
    mean, sem = shift.mean(axis=0), shift.std(axis=0, ddof=1) / np.sqrt(len(shift))
    rows = [{"metric": "corners detected in both / before only / after only",
             "value": f"{len(both)} / {len(set(before) - set(after))} / {len(set(after) - set(before))}"},
            {"metric": "detected vs true, before: median / 95th percentile (px)",
             "value": f"{np.median(error_before):.3f} / {np.percentile(error_before, 95):.3f}"},
            {"metric": "detected vs true, after: median / 95th percentile (px)",
             "value": f"{np.median(error_after):.3f} / {np.percentile(error_after, 95):.3f}"},
            {"metric": "moved, after against before: median / 95th percentile (px)",
             "value": f"{np.median(distance):.3f} / {np.percentile(distance, 95):.3f}"},
            {"metric": "mean shift x, y +- standard error (px)",
             "value": f"{mean[0]:+.4f} +- {sem[0]:.4f}, {mean[1]:+.4f} +- {sem[1]:.4f}"}]
    report("acquire_corners_moved", f"acquire: corners of {Path(before_root).name} and {Path(after_root).name}", rows,
           {"before": str(before_root), "after": str(after_root)})


def main(*args: str) -> None:
    if len(args) == 2:
        moved(*args)
    elif args and not args[0].isdigit():
        detection(args[0])
    else:
        timing(int(args[0]) if args else 6)


if __name__ == "__main__":
    main(*sys.argv[1:])
