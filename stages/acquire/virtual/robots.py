"""What the robots do and what their controllers report.

The controller servos each joint to the commanded angle (within the repeatability) and
reports the nominal forward kinematics of its encoder readings. The true arm has other
link lengths and encoder zero offsets, its base is not exactly where the lab measured
it, the rail scale is off, and the model's fixture sags under the model's weight. The
resulting telemetry errors depend on the pose, as on a real arm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.config import Config
from stages.acquire.virtual.truth import Truth
from stages.common import geometry as g
from stages.common import layout, tango
from stages.common.kinematics import arm_model, forward

GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class RobotState:
    """One capture's robot poses (4, 4) in K: reported (telemetry) and true."""

    kuka_world_from_camee: np.ndarray
    kuka_world_from_targetee: np.ndarray
    world_from_camee: np.ndarray  # true
    world_from_targetee: np.ndarray  # true
    world_from_cam: np.ndarray  # true camera
    world_from_target: np.ndarray  # true model, sag included
    camera_joints_rad: np.ndarray  # encoder readings
    target_joints_rad: np.ndarray
    rail_m: float  # reported
    sag_rad: float


def sag(world_from_targetee: np.ndarray, targetee_from_target: np.ndarray, mass_kg: float,
        compliance_rad_per_nm: float, centre_target_m: np.ndarray) -> tuple[np.ndarray, float]:
    """The fixture's rotation (4, 4, in the flange frame, about the flange origin) under the
    gravity moment of the model, and its angle (rad). Small-angle linear compliance."""
    centre_world = g.apply(world_from_targetee @ targetee_from_target, centre_target_m[None])[0]
    lever = centre_world - world_from_targetee[:3, 3]
    moment = np.cross(lever, [0.0, 0.0, -mass_kg * GRAVITY_M_S2])  # N m, world frame
    rotvec_flange = world_from_targetee[:3, :3].T @ (compliance_rad_per_nm * moment)
    return g.make_transform(g.rotvec_to_matrix(rotvec_flange), np.zeros(3)), float(np.linalg.norm(rotvec_flange))


def move(config: Config, truth: Truth, row: dict[str, Any], rng: np.random.Generator) -> RobotState:
    """Drive both robots to a plan row's commands; ``rng`` draws the servo noise."""
    v, testbed = config.virtual, config.testbed
    nominal = arm_model(testbed.robot_model)
    camera_joints = np.asarray(row["camera_joints_rad"]) + rng.normal(0.0, v.repeatability_rad, 6)
    target_joints = np.asarray(row["target_joints_rad"]) + rng.normal(0.0, v.repeatability_rad, 6)
    rail = float(row["rail_m"]) + rng.normal(0.0, v.rail_noise_m)

    kuka_world_from_camee = layout.world_from_camera_base(testbed, rail) @ forward(nominal, camera_joints)
    kuka_world_from_targetee = layout.world_from_target_base(testbed) @ forward(nominal, target_joints)

    world_from_camee = (layout.world_from_camera_base(testbed, rail * truth.rail_scale) @ truth.camera_base_error
                        @ forward(truth.camera_arm, camera_joints + truth.camera_joint_offsets_rad))
    world_from_targetee = (layout.world_from_target_base(testbed) @ truth.target_base_error
                           @ forward(truth.target_arm, target_joints + truth.target_joint_offsets_rad))
    targetee_from_target = g.invert(truth.target_from_targetee[row["mount"]])
    centre = tango.BODY_CENTRE_M * testbed.mockup_scale
    tilt, sag_rad = sag(world_from_targetee, targetee_from_target, v.model_mass_kg,
                        v.model_compliance_rad_per_nm, centre)
    return RobotState(
        kuka_world_from_camee=kuka_world_from_camee,
        kuka_world_from_targetee=kuka_world_from_targetee,
        world_from_camee=world_from_camee,
        world_from_targetee=world_from_targetee,
        world_from_cam=world_from_camee @ truth.camee_from_cam,
        world_from_target=world_from_targetee @ tilt @ targetee_from_target,
        camera_joints_rad=camera_joints,
        target_joints_rad=target_joints,
        rail_m=rail,
        sag_rad=sag_rad,
    )
