"""The fuse stage: per dataset capture, the pose from each source through its calibrated
offsets, the motion-capture rejection test, and the Bayesian fusion (DESIGN section 6).

It reads the captures and ``W/calibration.json``, never the truth.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pyarrow as pa

from manifests import Workspace, open_sink, read_keys, read_manifest
from pipeline.config import Config
from pipeline.errors import InputError
from pipeline.progress import track
from stages import geometry as g
from stages.calibrate import measurement
from stages.fusion import Sigma, at_position, fuse, rejection_reason

CALIBRATION_FILE = "calibration.json"


class SourceModel:
    """One source's calibrated offsets and uncertainty."""

    def __init__(self, entry: dict[str, Any], z_name: str, x_name: str, calibration_lever_sq: np.ndarray) -> None:
        self.z = g.pose_from_json(entry[z_name])
        self.x = {fixture: g.pose_from_json(pose) for fixture, pose in entry[f"{x_name}_by_fixture"].items()}
        self.sigma = Sigma.from_json(entry)
        self.calibration_lever_sq = calibration_lever_sq

    def estimate(self, b: np.ndarray, fixture: str, sample_id: str) -> np.ndarray:
        if fixture not in self.x:
            raise InputError(f"captures: sample {sample_id} uses fixture {fixture!r}, which the calibration did not "
                             f"see (calibrated: {', '.join(sorted(self.x))}); add calibration captures with it")
        return self.z @ b @ g.invert(self.x[fixture])

    def sigma_at(self, pose: np.ndarray) -> Sigma:
        return at_position(self.sigma, pose[:3, 3], self.calibration_lever_sq)


def load_models(workspace: Workspace) -> tuple[SourceModel, SourceModel | None, Sigma | None]:
    path = workspace.root / CALIBRATION_FILE
    if not path.exists():
        raise InputError(f"{path}: missing; run calibrate first")
    calibration = json.loads(path.read_text())
    lever = np.array(calibration["calibration_lever_sq_m2"])
    kuka = SourceModel(calibration["kuka"], "cam_from_camee", "target_from_targetee", lever)
    vicon = None
    rejection = None
    if calibration.get("vicon"):
        vicon = SourceModel(calibration["vicon"], "cam_from_camrb", "target_from_targetrb", lever)
        rejection = Sigma.from_json(calibration["rejection"])
    return kuka, vicon, rejection


def fuse_capture(row: dict[str, Any], kuka: SourceModel, vicon: SourceModel | None,
                 rejection: Sigma | None, rejection_k: float) -> dict[str, Any]:
    """One ``poses`` row."""
    kuka_pose = kuka.estimate(measurement(row, "kuka"), row["fixture"], row["sample_id"])
    vicon_pose = None
    reason = "no motion capture in this session"
    if vicon is not None:
        b = measurement(row, "vicon")
        vicon_pose = None if b is None else vicon.estimate(b, row["fixture"], row["sample_id"])
        reason = rejection_reason(kuka_pose, vicon_pose,
                                  at_position(rejection, kuka_pose[:3, 3], kuka.calibration_lever_sq), rejection_k)
    if reason is None:
        fused, sigma = fuse(kuka_pose, kuka.sigma_at(kuka_pose), vicon_pose, vicon.sigma_at(vicon_pose))
    else:
        fused, sigma = kuka_pose, kuka.sigma_at(kuka_pose)
    q_k, t_k = g.transform_to_qt(kuka_pose)
    q_v, t_v = g.transform_to_qt(vicon_pose) if vicon_pose is not None else (None, None)
    q, t = g.transform_to_qt(fused)
    return {"sample_id": row["sample_id"], "kuka_cam_from_target_q": q_k, "kuka_cam_from_target_t": t_k,
            "vicon_cam_from_target_q": q_v, "vicon_cam_from_target_t": t_v, "vicon_accepted": reason is None,
            "reject_reason": reason, "cam_from_target_q": q, "cam_from_target_t": t,
            "sigma_t_m": sigma.t_m, "sigma_r_rad": sigma.r_rad}


def run(config: Config, workspace: Workspace) -> pa.Table:
    kuka, vicon, rejection = load_models(workspace)
    done = read_keys(workspace, "poses")
    rows = [r for r in read_manifest(workspace, "captures").to_pylist()
            if r["session"] == "dataset" and r["status"] == "ok" and r["sample_id"] not in done]
    with open_sink(workspace, "poses", config.run.part_rows) as sink:
        for row in track(rows, len(rows), "fuse"):
            sink.add(fuse_capture(row, kuka, vicon, rejection, config.fuse.rejection_k))
    return read_manifest(workspace, "poses")
