"""Gravity loads of a KUKA KR arm: the torque each joint carries in a configuration.

Industrial arms are stiff links on compliant joints (gearbox and shaft windup): a joint
``j`` carrying the gravity torque ``tau_j`` turns by ``tau_j / k_j`` beyond what its
motor encoder reads (Dumas, Caro, Garnier, Furet, "Joint stiffness identification of
six-revolute industrial serial robots", Robotics and Computer-Integrated Manufacturing
27(4), 2011). The virtual testbed uses this with TRON's true masses and stiffnesses;
``calibrate`` takes the same nominal masses from ``core/facilities/tron/kr16_2.urdf``'s
``<inertial>`` elements (``SerialChain.gravity_torques``; a test holds the two equal).

Torques are the generalised gravity forces ``tau = -dU/dq`` of the potential energy
``U = g sum m_i z_i(q)`` of the moving masses, ``z`` the world's up axis: positive when
gravity pulls the joint towards larger angles (KUKA's joint convention). The masses sit
on the segments of ``kinematics.link_points``: the lower arm between the A2 and A3 axes,
the upper arm between A3 and the wrist centre, the wrist at its centre, the payload at a
point of the flange frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from stages.common import geometry as g
from stages.common.kinematics import ArmModel, forward, link_points

GRAVITY_M_S2 = 9.80665
_STEP_RAD = 1e-6


@dataclass(frozen=True)
class LinkMasses:
    """Moving masses (kg) and where their centres sit along their link (fraction from the
    joint nearer the base)."""

    lower_arm_kg: float
    lower_arm_centre: float
    upper_arm_kg: float
    upper_arm_centre: float
    wrist_kg: float

    def scaled(self, factors: ArrayLike) -> LinkMasses:
        """These masses times ``factors`` (3,) (lower arm, upper arm, wrist)."""
        lower, upper, wrist = np.asarray(factors, float)
        return LinkMasses(self.lower_arm_kg * lower, self.lower_arm_centre, self.upper_arm_kg * upper,
                          self.upper_arm_centre, self.wrist_kg * wrist)


#: KR 16-2: 235 kg in all (data sheet); the split between base, arms and wrist is the lab's
#: estimate from the links' sizes (KUKA publishes no link masses)
KR16_2_MASSES = LinkMasses(lower_arm_kg=45.0, lower_arm_centre=0.45, upper_arm_kg=32.0, upper_arm_centre=0.3,
                           wrist_kg=9.0)
MASSES: dict[str, LinkMasses] = {"KR16-2": KR16_2_MASSES}


def link_masses(robot_model: str) -> LinkMasses:
    try:
        return MASSES[robot_model]
    except KeyError:
        raise ValueError(f"no link masses for robot model {robot_model!r}; known: {', '.join(MASSES)}") from None


def potential_energy(arm: ArmModel, masses: LinkMasses, world_from_base: np.ndarray, joints: np.ndarray,
                     payload_kg: float, flange_payload_m: np.ndarray, world_up: np.ndarray) -> np.ndarray:
    """Gravity potential (...,) in J of the moving masses at joints (..., 6) rad."""
    points = g.apply(world_from_base, link_points(arm, joints))  # base, shoulder, elbow, wrist, flange
    shoulder, elbow, wrist = points[..., 1, :], points[..., 2, :], points[..., 3, :]
    payload = g.apply(world_from_base @ forward(arm, joints), np.asarray(flange_payload_m, float)[None])[..., 0, :]
    height = (masses.lower_arm_kg * (shoulder + masses.lower_arm_centre * (elbow - shoulder))
              + masses.upper_arm_kg * (elbow + masses.upper_arm_centre * (wrist - elbow))
              + masses.wrist_kg * wrist + payload_kg * payload) @ np.asarray(world_up, float)
    return GRAVITY_M_S2 * height


def gravity_torques(arm: ArmModel, masses: LinkMasses, world_from_base: np.ndarray, joints: ArrayLike,
                    payload_kg: float, flange_payload_m: ArrayLike, world_up: ArrayLike = (0.0, 0.0, 1.0)
                    ) -> np.ndarray:
    """Gravity torque (..., 6) N m on each joint at joints (..., 6) rad, for an arm whose
    base frame sits at ``world_from_base`` (4, 4) and carries ``payload_kg`` at
    ``flange_payload_m`` (3,) in the flange frame (central differences of the potential)."""
    joints = np.asarray(joints, dtype=np.float64)
    torques = np.zeros(joints.shape)
    for j in range(6):
        step = np.zeros(6)
        step[j] = _STEP_RAD
        up_energy, down_energy = (potential_energy(arm, masses, world_from_base, joints + s, payload_kg,
                                                   np.asarray(flange_payload_m, float), np.asarray(world_up, float))
                                  for s in (step, -step))
        torques[..., j] = -(up_energy - down_energy) / (2 * _STEP_RAD)
    return torques
