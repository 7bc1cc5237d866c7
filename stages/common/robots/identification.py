"""Identification of a facility's robots from the calibration captures (docs/architecture.md
section 6): which of their parameters (``errors.py``) the data can separate, the maximum a
posteriori fit of those with the hand-eye offsets, and the poses' sensitivity to them, which
fuse propagates into each label's sigma.

Identifiability. A parameter whose effect on the predicted ``cam_from_target`` is a
combination of the kept parameters' effects over the joints' whole range can never be
told apart from them: it is dropped (held at zero, no covariance) and named with what
absorbs it. The test is structural, on configurations drawn over the joints' limits and
the rail's travel, not on the calibration poses: a parameter the poses leave weakly
determined is kept with its prior (the lab's tolerance) and named as weak, so that its
uncertainty reaches the labels where the dataset's poses differ from the calibration's.
The kept parameters are chosen in a fixed order of preference (the hand-eye offsets, then
per robot the joints' zero offsets, the rail's scale, the compliances, then the frames
from base to flange), as the base-parameter reductions of robot calibration do.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from manifests.sidecars.arm_fit import ChainFit, ResidualNoise, RobotCorrection
from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.pose_noise import ResidualCovariance
from stages.common.robots.errors import RANK_TOLERANCE, HolderModel, Holders
from stages.common.robots.lost_motion import (
    BEFORE_KEY,
    DIRECTION_KEYS,
    flank,
    hysteresis_shown,
    loaded_flanks,
    unknown_flanks,
)

#: configurations drawn for the structural rank test
RANK_CONFIGURATIONS = 96
#: a kept parameter is weakly determined when the data narrow its prior by less than this
WEAK_RATIO = 0.7


@dataclass(frozen=True)
class Measured:
    """A session's encoder readings for a facility's holders: joints (N, J) of each robot
    ((N, 0) for a static mount), rail (N,) m, the fixture of each capture, the nominal
    gravity torques (N, J) N m of what each robot carries, and the gear flank (N, J) each
    joint rests on (+-1; 0 unknown; ``errors.py``); ``target_before`` (N, J): the target
    robot's joints before its last move (NaN rows: none; ``rwhe.fixture_lag``,
    ``lost_motion.BEFORE_KEY``)."""

    camera_joints: np.ndarray
    target_joints: np.ndarray
    rail_m: np.ndarray
    fixtures: tuple[str, ...]
    camera_torque: np.ndarray
    target_torque: np.ndarray
    camera_flank: np.ndarray
    target_flank: np.ndarray
    target_before: np.ndarray | None = None  # None: NaN everywhere

    def __post_init__(self) -> None:
        if self.target_before is None:
            object.__setattr__(self, "target_before", np.full(self.target_joints.shape, np.nan))

    def subset(self, mask: np.ndarray) -> Measured:
        return Measured(self.camera_joints[mask], self.target_joints[mask], self.rail_m[mask],
                        tuple(np.asarray(self.fixtures, object)[mask]), self.camera_torque[mask],
                        self.target_torque[mask], self.camera_flank[mask], self.target_flank[mask],
                        self.target_before[mask])


def _joints(holder: HolderModel | np.ndarray, rows: list[dict[str, Any]], key: str) -> np.ndarray | None:
    if not isinstance(holder, HolderModel):
        return np.zeros((len(rows), 0))
    if any(row.get(key) is None for row in rows):
        return None
    return np.array([row[key] for row in rows], float).reshape(len(rows), -1)[:, :holder.joints]


def _directions(holder: HolderModel | np.ndarray, rows: list[dict[str, Any]], role: str) -> np.ndarray:
    if not isinstance(holder, HolderModel):
        return np.zeros((len(rows), 0))
    return np.array([(row.get(DIRECTION_KEYS[role]) or [0.0] * holder.joints)[:holder.joints] for row in rows],
                    float).reshape(len(rows), holder.joints)


def measure(holders: Holders, joints: tuple[np.ndarray, np.ndarray], rail_m: np.ndarray, fixtures: tuple[str, ...],
            payload: arms.Payload, world_up: np.ndarray, directions: tuple[np.ndarray, np.ndarray] | None = None,
            preload_nm: float = np.inf, target_before: np.ndarray | None = None) -> Measured:
    """``Measured`` of readings: the camera's and target's joints (N, J), rail (N,) m, and
    each joint's last move (N, J) (+-1, 0 unknown; None: all unknown); the target's joints
    before its last move (N, J; NaN rows: none; None: none anywhere)."""
    torque = []
    for holder, q in zip((holders.camera, holders.target), joints, strict=True):
        if not isinstance(holder, HolderModel):
            torque.append(np.zeros((len(rail_m), 0)))
        elif holder.role == "camera":
            torque.append(holder.torques(q, rail_m, holder.payload_kg, np.tile(holder.load_in_flange_m, (len(q), 1)),
                                         world_up))
        else:
            load = np.stack([payload.centre_in_flange(f) for f in fixtures]) if fixtures else np.zeros((0, 3))
            torque.append(holder.torques(q, rail_m, payload.mass_kg, load, world_up))
    if directions is None:
        directions = (np.zeros_like(torque[0]), np.zeros_like(torque[1]))
    flanks = [flank(t, d, preload_nm) for t, d in zip(torque, directions, strict=True)]
    return Measured(joints[0], joints[1], np.asarray(rail_m, float), tuple(fixtures), torque[0], torque[1], *flanks,
                    target_before)


def measured(holders: Holders, rows: list[dict[str, Any]], payload: arms.Payload,
             world_up: np.ndarray, preload_nm: float = np.inf) -> Measured | None:
    """The captures' readings, or None when any capture lacks a robot's joints or a railed
    robot's rail; each joint's flank from ``move_directions``' keys where the rows have them."""
    camera = _joints(holders.camera, rows, "kuka_camera_joints_rad")
    target = _joints(holders.target, rows, "kuka_target_joints_rad")
    if camera is None or target is None or not rows:
        return None
    railed = any(robot.rail_axis is not None for robot in holders.robots)
    if railed and any(row.get("kuka_rail_m") is None for row in rows):
        return None  # a rail's reading is as much the arm's configuration as a joint's
    rail = np.array([0.0 if row.get("kuka_rail_m") is None else row["kuka_rail_m"] for row in rows], float)
    fixtures = tuple(str(row.get("fixture") or "fixed") for row in rows)
    directions = (_directions(holders.camera, rows, "camera"), _directions(holders.target, rows, "target"))
    before = np.array([(row.get(BEFORE_KEY) or [np.nan] * target.shape[1])[:target.shape[1]] for row in rows],
                      float).reshape(target.shape)
    return measure(holders, (camera, target), rail, fixtures, payload, world_up, directions, preload_nm, before)


def distinct_rows(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``p`` (K, P) to evaluate (the first, and every other row that differs from it
    bit for bit), and which of them each row is (K,): ``f(p[rows])[which]`` is ``f(p)`` for
    any ``f`` that maps rows on their own. A finite-difference Jacobian's batch steps one
    parameter a row, so one robot's slice of it is the first row's in every row that steps
    another robot's, or a fixture's, parameter: each robot's chain is evaluated once per
    row that moves it."""
    if len(p) < 2 or p.shape[1] == 0:
        return np.zeros(min(len(p), 1), int), np.zeros(len(p), int)
    bits = np.ascontiguousarray(p, dtype=np.float64).view(np.uint64)  # -0.0 and NaN payloads kept apart
    other = np.flatnonzero((bits[1:] != bits[0]).any(axis=1)) + 1
    which = np.zeros(len(p), int)
    which[other] = np.arange(1, len(other) + 1)
    return np.concatenate([[0], other]), which


def flanges(holders: Holders, p: np.ndarray, m: Measured) -> tuple[np.ndarray, np.ndarray]:
    """``world_from_camee`` and ``world_from_targetee`` (K, N, 4, 4) of the arms' packed
    parameters (K, size)."""
    slices, out = holders.slices(), []
    for role, holder, joints, torque, flank_ in (
            ("camera", holders.camera, m.camera_joints, m.camera_torque, m.camera_flank),
            ("target", holders.target, m.target_joints, m.target_torque, m.target_flank)):
        if isinstance(holder, HolderModel):
            own = p[:, slices[role]]
            rows, which = distinct_rows(own)
            out.append(holder.flanges(own[rows], joints, m.rail_m, torque, flank_)[which])
        else:
            out.append(np.broadcast_to(holder, (len(p), len(m.rail_m), 4, 4)))
    return out[0], out[1]


def predict_batch(holders: Holders, params: np.ndarray, names: list[str], compliant: bool, m: Measured,
                  world_up: np.ndarray) -> np.ndarray:
    """``cam_from_target`` (K, N, 4, 4) of packed parameters (K, P): the arms', then
    ``rwhe.pack`` of the offsets of fixtures ``names`` (compliant fixtures: anisotropic, with
    their play)."""
    rows, which = distinct_rows(params[:, :holders.size])
    world_from_camee, world_from_targetee = flanges(holders, params[rows, :holders.size], m)
    up = np.einsum("knji,j->kni", world_from_targetee[..., :3, :3], np.asarray(world_up, float))[which]
    b = (g.invert(world_from_camee) @ world_from_targetee)[which]
    # at the first parameters for every row: the lag follows the tilt's change of direction,
    # which the arms' corrections move by microradians, and a second pass of the chain per
    # parameter step would double the fit's cost
    before = up_before(holders, params[:1, :holders.size], m, world_up)[0] if compliant else None
    return rwhe.predict_packed(params[:, holders.size:], names, compliant, compliant, b, list(m.fixtures),
                               up if compliant else None, played=compliant, up_before=before)


def up_before(holders: Holders, arm_params: np.ndarray, m: Measured, world_up: np.ndarray) -> np.ndarray:
    """(K, N, 3) the up direction in the target flange before each capture's last move of the
    target (NaN rows: none), of the arms' packed parameters (K, size); the joints' windup and flank taken as
    at the capture itself (a fixture's lag needs only the direction of its tilt's change)."""
    known = ~np.isnan(m.target_before).any(axis=1) & (m.target_before.shape[1] > 0)
    out = np.full((len(arm_params), len(m.rail_m), 3), np.nan)
    if not isinstance(holders.target, HolderModel) or not known.any():
        return out
    joints = np.where(known[:, None], np.nan_to_num(m.target_before), m.target_joints)
    slices = holders.slices()
    world_from_targetee = holders.target.flanges(arm_params[:, slices["target"]], joints, m.rail_m, m.target_torque,
                                                 m.target_flank)
    up = np.einsum("knji,j->kni", world_from_targetee[..., :3, :3], np.asarray(world_up, float))
    out[:, known] = up[:, known]
    return out


def corrected_b(holders: Holders, arm_params: np.ndarray, m: Measured,
                world_up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The robots' ``B`` = ``camee_from_targetee`` (N, 4, 4) and the up direction in the
    target flange (N, 3) with the arms corrected by ``arm_params`` (size,)."""
    world_from_camee, world_from_targetee = flanges(holders, np.asarray(arm_params, float)[None], m)
    up = np.einsum("nji,j->ni", world_from_targetee[0, :, :3, :3], np.asarray(world_up, float))
    return g.invert(world_from_camee[0]) @ world_from_targetee[0], up


def central_jacobian(function: Any, x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """(M, P) central differences of a batched function ((K, P) -> (K, M)) at ``x`` (P,)."""
    moved = np.repeat(x[None], 2 * len(x), axis=0)
    moved[np.arange(len(x)), np.arange(len(x))] += step
    moved[len(x) + np.arange(len(x)), np.arange(len(x))] -= step
    values = function(moved)
    return ((values[:len(x)] - values[len(x):]) / (2 * step)).T


def _draw_configurations(holders: Holders, fixtures: list[str], payload: arms.Payload, world_up: np.ndarray,
                         seed: int, preload_nm: float = np.inf) -> Measured:
    rng = np.random.default_rng(seed)
    joints = []
    for holder in (holders.camera, holders.target):
        if isinstance(holder, HolderModel):
            low = np.maximum(holder.chain.lower, -np.pi)
            high = np.minimum(holder.chain.upper, np.pi)
            joints.append(rng.uniform(low, high, (RANK_CONFIGURATIONS, holder.joints)))
        else:
            joints.append(np.zeros((RANK_CONFIGURATIONS, 0)))
    travel = max((h.rail_travel_m for h in holders.robots if h.rail_axis is not None), default=(0.0, 0.0))
    rail = rng.uniform(travel[0], travel[1], RANK_CONFIGURATIONS)
    chosen = tuple(fixtures[i % len(fixtures)] for i in range(RANK_CONFIGURATIONS))
    directions = (rng.choice([-1.0, 1.0], joints[0].shape), rng.choice([-1.0, 1.0], joints[1].shape))
    return measure(holders, (joints[0], joints[1]), rail, chosen, payload, world_up, directions, preload_nm)


def preference(holders: Holders, offsets: int) -> np.ndarray:
    """The order (P,) in which parameters are kept when they are separable: the offsets
    (the last ``offsets``), then per robot zero offsets, rail, compliances, frames, lost
    motions (last: a joint's lost motion on a flank that never changes is its zero offset)."""
    order, at = [holders.size + i for i in range(offsets)], 0
    for robot in holders.robots:
        j, frames = robot.joints, 6 * (robot.joints + 1)
        rail = 1 if robot.rail_axis is not None else 0
        order += [at + i for i in range(j)]  # zero offsets
        order += [at + j + frames + i for i in range(rail)]
        order += [at + j + frames + rail + i for i in range(j)]  # compliances
        order += [at + j + 6 * k + 3 + i for k in range(robot.joints + 1) for i in range(3)]  # translations
        order += [at + j + 6 * k + i for k in range(robot.joints + 1) for i in range(3)]  # then rotations
        order += [at + j + frames + rail + j + i for i in range(j)]  # lost motions
        at += robot.size
    return np.array(order)


def identifiable(holders: Holders, fixtures: list[str], compliant: bool, params: np.ndarray, free: np.ndarray,
                 payload: arms.Payload, world_up: np.ndarray, seed: int = 0,
                 preload_nm: float = np.inf) -> dict[str, str]:
    """The free arm parameters (indices < ``holders.size`` of ``params``) that no data can
    separate from the kept ones, by name, each with what absorbs it; the structural rank
    test of the module docstring, at ``params`` (P,)."""
    names = sorted(set(fixtures))
    m = _draw_configurations(holders, fixtures, payload, world_up, seed, preload_nm)

    def poses(p: np.ndarray) -> np.ndarray:
        return predict_batch(holders, p, names, compliant, m, world_up)[..., :3, :].reshape(len(p), -1)

    jacobian = central_jacobian(poses, params)
    all_names = list(holders.names)
    basis: list[np.ndarray] = []
    kept: list[int] = []
    dropped: dict[str, str] = {}
    for index in preference(holders, len(params) - holders.size):
        if not free[index]:
            continue
        column = jacobian[:, index]
        norm = float(np.linalg.norm(column))
        residual = column - sum((b @ column) * b for b in basis) if basis else column
        if norm > 0 and np.linalg.norm(residual) > RANK_TOLERANCE * norm:
            basis.append(residual / np.linalg.norm(residual))
            kept.append(index)
            continue
        if index >= holders.size:  # an offset the rest already fix: not an arm parameter to name
            continue
        dropped[all_names[index]] = _absorbed_by(jacobian, column, kept, all_names, holders.size) if norm > 0 \
            else "moves no pose (no gravity torque about this joint, or no lever)"
    return dropped


def _absorbed_by(jacobian: np.ndarray, column: np.ndarray, kept: list[int], names: list[str], arms_size: int) -> str:
    coefficients, *_ = np.linalg.lstsq(jacobian[:, kept], column, rcond=None)
    weight = np.abs(coefficients) * np.linalg.norm(jacobian[:, kept], axis=0)
    top = [kept[i] for i in np.argsort(-weight)[:3] if weight[i] > 1e-3 * weight.max()]
    label = [names[i] if i < arms_size else "the hand-eye offsets" for i in top]
    return "a combination of " + ", ".join(dict.fromkeys(label))


@dataclass(frozen=True)
class Verdicts:
    """What a cross-validation fold takes from the whole calibration's fit instead of
    deciding it again, so that the folds judge the model the calibration reports
    (docs/architecture.md, section 6): the parameters the structural rank test held, for the
    offsets' fixtures it saw (the test asks what no data could separate, on configurations
    it draws itself), and the hysteresis groups the F tests held (a fold's own tests cost two
    more fits of three)."""

    names: tuple[str, ...]  # the offsets' fixtures of the rank test, sorted (``Fitted.names``)
    unidentifiable: tuple[tuple[str, str], ...]  # (arm parameter, why it is held)
    held: frozenset[str]  # of "play", "lost motion"


@dataclass(frozen=True)
class Fitted:
    """The facility's robots and hand-eye offsets fitted together."""

    holders: Holders
    offsets: rwhe.Solution
    params: np.ndarray  # (P,): the arms' (holders.size), then the offsets'
    covariance: np.ndarray  # (P, P)
    names: list[str]  # the fixtures of the offsets
    compliant: bool
    dropped: dict[str, str]
    prior: np.ndarray  # (holders.size,) 1-sigma before calibration
    preload_nm: float  # above it a joint rests on its loaded flank (``flank``)
    noise: ResidualCovariance  # what the fit whitened the poses by (``arms.MapFit.noise``)
    capped: bool  # the fit stopped at its iterations' cap (``arms.MapFit.capped``)
    play_why: str = ""  # why the fixtures' play was not fitted ("": fitted, or rigid fixtures)
    #: the hysteresis groups ("play", "lost motion") free before the tests and held after them
    #: (``_hysteresis``)
    held: frozenset[str] = frozenset()
    #: the arm parameters the structural rank test held (``identifiable``: name, why)
    unidentifiable: tuple[tuple[str, str], ...] = ()

    def verdicts(self) -> Verdicts:
        """What a cross-validation fold of this calibration fits (``fit``'s ``verdicts``)."""
        return Verdicts(tuple(self.names), self.unidentifiable, self.held)

    def residual_noise(self) -> ResidualNoise:
        """``noise`` as its record: the PnP factor (None where the poses were weighed by
        groups) and the model's 1-sigmas."""
        v_pnp, v_rot, v_t = (float(v) for v in self.noise.variances)
        return ResidualNoise(None if self.noise.pnp is None else v_pnp, float(np.sqrt(v_rot)), float(np.sqrt(v_t)))

    def corrected_b(self, m: Measured, world_up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return corrected_b(self.holders, self.params[:self.holders.size], m, world_up)

    def up_before(self, m: Measured, world_up: np.ndarray) -> np.ndarray:
        """(N, 3) ``up_before`` of the fitted arms, for ``offsets.predict``."""
        return up_before(self.holders, self.params[None, :self.holders.size], m, world_up)[0]

    def weak(self) -> dict[str, float]:
        """Kept parameters the calibration poses narrow by less than ``WEAK_RATIO`` of their
        prior: name -> posterior over prior 1-sigma."""
        size = self.holders.size
        sigma = np.sqrt(np.clip(np.diag(self.covariance)[:size], 0.0, None))
        names = self.holders.names
        return {names[i]: round(float(sigma[i] / self.prior[i]), 3) for i in range(size)
                if names[i] not in self.dropped and sigma[i] > 0 and sigma[i] > WEAK_RATIO * self.prior[i]}

    def record(self) -> ChainFit:
        at, robots = 0, []
        for robot in self.holders.robots:
            zero, frames, scale, compliance, lost = robot.split(self.params[None, at:at + robot.size])
            robots.append(RobotCorrection(
                robot.robot, robot.role, robot.chain.joint_names, tuple(float(v) for v in zero[0]),
                tuple(tuple(float(v) for v in frame) for frame in frames[0]),
                float(scale[0]) if robot.rail_axis is not None else None, tuple(float(v) for v in compliance[0]),
                tuple(float(v) for v in lost[0])))
            at += robot.size
        return ChainFit(tuple(robots), tuple(self.holders.names), dict(self.dropped), self.weak(),
                        tuple(self.names), self.compliant, tuple(float(v) for v in self.params),
                        tuple(tuple(row) for row in self.covariance.tolist()), tuple(float(v) for v in self.prior),
                        float(self.preload_nm), self.residual_noise())


def free_parameters(holders: Holders, c: Any, names: list[str], compliant: bool, count: int) -> np.ndarray:
    """(count,) which packed parameters the fit estimates: all but the compliances with
    ``c.joint_compliance`` off, the lost motions with ``c.lost_motion`` off or
    ``c.arm_prior_lost_motion_rad`` 0, the fixtures' anisotropy with ``c.fixture_anisotropy`` off
    and their play with ``c.fixture_play`` off."""
    free = np.ones(count, bool)
    if compliant:
        play = rwhe.play_slice(names)
        free[holders.size + play.start:holders.size + play.stop] = c.fixture_play != "off"
    if c.joint_compliance != "on":
        free[[i for i, n in enumerate(holders.names) if n.endswith(".compliance")]] = False
    if c.lost_motion == "off" or c.arm_prior_lost_motion_rad <= 0:
        free[[i for i, n in enumerate(holders.names) if n.endswith(".lost_motion")]] = False
    shape = rwhe.anisotropy_slice(names) if compliant else slice(0, 0)
    free[holders.size + shape.start:holders.size + shape.stop] = c.fixture_anisotropy == "on"
    return free


def fitted_parameter_count(holders: Holders, c: Any, fixtures: list[str], compliant: bool, payload: arms.Payload,
                           world_up: np.ndarray) -> int:
    """How many parameters ``fit`` would estimate on samples of ``fixtures`` from their poses:
    the arms' identifiable ones and the offsets (``c``: what ``free_parameters`` reads). The
    joints' lost motions are not counted: the order of the moves determines them, not the
    poses, and a facility's plan (which asks this count) must not change with them; nor,
    for the same reason, the fixtures' play."""
    names = sorted(set(fixtures))
    start = rwhe.Solution(np.eye(4), {name: np.eye(4) for name in names})
    params = np.concatenate([np.zeros(holders.size), rwhe.pack(start, names, compliant, compliant, compliant)])
    free = free_parameters(holders, c, names, compliant, len(params))
    free[[i for i, name in enumerate(holders.names) if name.endswith(".lost_motion")]] = False
    if compliant:
        free[holders.size + rwhe.play_slice(names).start:holders.size + rwhe.play_slice(names).stop] = False
    dropped = identifiable(holders, list(fixtures), compliant, params, free, payload, world_up)
    return int(free.sum()) - len(dropped)


def bounded_compliance(holders: Holders, prior: np.ndarray, drawn: Measured, windup_rad: float) -> np.ndarray:
    """``prior`` (size,) with each joint's compliance sigma at most what winds the joint by
    ``windup_rad`` (the mastering tolerance) under its largest gravity torque over ``drawn``
    configurations: where the URDF gives the links' masses, a shoulder carries hundreds of
    N m (a KR 16-2's A2 up to 600) and one compliance sigma for every joint would let it
    wind by centimetres at the flange. On TRON's facility 12 (default profile) the robots'
    dataset error went 1.84 -> 1.65 mm with the bound (docs/accuracy.md)."""
    out = np.array(prior, float)
    for robot, torque in ((holders.camera, drawn.camera_torque), (holders.target, drawn.target_torque)):
        if not isinstance(robot, HolderModel):
            continue
        peak = np.abs(torque).max(axis=0) if len(torque) else np.zeros(robot.joints)
        for joint, largest in zip(robot.chain.joint_names, peak, strict=True):
            if largest > 0.0:
                index = holders.names.index(f"{robot.robot}.{joint}.compliance")
                out[index] = min(out[index], windup_rad / largest)
    return out


def fit(holders: Holders, c: Any, a: np.ndarray, m: Measured, start: rwhe.Solution, compliant: bool,
        payload: arms.Payload, pnp: np.ndarray | None = None, verdicts: Verdicts | None = None) -> Fitted:
    """The robots (the parameters ``identifiable`` keeps), ``Z``, ``X_f`` (and ``k_f``,
    ``D_f``) from PnP poses ``a`` (N, 4, 4) of covariances ``pnp`` (N, 6, 6; None: unknown)
    and readings ``m``: ``arms.map_fit`` with the lab's tolerances as zero-mean priors
    (``c``: the calibrate section). ``verdicts``: the whole calibration's (``Fitted.verdicts``),
    which a cross-validation fold takes instead of testing again; its rank test's only where
    the fold holds the same fixtures."""
    names = sorted(start.x)
    world_up = np.asarray(c.world_up, float)
    size = holders.size
    prior = holders.priors(c.arm_prior_joint_rad, c.arm_prior_length_m, c.arm_prior_frame_rad,
                           (c.arm_prior_base_rad, c.arm_prior_base_m), c.arm_prior_rail_scale,
                           c.arm_prior_compliance_rad_per_nm, c.arm_prior_lost_motion_rad)
    prior = bounded_compliance(holders, prior, _draw_configurations(holders, list(m.fixtures), payload, world_up, 0),
                               c.arm_prior_joint_rad)
    params = np.concatenate([np.zeros(size), rwhe.pack(start, names, compliant, compliant, compliant)])
    shape = rwhe.anisotropy_slice(names) if compliant else slice(0, 0)
    shape = slice(size + shape.start, size + shape.stop)
    play = rwhe.play_slice(names) if compliant else slice(0, 0)
    play = slice(size + play.start, size + play.stop)
    free = free_parameters(holders, c, names, compliant, len(params))
    if verdicts is not None and verdicts.names == tuple(names):
        unidentifiable = dict(verdicts.unidentifiable)
    else:
        unidentifiable = identifiable(holders, list(m.fixtures), compliant, params, free, payload, world_up,
                                      preload_nm=c.backlash_preload_nm)
    dropped = dict(unidentifiable)
    dropped.update({name: why for name, why in unknown_flanks(holders, m, free).items() if name not in dropped})
    if c.lost_motion == "auto":
        dropped.update({name: why for name, why in loaded_flanks(holders, m, free, c.backlash_preload_nm,
                                                                  c.link_mass_uncertainty, world_up).items()
                        if name not in dropped})
    dropped.update({name: "not fitted (calibrate.lost_motion = off, or calibrate.arm_prior_lost_motion_rad = 0)"
                    for i, name in enumerate(holders.names) if name.endswith(".lost_motion") and not free[i]
                    and name not in dropped})
    free[[holders.names.index(n) for n in dropped]] = False
    if compliant and (not isinstance(holders.target, HolderModel) or np.isnan(m.target_before).any(axis=1).all()):
        free[play] = False  # a static mount's tilt never changes; without times, no change is known
    all_prior = np.concatenate([prior, np.full(shape.stop - shape.start, c.fixture_anisotropy_prior),
                                np.full(play.stop - play.start, c.fixture_play_prior_rad)])
    priored_all = np.concatenate([np.arange(size), np.arange(shape.start, shape.stop),
                                  np.arange(play.start, play.stop)])

    def batch(p: np.ndarray) -> np.ndarray:
        return predict_batch(holders, p, names, compliant, m, world_up)

    def fitted(chosen: np.ndarray) -> arms.MapFit:
        keep = chosen[priored_all]
        return arms.map_fit(batch, a, params, chosen, all_prior[keep], priored_all[keep], pnp)

    lost = np.array([name.endswith(".lost_motion") for name in holders.names] + [False] * (len(params) - size))
    played = np.zeros(len(params), bool)
    played[play] = True
    play_why = "" if np.any(free & played) or not compliant else (
        "not fitted (calibrate.fixture_play = off)" if c.fixture_play == "off"
        else "not fitted: the target stands on a static mount, whose tilt never changes"
        if not isinstance(holders.target, HolderModel)
        else "not fitted: no calibration capture has a capture before it (captures without capture_time_s)")
    groups = {"play": played, "lost motion": lost}
    result, play_why, chosen = _hysteresis(holders, c, batch, a, fitted, free, groups, dropped, play_why,
                                           None if verdicts is None else verdicts.held)
    params, covariance = result.params, result.covariance
    offsets = rwhe.unpack(params[size:], names, compliant, compliant, compliant)
    held_now = frozenset(what for what, group in groups.items() if np.any(free & group) and not np.any(chosen & group))
    return Fitted(holders, offsets, params, covariance, names, compliant, dropped, prior, c.backlash_preload_nm,
                  result.noise, result.capped, play_why, held_now, tuple(unidentifiable.items()))


def _hysteresis(holders: Holders, c: Any, batch: Any, a: np.ndarray, fitted: Any, free: np.ndarray,
                groups: dict[str, np.ndarray], dropped: dict[str, str], play_why: str,
                held: frozenset[str] | None = None) -> tuple[Any, str, np.ndarray]:
    """The fit of the ``free`` parameters (``fitted``: chosen -> (params, covariance)) less
    the hysteresis groups (the fixtures' play, the joints' lost motions) the captures do not
    show: a negative play is held at 0, and under ``auto`` each group is F-tested against
    the fit without it, the play first (a fixture's lag left out is taken up by the lost
    motions of the joints whose moves it follows). Held lost motions are named in
    ``dropped``; returns the fit, why the play was not fitted ("": it was) and the
    parameters it kept free.

    ``held`` (a cross-validation fold): the groups the whole calibration held are held and
    the rest fitted, untested. A fold's own tests cost two more fits of the three, and its
    model is then the one the calibration reports, whose predictions the folds judge."""
    played, lost = groups["play"], groups["lost motion"]
    if held is not None:
        for what, group in groups.items():
            if what in held and np.any(free & group):
                said = "held, as on the whole calibration's captures"
                if what == "play":
                    play_why = said
                else:
                    dropped.update({holders.names[i]: said for i in np.flatnonzero(free & group)})
                free = free & ~group
    result = fitted(free)
    if np.any(free & played) and np.any(result.params[played] < 0):  # a fixture that leads its change: no play seen
        play_why = (f"fitted below zero ({', '.join(f'{w:.2g}' for w in result.params[played])} rad) and held at 0: "
                    "the captures show no lag")
        free = free & ~played
        result = fitted(free)
    for what, group, setting in (("play", played, c.fixture_play), ("lost motion", lost, c.lost_motion)):
        if held is None and setting == "auto" and np.any(free & group):
            without = fitted(free & ~group)
            shown, said = hysteresis_shown(batch, a, without, result.params, int(np.sum(free & group)),
                                           int(free.sum()), what)
            if not shown:
                if what == "play":
                    play_why = said
                else:
                    dropped.update({holders.names[i]: said for i in np.flatnonzero(free & group)})
                free, result = free & ~group, without
    return result, play_why, free


def joint_columns(holders: Holders) -> np.ndarray:
    """The packed parameters' indices of the robots' joint zero offsets, the camera's then the
    target's: a joint angle's own columns of ``pose_jacobians``."""
    slices = holders.slices()
    return np.concatenate([np.arange(slices[robot.role].start, slices[robot.role].start + robot.joints)
                           for robot in holders.robots]).astype(int) if holders.robots else np.zeros(0, int)


def pose_jacobians(holders: Holders, fit: ChainFit, m: Measured, world_up: np.ndarray,
                   step: float = 1e-7) -> np.ndarray:
    """(N, 6, P) derivatives of the poses predicted for captures ``m`` (rotation applied on
    the camera side, rad; translation, m) by the fitted parameters, forward differences."""
    params = np.asarray(fit.parameters, float)
    moved = np.repeat(params[None], len(params) + 1, axis=0)
    moved[1 + np.arange(len(params)), np.arange(len(params))] += step
    centre, *poses = predict_batch(holders, moved, list(fit.fixtures), fit.compliant, m, world_up)
    # each moved prediction against the centre's: (P, N, 6) -> (N, 6, P)
    return np.moveaxis(arms.pose_difference(np.stack(poses), centre[None]), 0, -1) / step

