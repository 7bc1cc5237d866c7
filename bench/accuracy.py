"""Label accuracy on a virtual-testbed workspace (issue: calibration, fusion, labels):

(a) Table 1 in-sample against the paper (within a factor of two?), (b) fused labels of
the calibration samples against the truth vs the paper's fused figures, (c) the share of
dataset labels whose true error is under the SPEED+ score thresholds, (d) fusion against
each single source, (e) honesty of the reported sigmas (share of true errors inside 1.96
sigma, per axis).

    python -m bench accuracy WORKSPACE      (after `speedplus run --until label`)
"""

from __future__ import annotations

import json
import sys

import numpy as np

from bench.common import report
from manifests import Workspace, read_manifest
from stages import geometry as g
from stages.calibrate.table import PAPER

SPEEDPLUS_ROTATION_RAD = np.radians(0.169)
SPEEDPLUS_TRANSLATION = 2.173e-3


def main(root: str = "data/default") -> None:
    ws = Workspace(root)
    calibration = json.loads((ws.root / "calibration.json").read_text())
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
                rows.append({"source": source, "metric": f"{key[:3]} [{unit}]", "kind": kind, "value": value,
                             "paper": paper, "ratio": value / paper,
                             "within_2x": "yes" if 0.5 <= value / paper <= 2 else "no"})
    report("accuracy_table1", "calibration metrics vs TRON's Table 1", rows)

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
    accepted = np.mean([p["vicon_accepted"] for p in poses])
    dataset = [
        {"metric": "dataset labels", "value": len(poses)},
        {"metric": "motion capture accepted (fraction)", "value": float(accepted)},
        {"metric": "rotation error < 0.169 deg (fraction)", "value": float(np.mean(error_r < SPEEDPLUS_ROTATION_RAD))},
        {"metric": "normalised position error < 2.173e-3 (fraction)",
         "value": float(np.mean(error_t < SPEEDPLUS_TRANSLATION))},
        {"metric": "both (fraction)",
         "value": float(np.mean((error_r < SPEEDPLUS_ROTATION_RAD) & (error_t < SPEEDPLUS_TRANSLATION)))},
        {"metric": "rotation error, mean (deg)", "value": float(np.degrees(error_r.mean()))},
        {"metric": "normalised position error, mean", "value": float(error_t.mean())},
        *({"metric": f"mean E_T vs truth, {s} (mm)", "value": float(np.mean(v) * 1000)} for s, v in sources.items()
          if v),
        *({"metric": f"true error inside 1.96 sigma, camera {a} (fraction)", "value": float(inside[:, i].mean())}
          for i, a in enumerate("xyz")),
    ]
    report("accuracy_dataset", "dataset labels against the hidden truth", dataset)


if __name__ == "__main__":
    main(*sys.argv[1:])
