"""Error budget of the labels: what each unmodelled error source of the virtual facility
costs (docs/architecture.md section 5). The default profile is acquired, calibrated, fused
and labelled with no unmodelled source, with each one alone, and with all of them, on the
same facility seed (each source draws from its own stream, so "alone" is the same
realisation as in "all"). A lab reads it as: what to fix first on its own facility.

    python -m bench budget [SEED] [ROOT] [ROWS]   (default: 11, data/budget, every row; ~7 min a row)

ROWS: comma-separated names of the rows to run (none, a source's name, all).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from bench.accuracy import SPEEDPLUS_ROTATION_RAD, SPEEDPLUS_TRANSLATION
from bench.common import report
from bench.honesty import calibration_samples, dataset, run_facility
from core.config import UNMODELLED_SOURCES, CameraConfig
from manifests import Workspace, read_manifest
from manifests.sidecars import read_session, read_truth
from stages.common import geometry as g
from stages.common import tango


def keypoint_error_px(ws: Workspace) -> float:
    """Mean distance (px) of the labels' keypoints from where the dataset session's true
    camera saw them."""
    camera = CameraConfig(**{key: tuple(v) if isinstance(v, list) else v for key, v in
                             read_truth(ws).unmodelled["camera_by_session"]["dataset"].items()})
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    points = tango.KEYPOINTS_M * read_session(ws).mockup_scale
    errors = []
    for label in read_manifest(ws, "labels").to_pylist():
        row = truth[label["sample_id"]]
        pose = g.transform_from_qt(row["cam_from_target_q"], row["cam_from_target_t"])
        true_px = g.project_points(g.apply(pose, points), camera.camera_matrix(), camera.dist_coeffs())
        errors.append(np.linalg.norm(np.asarray(label["keypoints_px"]) - true_px, axis=1).mean())
    return float(np.mean(errors))


def row(name: str, ws: Workspace) -> dict[str, Any]:
    data, samples = dataset(ws), calibration_samples(ws)
    under = (data["rotation"] < SPEEDPLUS_ROTATION_RAD) & (data["position"] < SPEEDPLUS_TRANSLATION)
    return {"unmodelled errors on": name,
            "robots E_T cal (mm)": samples["kuka"], "mocap E_T cal (mm)": samples["vicon"],
            "robots E_T dataset (mm)": float(data["kuka"].mean() * 1000),
            "mocap E_T dataset (mm)": float(data["vicon"].mean() * 1000),
            "label E_T (mm)": float(data["fused"].mean() * 1000),
            "label E_R (deg)": float(np.degrees(data["rotation"].mean())),
            "label E_R max (deg)": float(np.degrees(data["rotation"].max())),
            "under SPEED+ thresholds": float(under.mean()),
            "keypoints (px)": keypoint_error_px(ws)}


def main(seed: str = "11", root: str = "data/budget", only: str = "") -> None:
    runs = {"none": [], **{source: [source] for source in UNMODELLED_SOURCES}, "all": list(UNMODELLED_SOURCES)}
    unknown = [name for name in only.split(",") if name and name not in runs]
    if unknown:
        sys.exit(f"unknown rows {unknown}; rows: {', '.join(runs)}")
    runs = {name: sources for name, sources in runs.items() if not only or name in only.split(",")}
    rows = []
    for name, sources in runs.items():
        listed = ", ".join(f'"{s}"' for s in sources)
        ws = run_facility(Path(root) / name, int(seed), [f"virtual.unmodelled=[{listed}]"])
        rows.append(row(name, ws))
        print(rows[-1], flush=True)
    report("budget", f"label error by unmodelled error source (default profile, facility seed {seed})", rows)


if __name__ == "__main__":
    main(*sys.argv[1:])
