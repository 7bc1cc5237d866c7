"""Any facility robot's kinematic error model, built from its URDF chain (docs/architecture.md
section 6): the parameters calibrate identifies and fuse applies.

Model (Mooring, Roth and Driels, *Fundamentals of Manipulator Calibration*, Wiley 1991,
ch. 3; ROS ``robot_calibration``'s joint and frame offsets). For a holder whose chain has
moving joints ``0..J-1`` after fixed origins ``O_0..O_J`` (``SerialChain.origins``),

    world_from_flange = world_from_base(rail (1 + s)) O_0 E_0 M_0(q_0 + z_0 + c_0 tau_0) ... O_J E_J

- ``z_j``: the encoder's zero offset of joint j (rad; m for a prismatic joint);
- ``E_k = exp(e_k)``: a small frame error of origin k, ``e_k`` a rotation vector (rad) then a
  translation (m) in origin k's frame: link lengths, twists and assembly. ``E_0`` holds the
  base's placement as the lab surveyed it; ``E_J`` the flange's, which the hand-eye offset
  always absorbs;
- ``s``: the rail encoder's scale error (a railed robot only);
- ``c_j``: joint j's compliance (rad/(N m)) under ``tau_j``, the gravity torque of the
  payload (the flange Jacobian's transpose of its weight) and of the links' own masses
  where the URDF gives them (``<inertial>``), evaluated at the nominal arm;
- ``l_j``: joint j's lost motion (rad; gearbox backlash plus hysteresis), entering as
  ``+ l_j f_j / 2`` with ``f_j`` the flank the joint rests on: the sign of its gravity
  torque where that exceeds the gearbox's preload, else the direction of its last move
  (``Measured``; 0 where unknown). A loaded joint's flank never changes, so its lost
  motion is its zero offset's; an unloaded one's changes with the order of the moves,
  which calibrations that fit offsets alone leave as noise (Mooring, Roth and Driels
  ch. 3: backlash as a configuration-dependent joint error).

Many of these are not separable from each other or from the hand-eye offsets (a frame's
turn about the next joint's axis is that joint's zero offset; one base against the other
robot's; the flange's against ``Z`` or ``X_f``). ``identifiable`` finds them by rank, on
configurations drawn over the joints' ranges, and the fit holds them at zero, named.

A static mount has no parameters: its placement error is the hand-eye offset's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from core.config import TestbedConfig
from stages.common import layout
from stages.common.robots.chain import SerialChain
from stages.common.robots.facility import Facility, Robot, load_facility, pose_matrix
from stages.common.rwhe import transform_from_vector
from stages.common.statics import GRAVITY_M_S2

#: the six components of a frame error, in the packed order
FRAME_AXES = ("rx", "ry", "rz", "x", "y", "z")
#: a column is dropped when its part independent of the kept columns is under this share of its
#: norm. At 1e-6 the rank depended on the order the columns were taken in (a facility's build
#: dropped 50 of its parameters in one order and 27 in another, TRON's 33 and 24) and on the
#: offsets it was evaluated at: dependent columns whose finite-difference residuals sit near
#: it were kept at their priors; from 1e-5 to 1e-3 the count is the same in either order on
#: every facility measured (docs/accuracy.md)
RANK_TOLERANCE = 1e-4


@dataclass(frozen=True)
class HolderModel:
    """One robot's error model: its chain, where it stands, what it carries."""

    robot: str  # the facility's name for it
    role: str  # "camera" or "target"
    chain: SerialChain
    world_from_base: np.ndarray  # (4, 4) nominal, rail at 0
    rail_axis: np.ndarray | None  # (3,) unit, in K; None: no rail
    payload_kg: float  # the camera's mass (camera robot); the target's comes with the readings
    load_in_flange_m: np.ndarray  # (3,) where the camera's weight hangs: halfway to the lens (as acquire's)
    rail_travel_m: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def of(cls, robot: Robot, role: str) -> HolderModel:
        rail = None if robot.spec.rail is None else np.asarray(robot.spec.rail.axis, float)
        load = 0.5 * pose_matrix(robot.spec.flange_from_tool)[:3, 3]
        return cls(robot.spec.name, role, robot.chain, robot.world_from_base(0.0), rail, float(robot.spec.payload_kg),
                   load, robot.rail_travel_m)

    @property
    def joints(self) -> int:
        return self.chain.dof

    @cached_property  # the fit asks for it (and ``size``) at every evaluation: made once
    def names(self) -> tuple[str, ...]:
        """Every parameter's name, in the packed order: zero offsets, frame errors (each
        joint's origin, then the flange's), the rail's scale, the compliances, the lost motions."""
        joints = self.chain.joint_names
        frames = [*(f"{j}.origin" for j in joints), "flange"]
        return (*(f"{self.robot}.{j}.zero" for j in joints),
                *(f"{self.robot}.{frame}.{axis}" for frame in frames for axis in FRAME_AXES),
                *((f"{self.robot}.rail.scale",) if self.rail_axis is not None else ()),
                *(f"{self.robot}.{j}.compliance" for j in joints),
                *(f"{self.robot}.{j}.lost_motion" for j in joints))

    @cached_property
    def size(self) -> int:
        return len(self.names)

    def split(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Zero offsets (K, J), frame errors (K, J + 1, 6), rail scale (K,), compliances (K, J),
        lost motions (K, J) of packed parameters (K, size)."""
        j = self.joints
        zero, frames = p[:, :j], p[:, j:j + 6 * (j + 1)].reshape(len(p), j + 1, 6)
        at = j + 6 * (j + 1)
        scale = p[:, at] if self.rail_axis is not None else np.zeros(len(p))
        at += self.rail_axis is not None
        return zero, frames, scale, p[:, at:at + j], p[:, at + j:at + 2 * j]

    def base_at(self, rail_m: np.ndarray) -> np.ndarray:
        """(..., 4, 4) the base in K at rail positions (...)."""
        rail_m = np.asarray(rail_m, float)
        out = np.broadcast_to(self.world_from_base, rail_m.shape + (4, 4)).copy()
        if self.rail_axis is not None:
            out[..., :3, 3] += rail_m[..., None] * self.rail_axis
        return out

    def flanges(self, p: np.ndarray, joints: np.ndarray, rail_m: np.ndarray, torque: np.ndarray,
                flank: np.ndarray | None = None) -> np.ndarray:
        """``world_from_flange`` (K, N, 4, 4) of packed parameters (K, size) at encoder
        readings ``joints`` (N, J), rail (N,) m, gravity torques (N, J) N m, and the flanks
        (N, J) the joints rest on (+-1, 0 unknown; None: all unknown)."""
        zero, frames, scale, compliance, lost = self.split(p)
        links = joints[None] + zero[:, None] + compliance[:, None] * torque[None]  # (K, N, J)
        if flank is not None:
            links = links + 0.5 * lost[:, None] * flank[None]
        errors = transform_from_vector(frames)  # (K, J + 1, 4, 4)
        current = self.base_at(rail_m[None] * (1.0 + scale[:, None]))  # (K, N, 4, 4)
        for index in range(self.joints):
            current = current @ (self.chain.origins[index] @ errors[:, index])[:, None]
            current = current @ self.chain.motion(index, links[..., index])
        return current @ (self.chain.origins[-1] @ errors[:, -1])[:, None]

    def torques(self, joints: np.ndarray, rail_m: np.ndarray, mass_kg: float, load_in_flange_m: np.ndarray,
                world_up: np.ndarray) -> np.ndarray:
        """(N, J) N m: each joint's gravity torque from ``mass_kg`` at ``load_in_flange_m``
        (N, 3), tau = J^T (F, M) with the nominal flange's geometric Jacobian, and from the
        links' own masses where the URDF gives them (``SerialChain.gravity_torques``)."""
        bases = self.base_at(rail_m)
        gravity = np.einsum("nji,j->ni", bases[:, :3, :3], -GRAVITY_M_S2 * np.asarray(world_up, float))  # base frame
        out = self.chain.gravity_torques(joints, gravity)
        if mass_kg == 0.0:
            return out
        for i, q in enumerate(joints):
            force = mass_kg * gravity[i]
            lever = self.chain.forward(q)[:3, :3] @ load_in_flange_m[i]
            out[i] += self.chain.jacobian(q).T @ np.concatenate([force, np.cross(lever, force)])
        return out


@dataclass(frozen=True)
class Holders:
    """The camera's and the target's holders: a robot's model, or a static mount (4, 4)."""

    camera: HolderModel | np.ndarray
    target: HolderModel | np.ndarray

    @classmethod
    def of(cls, facility: Facility) -> Holders:
        def held(role: str) -> HolderModel | np.ndarray:
            holder = facility.holder(role)
            if isinstance(holder, Robot):
                return HolderModel.of(holder, role)
            return pose_matrix(holder.world_from_mount)

        return cls(held("camera"), held("target"))

    @property
    def robots(self) -> tuple[HolderModel, ...]:
        return tuple(h for h in (self.camera, self.target) if isinstance(h, HolderModel))

    @cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(name for robot in self.robots for name in robot.names)

    @cached_property
    def size(self) -> int:
        return sum(robot.size for robot in self.robots)

    def slices(self) -> dict[str, slice]:
        """Each robot's (by role) slice of the packed parameters."""
        out, at = {}, 0
        for robot in self.robots:
            out[robot.role] = slice(at, at + robot.size)
            at += robot.size
        return out

    def priors(self, joint_rad: float, length_m: float, frame_rad: float, base: tuple[float, float],
               rail_scale: float, compliance_rad_per_nm: float, lost_motion_rad: float = 0.0) -> np.ndarray:
        """(size,) 1-sigma of each parameter before calibration (the lab's tolerances): the
        first frame's, the base's survey (``base``: rad, m); a lost motion's prior of 0 holds it
        at zero (``free_parameters``)."""
        out = []
        for robot in self.robots:
            j = robot.joints
            zero = [length_m if kind == "prismatic" else joint_rad for kind in robot.chain.kinds]
            frames = [base[0]] * 3 + [base[1]] * 3 + ([frame_rad] * 3 + [length_m] * 3) * j
            out += zero + frames + ([rail_scale] if robot.rail_axis is not None else [])
            out += [compliance_rad_per_nm] * j + [lost_motion_rad] * j
        return np.array(out, float)


def configured_holders(facility_path: str, testbed: TestbedConfig) -> tuple[Holders, Facility]:
    """The holders calibrate fits and fuse applies: a facility folder's robots, or TRON's
    KR 16-2 pair (the built-in folder's URDF) placed as the configuration's ``[testbed]``
    places them (its bases, the camera's payload; the plan and the virtual testbed read the
    same keys), so that an override of ``testbed.*`` reaches the arms' model as it reaches
    the robots."""
    facility = load_facility(Path(facility_path) if facility_path else None)
    holders = Holders.of(facility)
    if facility_path:
        return holders, facility
    camera, target = holders.camera, holders.target
    assert isinstance(camera, HolderModel) and isinstance(target, HolderModel)  # the built-in folder's two arms
    camera = replace(camera, world_from_base=layout.world_from_camera_base(testbed, 0.0),
                     payload_kg=float(testbed.camera_payload_kg),
                     load_in_flange_m=0.5 * np.asarray(testbed.camee_from_cam_t_m, float))
    return Holders(camera, replace(target, world_from_base=layout.world_from_target_base(testbed))), facility
