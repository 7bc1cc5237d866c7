"""What the report opens with (issue 59): how good the labels are, and whether they meet the
SPEED+ thresholds; then the domain gap in one line a model; the tables follow.

- On the virtual testbed the labels are measured against its hidden truth (the truth
  manifest: ``stages/common/label_accuracy.py``).
- On a facility folder, its rehearsal (``DIR/rehearsal.json``) says what a real run's labels
  can expect; a recording has no truth, so Table 1's cross-validated fused column and the
  labels' own sigmas are what it has.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from core.config import Config
from manifests import Workspace, read_manifest, read_marker
from manifests.sidecars import Calibration, read_session
from stages.common.facility_report import rehearsal_text
from stages.common.label_accuracy import label_accuracy
from stages.common.scores import ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD

THRESHOLDS = (f"rotation under {np.degrees(ROTATION_THRESHOLD_RAD):.3f} deg and position under "
              f"{1000 * TRANSLATION_THRESHOLD:.3f} mm per metre of range")


def labels_sentence(config: Config, workspace: Workspace, calibration: Calibration, labels: list[dict[str, Any]],
                    poses: list[dict[str, Any]]) -> str:
    """The labels' accuracy as this run can know it, in one paragraph of HTML."""
    said = []
    session = read_session(workspace)
    if read_marker(workspace, "truth") is not None and session.mockup_scale:
        accuracy = label_accuracy(read_manifest(workspace, "truth").to_pylist(), labels, poses, session.mockup_scale)
        if len(accuracy.position):
            under, count, low, high = accuracy.share()
            inside = "/".join(f"{v:.0%}" for v in accuracy.inside_1_96_sigma())
            said.append(f"<strong>{under} of {count} labels ({under / count:.0%}, 95% interval {low:.0%}-{high:.0%}) "
                        f"meet both SPEED+ thresholds</strong> ({THRESHOLDS}), against the virtual testbed's hidden "
                        f"truth: mean error {1000 * float(np.mean(accuracy.position_error_m)):.2f} mm at mock-up "
                        f"scale and {np.degrees(float(np.mean(accuracy.rotation_rad))):.3f} deg; their sigmas hold "
                        f"{inside} of the errors within 1.96 sigma (camera x/y/z).")
    if config.facility.path:
        said.append(f"The facility's rehearsal: {html.escape(rehearsal_text(Path(config.facility.path)))}.")
    if not said:  # a recording: no truth
        said.append(_recording_sentence(calibration, labels))
    return "<p>" + " ".join(said) + "</p>"


def _recording_sentence(calibration: Calibration, labels: list[dict[str, Any]]) -> str:
    """A recording has no truth: the calibration's cross-validated accuracy and the labels'
    own sigmas are what it can say."""
    fused = calibration.fused
    cross = fused.metrics.cross_validated if fused is not None else None
    sigma = [1000 * float(np.linalg.norm(row["sigma_t_m"])) for row in labels if row.get("sigma_t_m") is not None]
    parts = ["A recording has no truth to measure the labels against"]
    if cross is not None:
        parts.append(f"the calibration's cross-validated fused error is {1000 * cross.E_T_m[0]:.2f} mm and "
                     f"{np.degrees(cross.E_R_rad[0]):.3f} deg (Table 1)")
    if sigma:
        parts.append(f"the labels' own position sigmas are {np.median(sigma):.1f} mm at the median (full scale)")
    parts.append("a virtual rehearsal of the facility (python -m bench honesty --facility DIR) says what share "
                 f"of labels meets the SPEED+ thresholds ({THRESHOLDS})")
    return html.escape("; ".join(parts) + ".")


def gap_sentence(scores: list[dict[str, Any]], models: list[str], crops: list[str]) -> str:
    """The domain gap in one line a model (its first crop): mean SPEED score on the twins and
    on the testbed images, with their intervals."""
    by_group = {row["group"]: row for row in scores}
    lines = []
    for model in models:
        crop = next((c for c in crops if f"{model}/{c}/testbed/all/all" in by_group), None)
        if crop is None:
            continue
        test, twin = by_group[f"{model}/{crop}/testbed/all/all"], by_group.get(f"{model}/{crop}/synthetic/all/all")
        shown = f"{_mean(twin)} on the twins, " if twin else ""
        lines.append(f"<li>{html.escape(model)} ({html.escape(crop.replace('_', ' '))}): mean SPEED score {shown}"
                     f"{_mean(test)} on the testbed images ({test['count']} images; Table 2 below)</li>")
    return f"<p>The domain gap:</p><ul>{''.join(lines)}</ul>" if lines else ""


def _mean(row: dict[str, Any]) -> str:
    return f"{row['mean_score_speed']:.3f} [{row['mean_score_speed_low']:.3f}, {row['mean_score_speed_high']:.3f}]"
