"""Kinematics of 6-axis KUKA KR arms: forward and closed-form inverse, with joint limits.

KUKA's KR arms have an ortho-parallel base and a spherical wrist, so the inverse
kinematics has a closed form with up to 8 solutions (Brandstoetter, Angerer, Hofbaur,
"An analytical solution of the inverse kinematics problem of industrial serial
manipulators with an ortho-parallel basis and a spherical wrist", Austrian Robotics
Workshop 2014; the "OPW" parameters a1, a2, b, c1..c4).

Joint angles are in KUKA's convention (A1..A6 as the controller shows them, radians
here). OPW's internal angles are ``theta = sign * q - offset``.

Frames: ``base_from_flange`` maps flange coordinates ($FLANGE: z out of the tool plate)
into the robot's base frame ($ROBROOT: z up along A1 for a floor mount).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from stages.common.geometry import Array, axis_angle_matrix, make_transform


@dataclass(frozen=True)
class ArmModel:
    """Dimensions (m), joint zero offsets and signs (OPW), and joint limits (rad, KUKA)."""

    name: str
    source: str
    a1: float
    a2: float
    b: float
    c1: float
    c2: float
    c3: float
    c4: float
    offsets: tuple[float, ...]
    signs: tuple[int, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]

    @property
    def reach_m(self) -> float:
        """Horizontal distance from A1 to the flange, arm stretched."""
        return self.a1 + math.hypot(self.a2, self.c2 + self.c3) + self.c4


def _deg(*values: float) -> tuple[float, ...]:
    return tuple(math.radians(v) for v in values)


KR16_2 = ArmModel(
    name="KR16-2",
    source=("KUKA Roboter GmbH, 'KR 16-2' specification (KR C4): link dimensions 675/260/680/35/670/158 mm, "
            "axis ranges A1 +-185, A2 -155..+35, A3 -130..+154, A4 +-350, A5 +-130, A6 +-350 deg; "
            "as transcribed in ROS-Industrial kuka_experimental (kuka_kr16_support: kr16_2_macro.xacro, "
            "opw_parameters_kr16_2.yaml)"),
    a1=0.260, a2=0.035, b=0.0, c1=0.675, c2=0.680, c3=0.670, c4=0.158,
    offsets=_deg(0.0, -90.0, 0.0, 0.0, 0.0, 0.0),
    signs=(-1, 1, 1, -1, 1, -1),
    lower=_deg(-185.0, -155.0, -130.0, -350.0, -130.0, -350.0),
    upper=_deg(185.0, 35.0, 154.0, 350.0, 130.0, 350.0),
)

ARMS: dict[str, ArmModel] = {KR16_2.name: KR16_2}


def arm_model(name: str) -> ArmModel:
    try:
        return ARMS[name]
    except KeyError:
        raise ValueError(f"unknown robot model {name!r}; known: {', '.join(ARMS)}") from None


def _to_theta(arm: ArmModel, joints: Array) -> Array:
    return joints * np.asarray(arm.signs, float) - np.asarray(arm.offsets)


def _to_joints(arm: ArmModel, theta: Array) -> Array:
    return (theta + np.asarray(arm.offsets)) * np.asarray(arm.signs, float)


def _wrist_frame(theta1: Array, theta23: Array) -> Array:
    return axis_angle_matrix("z", theta1) @ axis_angle_matrix("y", theta23)


def forward(arm: ArmModel, joints: ArrayLike, length_deltas: ArrayLike | None = None) -> Array:
    """``base_from_flange`` (..., 4, 4) for joints (..., 6) in radians (KUKA convention);
    ``length_deltas`` (..., 6) m, broadcasting with the joints' batch, are added to the
    arm's ``a1, a2, c1, c2, c3, c4`` (a batch of corrected arms evaluated at once)."""
    theta = _to_theta(arm, np.asarray(joints, dtype=np.float64))
    t1, t2, t3, t4, t5, t6 = np.moveaxis(theta, -1, 0)
    if length_deltas is None:
        a1, a2, c1, c2, c3, c4 = arm.a1, arm.a2, arm.c1, arm.c2, arm.c3, arm.c4
        psi3, k = math.atan2(a2, c3), math.hypot(a2, c3)
    else:
        nominal = np.array([arm.a1, arm.a2, arm.c1, arm.c2, arm.c3, arm.c4])
        a1, a2, c1, c2, c3, c4 = np.moveaxis(nominal + np.asarray(length_deltas, np.float64), -1, 0)
        psi3, k = np.arctan2(a2, c3), np.hypot(a2, c3)
    cx1 = c2 * np.sin(t2) + k * np.sin(t2 + t3 + psi3) + a1
    cz1 = c2 * np.cos(t2) + k * np.cos(t2 + t3 + psi3)
    wrist_centre = np.stack(
        [cx1 * np.cos(t1) - arm.b * np.sin(t1), cx1 * np.sin(t1) + arm.b * np.cos(t1), cz1 + c1], axis=-1)
    rotation = (_wrist_frame(t1, t2 + t3) @ axis_angle_matrix("z", t4) @ axis_angle_matrix("y", t5)
                @ axis_angle_matrix("z", t6))
    return make_transform(rotation, wrist_centre + np.asarray(c4)[..., None] * rotation[..., :, 2])


def inverse(arm: ArmModel, base_from_flange: ArrayLike) -> Array:
    """All closed-form solutions (..., 8, 6), radians, KUKA convention, NaN where none exists.

    Angles are not yet wrapped into the joint limits; see ``fit_limits``.
    """
    pose = np.asarray(base_from_flange, dtype=np.float64)
    rotation = pose[..., :3, :3]
    c = pose[..., :3, 3] - arm.c4 * rotation[..., :, 2]
    cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
    with np.errstate(invalid="ignore"):
        nx1 = np.sqrt(cx**2 + cy**2 - arm.b**2) - arm.a1
        tmp1 = np.arctan2(cy, cx)
        tmp2 = np.arctan2(arm.b, nx1 + arm.a1)
        theta1 = [tmp1 - tmp2, tmp1 + tmp2 - np.pi]
        dz = cz - arm.c1
        s1_sq = nx1**2 + dz**2
        s2_sq = (nx1 + 2 * arm.a1) ** 2 + dz**2
        kappa_sq = arm.a2**2 + arm.c3**2
        acos1 = np.arccos((s1_sq + arm.c2**2 - kappa_sq) / (2 * np.sqrt(s1_sq) * arm.c2))
        acos2 = np.arccos((s2_sq + arm.c2**2 - kappa_sq) / (2 * np.sqrt(s2_sq) * arm.c2))
        base1 = np.arctan2(nx1, dz)
        base2 = np.arctan2(nx1 + 2 * arm.a1, dz)
        theta2 = [-acos1 + base1, acos1 + base1, -acos2 - base2, acos2 - base2]
        psi3 = math.atan2(arm.a2, arm.c3)
        denominator = 2 * arm.c2 * math.sqrt(kappa_sq)
        acos3 = np.arccos((s1_sq - arm.c2**2 - kappa_sq) / denominator)
        acos4 = np.arccos((s2_sq - arm.c2**2 - kappa_sq) / denominator)
        theta3 = [acos3 - psi3, -acos3 - psi3, acos4 - psi3, -acos4 - psi3]

    solutions = []
    for index in range(4):
        t1 = theta1[index // 2]
        t2, t3 = theta2[index], theta3[index]
        wrist = np.swapaxes(_wrist_frame(t1, t2 + t3), -1, -2) @ rotation  # = Rz(t4) Ry(t5) Rz(t6)
        t5 = np.arctan2(np.hypot(wrist[..., 0, 2], wrist[..., 1, 2]), wrist[..., 2, 2])
        t4 = np.arctan2(wrist[..., 1, 2], wrist[..., 0, 2])
        t6 = np.arctan2(wrist[..., 2, 1], -wrist[..., 2, 0])
        for flip in (False, True):
            w4, w5, w6 = (t4 + np.pi, -t5, t6 + np.pi) if flip else (t4, t5, t6)
            solutions.append(np.stack([t1, t2, t3, w4, w5, w6], axis=-1))
    theta = np.stack(solutions, axis=-2)
    theta = (theta + np.pi) % (2 * np.pi) - np.pi
    return _to_joints(arm, theta)


def fit_limits(arm: ArmModel, joints: ArrayLike, margin: float = 0.0) -> tuple[Array, Array]:
    """Wrap each angle by multiples of 2 pi into ``[lower + margin, upper - margin]``.

    Returns the wrapped joints (...,6) and a mask (...) of solutions that fit (NaN never fits).
    Among equivalent angles the one nearest the middle of the range is taken.
    """
    joints = np.asarray(joints, dtype=np.float64)
    lower = np.asarray(arm.lower) + margin
    upper = np.asarray(arm.upper) - margin
    middle = (lower + upper) / 2
    # the equivalent angle nearest the middle is inside the (symmetric) range if any is
    wrapped = middle + (joints - middle + np.pi) % (2 * np.pi) - np.pi
    with np.errstate(invalid="ignore"):
        fits = np.all((wrapped >= lower) & (wrapped <= upper), axis=-1)
    return wrapped, fits & np.all(np.isfinite(joints), axis=-1)


def limit_margin(arm: ArmModel, joints: ArrayLike) -> Array:
    """Smallest distance (rad) of any joint to its limit (...); negative outside."""
    joints = np.asarray(joints, dtype=np.float64)
    return np.min(np.minimum(joints - np.asarray(arm.lower), np.asarray(arm.upper) - joints), axis=-1)


def solve(arm: ArmModel, base_from_flange: ArrayLike, margin: float = 0.0,
          tolerance_m: float = 1e-7) -> tuple[Array, Array]:
    """Best reachable joints (..., 6) for poses (..., 4, 4) and a reachability mask (...).

    "Best" keeps the largest distance to the joint limits; every returned solution is
    verified by forward kinematics to ``tolerance_m``.
    """
    pose = np.asarray(base_from_flange, dtype=np.float64)
    candidates, fits = fit_limits(arm, inverse(arm, pose), margin)
    with np.errstate(invalid="ignore"):
        check = forward(arm, np.nan_to_num(candidates))
        position_error = np.linalg.norm(check[..., :3, 3] - pose[..., None, :3, 3], axis=-1)
        rotation_error = np.linalg.norm(check[..., :3, :3] - pose[..., None, :3, :3], axis=(-2, -1))
    fits &= (position_error < tolerance_m) & (rotation_error < 1e-6)
    score = np.where(fits, limit_margin(arm, np.nan_to_num(candidates)), -np.inf)
    best = np.argmax(score, axis=-1)
    joints = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    reachable = np.take_along_axis(fits, best[..., None], axis=-1)[..., 0]
    return np.where(reachable[..., None], joints, np.nan), reachable


def link_points(arm: ArmModel, joints: ArrayLike) -> Array:
    """Points along the arm (..., 5, 3) in the base frame: base, shoulder (A2 axis), elbow
    (A3 axis), wrist centre and flange. Consecutive points bound the links, which is what
    line-of-sight tests (motion capture occlusion) need."""
    theta = _to_theta(arm, np.asarray(joints, dtype=np.float64))
    t1, t2 = theta[..., 0], theta[..., 1]
    zero = np.zeros_like(t1)

    def planar(x: Array, z: Array) -> Array:  # point in the arm plane, rotated about A1
        return np.stack([x * np.cos(t1) - arm.b * np.sin(t1), x * np.sin(t1) + arm.b * np.cos(t1), z], axis=-1)

    base = np.stack([zero, zero, zero], axis=-1)
    shoulder = planar(zero + arm.a1, zero + arm.c1)
    elbow = planar(arm.a1 + arm.c2 * np.sin(t2), arm.c1 + arm.c2 * np.cos(t2))
    flange = forward(arm, joints)
    wrist = flange[..., :3, 3] - arm.c4 * flange[..., :3, 2]
    return np.stack([base, shoulder, elbow, wrist, flange[..., :3, 3]], axis=-2)
