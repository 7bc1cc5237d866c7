"""The label stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

Full-scale translation (mock-up translation / scale), the quaternion of
``cam_from_target``, the workspace target's keypoints projected through the calibrated
camera (with lens distortion), their bounding box, its view, and the label's 1-sigma
uncertainty. Reads ``poses``, the session, the calibration and ``W/target``; never the truth.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from core.config import Config
from core.progress import track
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest, read_marker
from manifests.schema import DOMAINS
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common.json_arrays import calibrated_camera
from stages.common.model_input import points_box
from stages.common.target import Target
from stages.common.workspace_target import workspace_target


def label_row(pose: dict[str, Any], plan: dict[str, Any] | None, camera_matrix: np.ndarray, dist: np.ndarray,
              target: Target, filename: str) -> dict[str, Any]:
    scale = target.mockup_scale
    cam_from_target = g.transform_from_qt(pose["cam_from_target_q"], pose["cam_from_target_t"])
    keypoints = g.project(cam_from_target, target.keypoints_m * scale, camera_matrix, dist)
    camera_in_target = g.invert(cam_from_target)[:3, 3]
    light = plan["light"] if plan is not None else "lightbox"
    if light not in DOMAINS:
        raise InputError(f"plan: dataset sample {pose['sample_id']} has light {light!r}; "
                         "labels need lightbox or sunlamp")
    q, t = g.transform_to_qt(cam_from_target)
    return {
        "sample_id": pose["sample_id"],
        "filename": filename,
        "domain": light,
        "view": str(target.view_of(camera_in_target, scale)),
        "q_vbs2tango_true": q,
        "r_Vo2To_vbs_true": t / scale,
        "label_source": "fused" if pose["vicon_accepted"] else "kuka_only",
        "sigma_t_m": np.asarray(pose["sigma_t_m"]) / scale,
        "sigma_r_rad": pose["sigma_r_rad"],
        "keypoints_px": keypoints,
        "bbox_px": points_box(keypoints),
    }



def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the fused poses (and the calibration, the session); writes ``labels``."""
    return Resolved(("poses",), ("label",), {}, ("labels",))


def run(config: Config, workspace: Workspace) -> pa.Table:
    camera = calibrated_camera(workspace)
    camera_matrix, dist = camera.camera_matrix, camera.dist
    target = workspace_target(config, workspace)
    plan = ({r["sample_id"]: r for r in read_manifest(workspace, "plan").to_pylist()}
            if read_marker(workspace, "plan") is not None else {})
    done = read_keys(workspace, "labels")
    poses = sorted((p for p in read_manifest(workspace, "poses").to_pylist() if p["sample_id"] not in done),
                   key=lambda p: p["sample_id"])
    with open_sink(workspace, "labels", config.run.part_rows) as sink:
        for pose in track(poses, len(poses), "label"):
            filename = config.label.filename_template.format(sample_id=pose["sample_id"])
            sink.add(label_row(pose, plan.get(pose["sample_id"]), camera_matrix, dist, target, filename))
    return read_manifest(workspace, "labels")
