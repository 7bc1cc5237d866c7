"""What the robots do and what their controllers report.

The controller servos each joint's motor to the commanded angle (within the
repeatability) and reports the nominal forward kinematics of its encoder readings. The
true arm has other link lengths and encoder zero offsets, its base is not exactly where
the lab measured it, the rail scale is off, and the model's fixture sags under the model's
weight. Beyond what calibrate models (``unmodelled.py``): each link turns past its motor
by the gearbox's windup under gravity and by half its lost motion, on the flank its load
or its last move (``timeline.py``) pushes it to; links and rail grow with temperature; the
fixture bends more about one axis than another and the model is remounted between the
sessions. The resulting telemetry errors depend on the pose and the history, as on a real
arm.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from core.config import Config
from stages.acquire.virtual.timeline import Moment
from stages.acquire.virtual.truth import Truth
from stages.acquire.virtual.unmodelled import Unmodelled
from stages.common import geometry as g
from stages.common import layout
from stages.common.arms import Payload
from stages.common.kinematics import ArmModel, arm_model, forward
from stages.common.statics import GRAVITY_M_S2, gravity_torques
from stages.common.workspace_target import planned_target

_LENGTHS = ("a1", "a2", "b", "c1", "c2", "c3", "c4")


@dataclass(frozen=True)
class RobotState:
    """One capture's robot poses (4, 4) in K: reported (telemetry) and true."""

    kuka_world_from_camee: np.ndarray
    kuka_world_from_targetee: np.ndarray
    world_from_camee: np.ndarray  # true
    world_from_targetee: np.ndarray  # true
    world_from_cam: np.ndarray  # true camera
    world_from_target: np.ndarray  # true model, sag included
    camera_joints_rad: np.ndarray | None  # encoder readings; None: a facility's static mount
    target_joints_rad: np.ndarray | None
    rail_m: float  # reported
    sag_rad: float
    camera_link_rad: np.ndarray | None  # true link angles (J,)
    target_link_rad: np.ndarray | None
    camera_arm: ArmModel | None  # TRON's: true, at this moment's temperature; None on a facility (rig.py)
    target_arm: ArmModel | None
    world_from_camera_base: np.ndarray  # true (4, 4)
    world_from_target_base: np.ndarray


def sag(world_from_targetee: np.ndarray, targetee_from_target: np.ndarray, mass_kg: float,
        compliance_rad_per_nm: float, centre_target_m: np.ndarray,
        shape: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The fixture's rotation (4, 4, in the flange frame, about the flange origin) under the
    gravity moment of the model, and its angle (rad). Small-angle linear compliance, the
    same about every axis unless ``shape`` (3, 3, flange frame) makes it anisotropic."""
    centre_world = g.apply(world_from_targetee @ targetee_from_target, centre_target_m[None])[0]
    lever = centre_world - world_from_targetee[:3, 3]
    moment = np.cross(lever, [0.0, 0.0, -mass_kg * GRAVITY_M_S2])  # N m, world frame
    rotvec_flange = world_from_targetee[:3, :3].T @ (compliance_rad_per_nm * moment)
    if shape is not None:
        rotvec_flange = shape @ rotvec_flange
    return g.make_transform(g.rotvec_to_matrix(rotvec_flange), np.zeros(3)), float(np.linalg.norm(rotvec_flange))


def play(change_rad: np.ndarray, width_rad: float) -> np.ndarray:
    """The fixture's lag (4, 4, flange frame) behind its elastic tilt: micro-slip in its
    clamped joints holds it back by up to ``width_rad`` against the direction its tilt last
    changed in (``change_rad`` (3,), rotation vector), a play operator."""
    size = float(np.linalg.norm(change_rad))
    if size == 0.0:
        return np.eye(4)
    return g.make_transform(g.rotvec_to_matrix(-min(size, width_rad) * change_rad / size), np.zeros(3))


def warming_k(u: Unmodelled, session: str, time_s: float, time_constant_s: float) -> float:
    """The arms' warming (K) at ``time_s`` of a session: first-order approach to the
    steady state from the session's starting state."""
    start = u.thermal_start_k[session]
    return u.thermal_rise_k + (start - u.thermal_rise_k) * float(np.exp(-time_s / time_constant_s))


def expanded(arm: ArmModel, strain: float) -> ArmModel:
    """``arm`` with every dimension grown by ``strain`` (thermal expansion)."""
    if strain == 0.0:
        return arm
    return replace(arm, **{name: getattr(arm, name) * (1.0 + strain) for name in _LENGTHS})


def link_errors(u: Unmodelled, robot: str, arm: ArmModel, world_from_base: np.ndarray, joints: np.ndarray,
                direction: np.ndarray, payload_kg: float, flange_payload_m: np.ndarray) -> np.ndarray:
    """How far (6,) rad each link turns past its motor's angle ``joints``: gearbox windup
    under the gravity torque, and half the lost motion towards the flank the load (above
    the preload torque) or else the last move (``direction`` (6,)) pushes it to."""
    stiffness, lost = u.stiffness_nm_per_rad[robot], u.lost_motion_rad[robot]
    if np.all(np.isinf(stiffness)) and not np.any(lost):
        return np.zeros(6)
    torque = gravity_torques(arm, u.masses[robot], world_from_base, joints, payload_kg, flange_payload_m)
    flank = np.where(np.abs(torque) > u.backlash_preload_nm, np.sign(torque), direction)
    return torque / stiffness + 0.5 * lost * flank


def move(config: Config, truth: Truth, row: dict[str, Any], rng: np.random.Generator,
         moment: Moment | None = None, payload: Payload | None = None) -> RobotState:
    """Drive both robots to a plan row's commands; ``rng`` draws the servo noise; ``moment``
    is the capture's place in its session (``timeline.timeline``; None: the session's start
    with the robots' initial move directions); ``payload``: the mock-up on the target
    flange (None: the configured target's). Kept in one piece (66 lines): its draws from
    ``rng`` come in one fixed order, which the same-bytes guarantee depends on."""
    v, testbed, u = config.virtual, config.testbed, truth.unmodelled
    payload = Payload.of(planned_target(config)) if payload is None else payload
    session = row["session"]
    nominal = arm_model(testbed.robot_model)
    camera_joints = np.asarray(row["camera_joints_rad"]) + rng.normal(0.0, v.repeatability_rad, 6)
    target_joints = np.asarray(row["target_joints_rad"]) + rng.normal(0.0, v.repeatability_rad, 6)
    rail = float(row["rail_m"]) + rng.normal(0.0, v.rail_noise_m)
    if moment is None:
        moment = Moment(0.0, u.start_direction["camera"], u.start_direction["target"])

    kuka_world_from_camee = layout.world_from_camera_base(testbed, rail) @ forward(nominal, camera_joints)
    kuka_world_from_targetee = layout.world_from_target_base(testbed) @ forward(nominal, target_joints)

    warming = warming_k(u, session, moment.time_s, v.thermal_time_constant_s)
    camera_arm = expanded(truth.camera_arm, v.link_expansion_per_k * warming)
    target_arm = expanded(truth.target_arm, v.link_expansion_per_k * warming)
    room_k = u.room_change_k if session == "dataset" else 0.0
    rail_scale = truth.rail_scale * (1.0 + v.rail_expansion_per_k * room_k)
    targetee_from_target = g.invert(truth.target_from_targetee[row["mount"]]
                                    @ (u.remount[row["mount"]] if session == "dataset" else np.eye(4)))
    centre = np.asarray(payload.centre_m, float)

    camera_base = layout.world_from_camera_base(testbed, rail * rail_scale) @ truth.camera_base_error
    target_base = layout.world_from_target_base(testbed) @ truth.target_base_error
    camera_links = camera_joints + truth.camera_joint_offsets_rad
    target_links = target_joints + truth.target_joint_offsets_rad
    camera_links = camera_links + link_errors(u, "camera", camera_arm, camera_base, camera_links,
                                              moment.camera_direction, u.camera_payload_kg,
                                              0.5 * truth.camee_from_cam[:3, 3])
    target_links = target_links + link_errors(u, "target", target_arm, target_base, target_links,
                                              moment.target_direction, payload.mass_kg,
                                              g.apply(targetee_from_target, centre[None])[0])
    world_from_camee = camera_base @ forward(camera_arm, camera_links)
    world_from_targetee = target_base @ forward(target_arm, target_links)
    shape = u.mount_compliance if "mount" in v.unmodelled else None
    tilt, sag_rad = sag(world_from_targetee, targetee_from_target, payload.mass_kg,
                        v.model_compliance_rad_per_nm, centre, shape)
    if shape is not None and moment.previous_target_joints_rad is not None and v.mount_play_rad > 0:
        before = target_base @ forward(target_arm, moment.previous_target_joints_rad + truth.target_joint_offsets_rad)
        earlier, _ = sag(before, targetee_from_target, payload.mass_kg, v.model_compliance_rad_per_nm, centre, shape)
        tilt = tilt @ play(g.matrix_to_rotvec(tilt[:3, :3]) - g.matrix_to_rotvec(earlier[:3, :3]), v.mount_play_rad)
        sag_rad = float(np.linalg.norm(g.matrix_to_rotvec(tilt[:3, :3])))
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
        camera_link_rad=camera_links,
        target_link_rad=target_links,
        camera_arm=camera_arm,
        target_arm=target_arm,
        world_from_camera_base=camera_base,
        world_from_target_base=target_base,
    )
