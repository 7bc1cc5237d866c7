"""A facility folder's robots on the virtual testbed (``facility.path``; docs/architecture.md
section 11): what each arm of its URDF truly does, and what its controller reports.

The controller reports the URDF's forward kinematics of its encoder readings, from the
base where the folder puts it. The true arm differs per joint of its URDF, as a real arm
differs from its data sheet (Mooring, Roth and Driels, *Fundamentals of Manipulator
Calibration*, Wiley 1991, ch. 3):

- every joint's origin is moved by ``virtual.link_length_sigma_m`` per axis and turned by
  a tenth of ``virtual.joint_offset_sigma_rad`` per axis (link lengths, assembly);
- every encoder reads off its link's angle by a zero offset (``virtual.joint_offset_sigma_rad``);
- the base stands off where the lab measured it (``virtual.base_*_sigma``) and a rail's
  scale is off (``virtual.rail_scale_sigma``);
- with ``elasticity`` among ``virtual.unmodelled``, each joint winds up under the gravity
  torque of what the arm carries (its ``payload_kg``, or the mock-up), the Jacobian's
  transpose applied to the payload's weight, and of its links' own masses where the URDF
  gives them (``<inertial>``), over a stiffness drawn as TRON's arms' are.

A static mount stands where the folder puts it, off by a base error. TRON's arms have more
(lost motion, warming): a facility's rehearsal leaves them out, and says so in
docs/user-guide.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from core.config import Config
from manifests.sidecars.truth import HolderTruth
from stages.acquire.virtual.robots import RobotState, sag
from stages.acquire.virtual.truth import Truth
from stages.common import geometry as g
from stages.common.arms import Payload
from stages.common.json_arrays import record
from stages.common.robots.chain import SerialChain
from stages.common.robots.facility import Facility, Robot, load_facility, pose_matrix
from stages.common.statics import GRAVITY_M_S2


@dataclass(frozen=True)
class Holder:
    """The truth of what holds the camera or the target: a robot of the folder, or a static
    mount (``robot`` None)."""

    robot: Robot | None
    world_from_mount: np.ndarray  # (4, 4) nominal: the robot's base at rail 0, or the mount
    true_chain: SerialChain | None
    joint_offsets_rad: np.ndarray  # (J,) true link angle = encoder reading + offset
    base_error: np.ndarray  # (4, 4) true base = nominal base @ error
    rail_scale: float
    stiffness_nm_per_rad: np.ndarray  # (J,); inf: rigid
    origin_errors: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))  # (J + 1, 4, 4)

    def truth(self) -> HolderTruth:
        """The stored form (``W/truth.json``'s ``facility``)."""
        rigid = bool(np.all(np.isinf(self.stiffness_nm_per_rad)))
        return HolderTruth(None if self.robot is None else self.robot.spec.name,
                           tuple(float(v) for v in self.joint_offsets_rad),
                           tuple(record(error) for error in self.origin_errors), record(self.base_error),
                           float(self.rail_scale),
                           None if rigid else tuple(float(v) for v in self.stiffness_nm_per_rad))

    def nominal(self, joints: np.ndarray | None, rail_m: float) -> np.ndarray:
        """(4, 4) the flange (or the mount) in K as the controller reports it."""
        if self.robot is None:
            return self.world_from_mount
        return self.robot.world_from_base(rail_m) @ self.robot.chain.forward(joints)

    def true_base(self, rail_m: float) -> np.ndarray:
        if self.robot is None:
            return self.world_from_mount @ self.base_error
        return self.robot.world_from_base(rail_m * self.rail_scale) @ self.base_error


@dataclass(frozen=True)
class Rig:
    """A facility's holders of the camera and of the target."""

    facility: Facility
    camera: Holder
    target: Holder

    def truth(self) -> dict[str, HolderTruth]:
        """``W/truth.json``'s ``facility``: the camera's and the target's holders' truth."""
        return {"camera": self.camera.truth(), "target": self.target.truth()}


def _small(rng: np.random.Generator, sigma_m: float, sigma_rad: float) -> np.ndarray:
    return g.make_transform(g.rotvec_to_matrix(rng.normal(0.0, sigma_rad, 3)), rng.normal(0.0, sigma_m, 3))


def _holder(config: Config, facility: Facility, carried: str, rng: np.random.Generator) -> Holder:
    v = config.virtual
    holder = facility.holder(carried)
    base_error = _small(rng, v.base_position_sigma_m, v.base_rotation_sigma_rad)
    if not isinstance(holder, Robot):
        return Holder(None, pose_matrix(holder.world_from_mount), None, np.zeros(0), base_error, 1.0, np.zeros(0))
    chain = holder.chain
    origins = np.stack([origin @ _small(rng, v.link_length_sigma_m, 0.1 * v.joint_offset_sigma_rad)
                        for origin in chain.origins])
    offsets = rng.normal(0.0, v.joint_offset_sigma_rad, chain.dof)
    rail_scale = 1.0 + rng.normal(0.0, v.rail_scale_sigma) if holder.spec.rail is not None else 1.0
    stiffness = np.full(chain.dof, np.inf)
    if "elasticity" in v.unmodelled:
        nominal = np.resize(np.asarray(v.joint_stiffness_nm_per_rad, float), chain.dof)
        stiffness = nominal * np.exp(rng.normal(0.0, v.stiffness_spread, chain.dof))
    errors = np.stack([g.invert(nominal) @ true for nominal, true in zip(chain.origins, origins, strict=True)])
    return Holder(holder, holder.world_from_base(0.0), replace(chain, origins=origins), offsets, base_error,
                  rail_scale, stiffness, errors)


def draw_rig(config: Config) -> Rig:
    """The configured facility's true robots; identical for the same ``virtual.seed``."""
    facility = load_facility(Path(config.facility.path))
    rng = np.random.default_rng([config.virtual.seed, 0xF0C1])
    return Rig(facility, _holder(config, facility, "camera", rng), _holder(config, facility, "target", rng))


def windup(holder: Holder, world_from_base: np.ndarray, links: np.ndarray, mass_kg: float,
           load_in_flange_m: np.ndarray) -> np.ndarray:
    """(J,) rad each link turns past its motor: the gravity torque of ``mass_kg`` at
    ``load_in_flange_m`` (3,), tau = J^T (F, M) with the flange's geometric Jacobian, and of
    the links' own masses where the URDF gives them, over each joint's stiffness."""
    if np.all(np.isinf(holder.stiffness_nm_per_rad)):
        return np.zeros_like(links)
    chain = holder.true_chain
    gravity = world_from_base[:3, :3].T @ np.array([0.0, 0.0, -GRAVITY_M_S2])  # m/s^2, base frame
    torque = chain.gravity_torques(links[None], gravity[None])[0]
    if mass_kg != 0.0:
        force = mass_kg * gravity  # N, base frame
        lever = chain.forward(links)[:3, :3] @ load_in_flange_m
        wrench = np.concatenate([force, np.cross(lever, force)])  # about the flange's origin
        torque = torque + chain.jacobian(links).T @ wrench
    return torque / holder.stiffness_nm_per_rad


def _read(row: dict[str, Any], key: str, holder: Holder, rng: np.random.Generator, sigma: float) -> np.ndarray | None:
    if holder.robot is None:
        return None
    return np.asarray(row[key], float) + rng.normal(0.0, sigma, holder.robot.chain.dof)


def move(config: Config, truth: Truth, rig: Rig, row: dict[str, Any], rng: np.random.Generator,
         payload: Payload) -> tuple[RobotState, np.ndarray]:
    """Drive the facility's robots to a plan row's commands: the state (the fields of TRON's
    arms are None) and the robots' link segments (S, 2, 3) in K, true, for the motion
    capture's occlusion. ``rng`` draws the servo noise, in one fixed order."""
    v, u = config.virtual, truth.unmodelled
    camera_joints = _read(row, "camera_joints_rad", rig.camera, rng, v.repeatability_rad)
    target_joints = _read(row, "target_joints_rad", rig.target, rng, v.repeatability_rad)
    railed = _on_rail(rig.camera) or _on_rail(rig.target)  # one robot at most (facility_plan.planned_facility)
    rail = float(row["rail_m"]) + (rng.normal(0.0, v.rail_noise_m) if railed else 0.0)
    mount = row["mount"]
    targetee_from_target = g.invert(truth.target_from_targetee[mount]
                                    @ (u.remount[mount] if row["session"] == "dataset" else np.eye(4)))
    centre = np.asarray(payload.centre_m, float)
    camera_payload = 0.0 if rig.camera.robot is None else rig.camera.robot.spec.payload_kg
    world_from_camee, camera_links, camera_base = _true_flange(
        rig.camera, camera_joints, rail, camera_payload, 0.5 * truth.camee_from_cam[:3, 3])
    world_from_targetee, target_links, target_base = _true_flange(
        rig.target, target_joints, rail, payload.mass_kg, g.apply(targetee_from_target, centre[None])[0])
    shape = u.mount_compliance if "mount" in v.unmodelled else None
    tilt, sag_rad = sag(world_from_targetee, targetee_from_target, payload.mass_kg,
                        v.model_compliance_rad_per_nm, centre, shape)
    state = RobotState(
        kuka_world_from_camee=rig.camera.nominal(camera_joints, rail),
        kuka_world_from_targetee=rig.target.nominal(target_joints, rail),
        world_from_camee=world_from_camee, world_from_targetee=world_from_targetee,
        world_from_cam=world_from_camee @ truth.camee_from_cam,
        world_from_target=world_from_targetee @ tilt @ targetee_from_target,
        camera_joints_rad=camera_joints, target_joints_rad=target_joints, rail_m=rail, sag_rad=sag_rad,
        camera_link_rad=camera_links, target_link_rad=target_links, camera_arm=None, target_arm=None,
        world_from_camera_base=camera_base, world_from_target_base=target_base)
    return state, _segments([(rig.camera, camera_links, camera_base), (rig.target, target_links, target_base)])


def _on_rail(holder: Holder) -> bool:
    return holder.robot is not None and holder.robot.spec.rail is not None


def _true_flange(holder: Holder, joints: np.ndarray | None, rail_m: float, mass_kg: float,
                 load_in_flange_m: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(true flange or mount (4, 4), true link angles (J,) or None, true base (4, 4))."""
    base = holder.true_base(rail_m)
    if holder.robot is None:
        return base, None, base
    links = joints + holder.joint_offsets_rad
    links = links + windup(holder, base, links, mass_kg, load_in_flange_m)
    return base @ holder.true_chain.forward(links), links, base


def _segments(placed: list[tuple[Holder, np.ndarray | None, np.ndarray]]) -> np.ndarray:
    """(S, 2, 3) the moving robots' link capsules' axes in K."""
    segments = [np.zeros((0, 2, 3))]
    for holder, links, base in placed:
        if holder.robot is not None:
            a, b, _ = holder.true_chain.capsules_in_base(links)
            segments.append(np.stack([g.apply(base, a), g.apply(base, b)], axis=1))
    return np.concatenate(segments)
