"""Label accuracy on a virtual-testbed workspace (issue: calibration, fusion, labels), for
this program's method and for the paper's (rigid fixtures, calibrated sigmas as they are),
run on a copy of the same captures:

(a) Table 1 in-sample against the paper (within a factor of two?), (b) fused labels of
the calibration samples against the truth vs the paper's fused figures, (c) the share of
dataset labels whose true error is under the SPEED+ score thresholds, (d) fusion against
each single source, (e) honesty of the reported sigmas (share of true errors inside 1.96
sigma, per axis, of the labels and of each source).

    python -m bench accuracy WORKSPACE      (after `speedplus run --until label`)
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import report
from manifests import Workspace, read_manifest
from manifests.sidecars import read_calibration, read_fusion
from stages.common import geometry as g
from stages.common.scores import ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD
from stages.common.tables import PAPER

#: the SPEED+ label precision, defined once (stages/common/scores.py)
SPEEDPLUS_ROTATION_RAD, SPEEDPLUS_TRANSLATION = ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD
#: nominal arms, rigid fixtures, the calibrated sigmas as they are: no variance factor, no
#: motion-capture scale growth (lost motion needs calibrated arms: off with them)
PAPERS_METHOD = ("calibrate.fixture_compliance=off", "calibrate.arm_kinematics=off", "fuse.sigma_scale=calibration",
                 "fuse.vicon_scale_sigma=0", "fuse.session_offset=off")


def table1_rows(ws: Workspace, method: str) -> list[dict[str, Any]]:
    calibration = read_calibration(ws).to_json()
    # the paper's camera is 1920 px wide: pixel errors compare at that resolution
    to_paper_px = 1920 / calibration["intrinsics"]["width"]
    rows = []
    for source in ("kuka", "vicon", "fused"):
        entry = calibration.get(source)
        if not entry:
            continue
        for index, (key, scale, unit) in enumerate((("E_T_m", 1000, "mm"), ("E_R_rad", np.degrees(1), "deg"),
                                                    ("E_p_px", to_paper_px, "px at 1920"))):
            for kind in ("in_sample", "cross_validated", "truth"):
                metric = entry["metrics"].get(kind)
                if metric is None:
                    continue
                paper = PAPER[source][index][0]
                value = metric[key][0] * scale
                rows.append({"method": method, "source": source, "metric": f"{key[:3]} [{unit}]", "kind": kind,
                             "value": value, "paper": paper, "ratio": value / paper,
                             "within_2x": "yes" if 0.5 <= value / paper <= 2 else "no"})
    return rows


def dataset_metrics(ws: Workspace) -> dict[str, float]:
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    poses = read_manifest(ws, "poses").to_pylist()
    labels = {r["sample_id"]: r for r in read_manifest(ws, "labels").to_pylist()}
    scale = json.loads(ws.session_path.read_text())["mockup_scale"]
    error_t, error_r, inside, sources = [], [], [], {"kuka": [], "vicon": [], "fused": []}
    for pose in poses:
        true = g.transform_from_qt(truth[pose["sample_id"]]["cam_from_target_q"],
                                   truth[pose["sample_id"]]["cam_from_target_t"])
        fused = g.transform_from_qt(pose["cam_from_target_q"], pose["cam_from_target_t"])
        label = labels[pose["sample_id"]]
        true_full = true[:3, 3] / scale
        error_t.append(np.linalg.norm(np.asarray(label["r_Vo2To_vbs_true"]) - true_full) / np.linalg.norm(true_full))
        error_r.append(g.quat_angular_distance(label["q_vbs2tango_true"], g.matrix_to_quat(true[:3, :3])))
        inside.append(np.abs(fused[:3, 3] - true[:3, 3]) <= 1.96 * np.asarray(pose["sigma_t_m"]))
        for source in ("kuka", "vicon"):
            if pose[f"{source}_cam_from_target_q"] is not None:
                estimate = g.transform_from_qt(pose[f"{source}_cam_from_target_q"], pose[f"{source}_cam_from_target_t"])
                sources[source].append(np.linalg.norm(estimate[:3, 3] - true[:3, 3]))
        sources["fused"].append(np.linalg.norm(fused[:3, 3] - true[:3, 3]))
    error_t, error_r, inside = np.array(error_t), np.array(error_r), np.array(inside)
    factor = read_fusion(ws).to_json()["variance_factor"] if ws.fusion_path.exists() else None
    return {
        "dataset labels": len(poses),
        "motion capture accepted (fraction)": float(np.mean([p["vicon_accepted"] for p in poses])),
        "rotation error < 0.169 deg (fraction)": float(np.mean(error_r < SPEEDPLUS_ROTATION_RAD)),
        "normalised position error < 2.173e-3 (fraction)": float(np.mean(error_t < SPEEDPLUS_TRANSLATION)),
        "both (fraction)": float(np.mean((error_r < SPEEDPLUS_ROTATION_RAD) & (error_t < SPEEDPLUS_TRANSLATION))),
        "rotation error, mean (deg)": float(np.degrees(error_r.mean())),
        "rotation error, max (deg)": float(np.degrees(error_r.max())),
        "normalised position error, mean": float(error_t.mean()),
        **{f"mean E_T vs truth, {s} (mm)": float(np.mean(v) * 1000) for s, v in sources.items() if v},
        **{f"true error inside 1.96 sigma, camera {a} (fraction)": float(inside[:, i].mean())
           for i, a in enumerate("xyz")},
        **({f"position sigma factor {a}": factor["t"][i] for i, a in enumerate("xyz")} if factor else {}),
        **({"rotation sigma factor": factor["r"]} if factor else {}),
    }


def papers_method(root: Path, directory: str) -> Workspace:
    """calibrate, fuse and label again on a copy, with the paper's method."""
    copy = Path(directory) / "papers_method"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("renders", "report", "export"))
    for stage in ("calibrate", "fuse", "label"):
        settings = [a for s in PAPERS_METHOD for a in ("--set", s)]
        result = subprocess.run([sys.executable, "-m", "pipeline.cli", stage, "--workspace", str(copy), "--force",
                                 *settings], capture_output=True, text=True)
        if result.returncode != 0:
            raise SystemExit(result.stderr)
    return Workspace(copy)


def main(root: str = "data/default") -> None:
    ours = Workspace(root)
    with tempfile.TemporaryDirectory() as directory:
        paper = papers_method(Path(root), directory)
        report("accuracy_table1", "calibration metrics vs TRON's Table 1 (this program's method, then the paper's)",
               table1_rows(ours, "ours") + table1_rows(paper, "paper's"))
        metrics = {"ours": dataset_metrics(ours), "paper's": dataset_metrics(paper)}
    rows = [{"metric": name, "ours": value, "paper's method": metrics["paper's"].get(name, float("nan"))}
            for name, value in metrics["ours"].items()]
    report("accuracy_dataset", "dataset labels against the hidden truth", rows)


if __name__ == "__main__":
    main(*sys.argv[1:])
