"""Inverse kinematics of any serial chain: damped least squares (Levenberg-Marquardt on
the flange's pose error; Wampler, "Manipulator inverse kinematic solutions based on vector
formulations and damped least-squares methods", IEEE Trans. SMC 16(1), 1986) from several
starts at once, each step held inside the joint limits, every answer verified by forward
kinematics. Arms with a closed form (stages/common/kinematics.py: KUKA's ortho-parallel
arms) take it instead: ``closed_form_model``.
"""

from __future__ import annotations

import numpy as np

from stages.common import geometry as g
from stages.common.kinematics import ARMS, ArmModel, forward
from stages.common.kinematics import solve as solve_closed_form
from stages.common.robots.chain import SerialChain

#: a solution's flange within this of the asked pose (m, rad)
TOLERANCE_M = 1e-6
TOLERANCE_RAD = 1e-6


def pose_error(base_from_flange: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """(..., 6): position error (m) and rotation error (rotation vector, rad), both in the
    base frame, that take ``base_from_flange`` (..., 4, 4) to ``wanted`` (4, 4)."""
    position = wanted[:3, 3] - base_from_flange[..., :3, 3]
    rotation = _rotvec(wanted[:3, :3] @ np.swapaxes(base_from_flange[..., :3, :3], -1, -2))
    return np.concatenate([position, rotation], axis=-1)


def _rotvec(rotation: np.ndarray) -> np.ndarray:
    """``geometry.matrix_to_rotvec`` of rotations (..., 3, 3), from the skew part and the
    trace (angle = atan2(sin, cos)) where the angle is under 150 deg, which is most of the
    inverse kinematics' steps and costs a fifth of the quaternion route; through the
    quaternion elsewhere, where the skew part no longer gives the axis well."""
    skew = np.stack([rotation[..., 2, 1] - rotation[..., 1, 2], rotation[..., 0, 2] - rotation[..., 2, 0],
                     rotation[..., 1, 0] - rotation[..., 0, 1]], axis=-1)  # 2 sin(angle) axis
    cosine = (rotation[..., 0, 0] + rotation[..., 1, 1] + rotation[..., 2, 2] - 1.0) / 2.0
    sine = np.linalg.norm(skew, axis=-1) / 2.0
    angle = np.arctan2(sine, cosine)
    # angle / (2 sin): 1/2 + angle^2/12 near zero
    scale = np.where(sine > 1e-8, angle / (2.0 * np.maximum(sine, 1e-300)), 0.5 + angle**2 / 12.0)
    out = skew * scale[..., None]
    wide = cosine < np.cos(np.radians(150.0))
    if np.any(wide):
        out[wide] = g.matrix_to_rotvec(rotation[wide])
    return out


def jacobians(chain: SerialChain, frames: np.ndarray) -> np.ndarray:
    """(S, 6, J) geometric Jacobians from joint frames (S, J + 1, 4, 4) (``SerialChain.frames``),
    every joint at once: the inverse kinematics calls it at every step of every start."""
    axes = np.einsum("sjab,jb->sja", frames[:, :-1, :3, :3], chain.axes)  # (S, J, 3) in the base frame
    lever = frames[:, -1:, :3, 3] - frames[:, :-1, :3, 3]  # (S, J, 3) from each joint to the flange
    linear = axes[..., [1, 2, 0]] * lever[..., [2, 0, 1]] - axes[..., [2, 0, 1]] * lever[..., [1, 2, 0]]
    prismatic = chain.prismatic[None, :, None]
    if prismatic.any():
        columns = np.concatenate([np.where(prismatic, axes, linear), np.where(prismatic, 0.0, axes)], axis=-1)
    else:
        columns = np.concatenate([linear, axes], axis=-1)
    return np.swapaxes(columns, -1, -2)


def solve_numeric(chain: SerialChain, base_from_flange: np.ndarray, rng: np.random.Generator, *,
                  starts: int = 16, seeds: np.ndarray | None = None, iterations: int = 80,
                  margin: float = 0.0) -> np.ndarray | None:
    """Joints (J,) that put the flange at ``base_from_flange`` (4, 4) within the limits less
    ``margin``, or None. Starts: ``seeds`` (S, J) and ``starts`` draws within the limits;
    of the converged ones, the one farthest from its limits."""
    wanted = np.asarray(base_from_flange, dtype=np.float64)
    lower, upper = chain.lower + margin, chain.upper - margin
    draws = rng.uniform(lower, upper, size=(starts, chain.dof))
    joints = draws if seeds is None else np.concatenate([np.clip(np.atleast_2d(seeds), lower, upper), draws])
    damping = np.full(len(joints), 1e-3)
    frames = chain.frames(joints)
    error = pose_error(frames[:, -1], wanted)
    cost = np.einsum("si,si->s", error, error)
    identity = np.eye(chain.dof)
    for _ in range(iterations):
        if np.all(cost < 1e-20):
            break
        jac = jacobians(chain, frames)
        transposed = np.swapaxes(jac, -1, -2)
        normal = transposed @ jac + damping[:, None, None] * identity
        step = np.linalg.solve(normal, (transposed @ error[..., None]))[..., 0]
        trial = np.clip(joints + step, lower, upper)
        trial_frames = chain.frames(trial)
        trial_error = pose_error(trial_frames[:, -1], wanted)
        trial_cost = np.einsum("si,si->s", trial_error, trial_error)
        better = trial_cost < cost  # Levenberg-Marquardt: keep a step that helps, else damp harder
        joints = np.where(better[:, None], trial, joints)
        frames = np.where(better[:, None, None, None], trial_frames, frames)
        error = np.where(better[:, None], trial_error, error)
        cost = np.where(better, trial_cost, cost)
        damping = np.clip(np.where(better, damping / 3, damping * 4), 1e-9, 1e6)
    return _best(chain, wanted, joints, lower, upper)


def _best(chain: SerialChain, wanted: np.ndarray, joints: np.ndarray, lower: np.ndarray,
          upper: np.ndarray) -> np.ndarray | None:
    """The verified solution farthest from its limits, or None."""
    error = pose_error(chain.forward(joints), wanted)
    ok = (np.linalg.norm(error[:, :3], axis=-1) < TOLERANCE_M) & (np.linalg.norm(error[:, 3:], axis=-1)
                                                                 < TOLERANCE_RAD)
    ok &= np.all((joints >= lower - 1e-12) & (joints <= upper + 1e-12), axis=-1)
    if not ok.any():
        return None
    room = np.min(np.minimum(joints - lower, upper - joints), axis=-1)
    return joints[int(np.argmax(np.where(ok, room, -np.inf)))]


def closed_form_model(chain: SerialChain, samples: int = 16) -> ArmModel | None:
    """The closed-form arm model whose forward kinematics and limits are the chain's (its
    fast path), found by comparing both at joints drawn within the limits; else None."""
    rng = np.random.default_rng(0)
    for arm in ARMS.values():
        if chain.dof != 6 or not (np.allclose(chain.lower, arm.lower, atol=1e-6)
                                  and np.allclose(chain.upper, arm.upper, atol=1e-6)):
            continue
        joints = rng.uniform(arm.lower, arm.upper, size=(samples, 6))
        if np.allclose(chain.forward(joints), forward(arm, joints), atol=1e-9):
            return arm
    return None


class Solver:
    """The inverse kinematics of one chain: its closed form where it has one (found once)."""

    def __init__(self, chain: SerialChain) -> None:
        self.chain = chain
        self.closed_form = closed_form_model(chain)

    def solve(self, base_from_flange: np.ndarray, rng: np.random.Generator, *, margin: float = 0.0,
              seeds: np.ndarray | None = None) -> np.ndarray | None:
        """Joints (J,) for one flange pose (4, 4) in the base frame, or None where the arm
        cannot reach it within its limits less ``margin``."""
        if self.closed_form is not None:
            joints, reachable = solve_closed_form(self.closed_form, base_from_flange, margin)
            return joints if bool(reachable) else None
        return solve_numeric(self.chain, base_from_flange, rng, seeds=seeds, margin=margin)
