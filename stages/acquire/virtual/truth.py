"""The hidden truth of the virtual testbed: what the real facility would never tell us.

Drawn once from ``virtual.seed`` (so every worker process agrees on it) and written to
``W/truth.json``: the true arm dimensions and joint zero offsets, the true robot bases,
the rail scale, the true camera and model fixtures, the motion-capture rigid bodies and
the motion-capture world frame, and the errors outside the calibration's model
(``unmodelled.py``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from core.config import Config
from manifests.sidecars import TruthRecord
from manifests.sidecars.truth import HolderTruth
from stages.acquire.virtual.unmodelled import Unmodelled, draw_unmodelled
from stages.common import geometry as g
from stages.common import layout
from stages.common.json_arrays import record
from stages.common.kinematics import ArmModel, arm_model
from stages.common.robots.facility import load_facility
from stages.common.target import Target
from stages.common.workspace_target import planned_target

#: the KR 16-2's dimensions the true arms are drawn off (Craig's a and c of its data sheet), in the draw's order
ARM_LINKS = ("a1", "a2", "c1", "c2", "c3", "c4")


@dataclass(frozen=True)
class Truth:
    """True parameters; transforms (4, 4) in metres, named as everywhere else."""

    camera_arm: ArmModel
    target_arm: ArmModel
    camera_joint_offsets_rad: np.ndarray  # (6,) true angle = encoder reading + offset
    target_joint_offsets_rad: np.ndarray
    camera_base_error: np.ndarray  # true base frame = nominal base frame @ error
    target_base_error: np.ndarray
    rail_scale: float  # true rail position = reported position * rail_scale
    camee_from_cam: np.ndarray
    target_from_targetee: dict[str, np.ndarray]  # per mount, before the fixture's sag
    camee_from_camrb: np.ndarray  # camera rigid body (markers) in the camera flange frame
    target_from_targetrb: np.ndarray  # model rigid body in T
    vicon_world_from_world: np.ndarray
    unmodelled: Unmodelled

    def to_record(self, facility: dict[str, HolderTruth] | None = None) -> TruthRecord:
        """The stored form (``W/truth.json``), with the inverse offsets the estimates name; on
        a facility folder, ``facility`` (``rig.Rig.truth``) stands for TRON's arms."""
        cam_from_camee = g.invert(self.camee_from_cam)
        poses = {"camera_base_error": self.camera_base_error, "target_base_error": self.target_base_error,
                 "camee_from_cam": self.camee_from_cam, "cam_from_camee": cam_from_camee,
                 "camee_from_camrb": self.camee_from_camrb, "cam_from_camrb": cam_from_camee @ self.camee_from_camrb,
                 "target_from_targetrb": self.target_from_targetrb,
                 "vicon_world_from_world": self.vicon_world_from_world}
        stored = {key: None if facility is not None and key.endswith("base_error") else record(pose)
                  for key, pose in poses.items()}
        mounts = {m: record(t) for m, t in self.target_from_targetee.items()}
        if facility is not None:
            return TruthRecord(None, None, None, None, None, stored, mounts, self.unmodelled.to_json(), facility)
        return TruthRecord(asdict(self.camera_arm), asdict(self.target_arm),
                           tuple(self.camera_joint_offsets_rad.tolist()), tuple(self.target_joint_offsets_rad.tolist()),
                           float(self.rail_scale), stored, mounts, self.unmodelled.to_json())


def _small_transform(rng: np.random.Generator, sigma_m: float, sigma_rad: float) -> np.ndarray:
    return g.make_transform(g.rotvec_to_matrix(rng.normal(0.0, sigma_rad, 3)), rng.normal(0.0, sigma_m, 3))


def _perturbed_arm(rng: np.random.Generator, arm: ArmModel, sigma_m: float) -> ArmModel:
    changes = {name: getattr(arm, name) + rng.normal(0.0, sigma_m) for name in ARM_LINKS}
    return replace(arm, name=f"{arm.name} (true)", **changes)


def _camera_fixture(config: Config) -> np.ndarray:
    """(4, 4) the camera in its flange as designed: TRON's (``[testbed]``), or the facility
    folder's ``flange_from_tool`` of the camera's robot."""
    if not config.facility.path:
        return layout.camee_from_cam(config.testbed)
    return load_facility(Path(config.facility.path)).fixture("camera")


def draw_truth(config: Config, target: Target | None = None) -> Truth:
    """The truth of this virtual facility holding ``target`` (default: the configured one);
    identical for the same ``virtual.seed``."""
    v, testbed = config.virtual, config.testbed
    target = planned_target(config) if target is None else target
    rng = np.random.default_rng([v.seed, 0xFAC7])
    arm = arm_model(testbed.robot_model)
    mounts = {m: layout.target_from_targetee(target, m) @ _small_transform(
        rng, v.model_fixture_sigma_m, v.model_fixture_sigma_rad) for m in layout.MOUNT_NAMES}
    # the model's markers sit on its body; the rigid body's frame is where the motion-capture
    # software put it when the object was defined: at the markers' centroid, axes rotated
    target_from_targetrb = g.make_transform(g.rotvec_to_matrix(rng.normal(0, 0.6, 3)),
                                            rng.normal(0, 0.02, 3) + [0, 0, 0.08])
    camee_from_camrb = g.make_transform(g.rotvec_to_matrix(rng.normal(0, 0.6, 3)), rng.normal(0, 0.02, 3))
    return Truth(
        camera_arm=_perturbed_arm(rng, arm, v.link_length_sigma_m),
        target_arm=_perturbed_arm(rng, arm, v.link_length_sigma_m),
        camera_joint_offsets_rad=rng.normal(0.0, v.joint_offset_sigma_rad, 6),
        target_joint_offsets_rad=rng.normal(0.0, v.joint_offset_sigma_rad, 6),
        camera_base_error=_small_transform(rng, v.base_position_sigma_m, v.base_rotation_sigma_rad),
        target_base_error=_small_transform(rng, v.base_position_sigma_m, v.base_rotation_sigma_rad),
        rail_scale=1.0 + rng.normal(0.0, v.rail_scale_sigma),
        camee_from_cam=_camera_fixture(config) @ _small_transform(
            rng, v.camera_fixture_sigma_m, v.camera_fixture_sigma_rad),
        target_from_targetee=mounts,
        camee_from_camrb=camee_from_camrb,
        target_from_targetrb=target_from_targetrb,
        vicon_world_from_world=g.transform_from_qt(v.vicon_world_from_world_q, v.vicon_world_from_world_t_m),
        unmodelled=draw_unmodelled(config),
    )
