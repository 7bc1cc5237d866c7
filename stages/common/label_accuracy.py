"""How good a run's labels are against the virtual testbed's hidden truth: each label's
rotation and normalised position error, as the SPEED+ paper states the precision its labels
must reach (Park et al. 2022: ``e_q < 0.169 deg`` and ``e_t < 2.173e-3``, the thresholds of
its score, ``stages/common/scores.py``), and the fused pose's error per camera axis over its
sigma (docs/architecture.md section 6).

A lab's real recording has no truth: what stands in for it is the facility's rehearsal
(``python -m bench honesty --facility DIR``) and Table 1's cross-validated column.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from stages.common import geometry as g
from stages.common.robots.facility import wilson
from stages.common.scores import ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD


@dataclass(frozen=True)
class LabelAccuracy:
    """Per label (N,): ``rotation_rad`` and ``position`` (|error| / range, full scale, as
    SPEED+'s ``e_t``); per label and camera axis (N, 3): ``axis_error_m`` and
    ``axis_sigma_m`` of the fused pose (mock-up scale)."""

    rotation_rad: np.ndarray
    position: np.ndarray
    position_error_m: np.ndarray
    axis_error_m: np.ndarray
    axis_sigma_m: np.ndarray

    @property
    def under_speedplus(self) -> np.ndarray:
        """(N,) bool: both errors strictly under SPEED+'s thresholds."""
        return (self.rotation_rad < ROTATION_THRESHOLD_RAD) & (self.position < TRANSLATION_THRESHOLD)

    def share(self) -> tuple[int, int, float, float]:
        """(labels under both thresholds, labels, and the share's 95% Wilson interval)."""
        under = int(self.under_speedplus.sum())
        low, high = wilson(under, len(self.position))
        return under, len(self.position), low, high

    def inside_1_96_sigma(self) -> np.ndarray:
        """(3,) the share of the fused errors within 1.96 sigma, per camera axis."""
        return np.mean(np.abs(self.axis_error_m) <= 1.96 * self.axis_sigma_m, axis=0)


def label_accuracy(truth: list[dict[str, Any]], labels: list[dict[str, Any]], poses: list[dict[str, Any]],
                   mockup_scale: float) -> LabelAccuracy:
    """The errors of every label that has its truth and its fused pose (``truth``,
    ``labels`` and ``poses`` manifest rows; ``mockup_scale``: mock-up size over real size)."""
    by_id = {row["sample_id"]: row for row in truth}
    fused = {row["sample_id"]: row for row in poses}
    out: dict[str, list] = {"rotation": [], "position": [], "metres": [], "error": [], "sigma": []}
    for label in labels:
        true_row, pose = by_id.get(label["sample_id"]), fused.get(label["sample_id"])
        if true_row is None or pose is None:
            continue
        true = g.transform_from_qt(true_row["cam_from_target_q"], true_row["cam_from_target_t"])
        true_full = true[:3, 3] / mockup_scale
        out["rotation"].append(g.quat_angular_distance(label["q_vbs2tango_true"], g.matrix_to_quat(true[:3, :3])))
        error = np.linalg.norm(np.asarray(label["r_Vo2To_vbs_true"]) - true_full)
        out["position"].append(error / np.linalg.norm(true_full))
        out["metres"].append(error * mockup_scale)
        estimate = g.transform_from_qt(pose["cam_from_target_q"], pose["cam_from_target_t"])
        out["error"].append(estimate[:3, 3] - true[:3, 3])
        out["sigma"].append(pose["sigma_t_m"])
    return LabelAccuracy(np.array(out["rotation"]), np.array(out["position"]), np.array(out["metres"]),
                         np.array(out["error"]).reshape(-1, 3), np.array(out["sigma"], float).reshape(-1, 3))
