"""The joints' lost motion (gearbox backlash plus hysteresis) in the arms' model
(``errors.py``; docs/architecture.md section 6): which flank each joint rests on, whether
the calibration captures show the lost motion at all, and what of it the labels' sigmas
must still carry.

A joint whose gravity torque exceeds the gearbox's preload rests on its loaded flank; any
other on the flank its last move left it on. The captures' times give the order of the
moves, and each reading's change from the capture before gives the direction.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from manifests.sidecars.arm_fit import ChainFit
from stages.common import arms
from stages.common.robots.errors import HolderModel, Holders

if TYPE_CHECKING:
    from stages.common.robots.identification import Measured

#: a joint whose reading changed by less than this between two captures did not move and keeps
#: its flank: 7 times the repeatability of a KR 16-class joint (1.5e-5 rad), far below any planned move
STILL_RAD = 1e-4
#: the keys ``move_directions`` adds to capture rows: each joint's last move (+-1, 0 unknown)
DIRECTION_KEYS = {"camera": "camera_move_direction", "target": "target_move_direction"}
#: and the target robot's readings before its last move (None: none this session), whose fixture
#: tilt the fixture's play lags behind (``rwhe.fixture_lag``); a target that stood still keeps
#: its lag, and a change of mount keeps it too: the adapter plate that slips stays clamped
BEFORE_KEY = "target_joints_before_rad"


def move_directions(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` (capture rows of any sessions) with each robot's last move per joint under
    ``DIRECTION_KEYS``: the sign of its reading's change from the session's capture before,
    in the order of ``capture_time_s``; a joint that did not move (``STILL_RAD``) keeps its
    direction; 0 for the session's first capture, and for every capture of a session whose
    captures lack a time (their order, and so the flanks, unknown). A capture without the
    robot's readings gets None. Under ``BEFORE_KEY``, the target robot's readings before its
    last move: at the capture before, or, where it stood still since, where that one's came
    from (None until it has moved). Call it on a session's
    every capture, failed ones included, before choosing some: a dropped capture still
    moved the arms."""
    out = [dict(row) for row in rows]
    for session in dict.fromkeys(row.get("session") for row in out):
        chosen = [row for row in out if row.get("session") == session]
        timed = all(row.get("capture_time_s") is not None for row in chosen)
        for robot, key in DIRECTION_KEYS.items():
            column = f"kuka_{robot}_joints_rad"
            read = sorted((row for row in chosen if row.get(column) is not None),
                          key=lambda row: (float(row["capture_time_s"]) if timed else 0.0, str(row.get("sample_id"))))
            for row in chosen:
                row[key] = None
                if robot == "target":
                    row[BEFORE_KEY] = None
            last, previous, before = None, None, None
            for row in read:
                reading = np.asarray(row[column], float)
                if previous is None or not timed:
                    last = np.zeros(len(reading))
                else:
                    change = reading - previous
                    last = np.where(np.abs(change) > STILL_RAD, np.sign(change), last)
                    if robot == "target":
                        # a target that stood still keeps its fixture's lag: the reading before its last move
                        before = previous if np.any(np.abs(change) > STILL_RAD) else before
                        row[BEFORE_KEY] = None if before is None else before.tolist()
                row[key], previous = last.tolist(), reading
    return out


def flank(torque: np.ndarray, direction: np.ndarray, preload_nm: float) -> np.ndarray:
    """(N, J) the gear flank each joint rests on: its gravity torque's sign where that
    exceeds ``preload_nm``, else the direction of its last move (0: unknown)."""
    return np.where(np.abs(torque) > preload_nm, np.sign(torque), direction)


#: the lost motions are fitted under ``calibrate.lost_motion = auto`` when the F test rejects
#: the model without them at this level
LOST_MOTION_TEST_LEVEL = 0.01


def hysteresis_shown(batch: Any, a: np.ndarray, without: arms.MapFit, with_params: np.ndarray, added: int,
                     parameters: int, what: str = "lost motion") -> tuple[bool, str]:
    """Whether the calibration captures show the joints' lost motion (or the fixtures' play,
    ``what``: "lost motion" or "play", whose ``calibrate.*`` switch the words name): the F test of the fit
    with its ``added`` parameters (``with_params``, P,) against the fit without (``without``),
    on the residuals of PnP poses ``a`` (N, 4, 4) whitened by the covariance the fit without
    estimated (``pose_noise``; the fit with them was made under its own, so the test leans
    towards not showing them), ``parameters`` estimated in all (Seber and Wild, *Nonlinear
    Regression*, Wiley 1989, section 5.3: the extra-sum-of-squares test); and in words."""
    from scipy.stats import f as f_distribution  # 0.5 s: every command resolves the stages that import this

    whitening = without.noise.whitening(len(a))

    def whitened_sum(params: np.ndarray) -> float:
        difference = arms.pose_difference(a, batch(params[None])[0])
        return float(np.sum(np.einsum("nij,nj->ni", whitening, difference) ** 2))

    redundancy = 6 * len(a) - parameters
    if redundancy <= 0:
        return False, "too few calibration captures to test for it"
    rss_without, rss_with = whitened_sum(without.params), whitened_sum(with_params)
    statistic = max(rss_without - rss_with, 0.0) / added / max(rss_with / redundancy, 1e-300)
    p = float(f_distribution.sf(statistic, added, redundancy))
    setting = {"lost motion": "lost_motion", "play": "fixture_play"}[what]
    said = (f"the calibration captures do not show it (F test of the {added} {what}s: F = {statistic:.2f}, "
            f"p = {p:.2g} >= {LOST_MOTION_TEST_LEVEL:g}; calibrate.{setting} = on fits them anyway)")
    return p < LOST_MOTION_TEST_LEVEL, said


def unknown_flanks(holders: Holders, m: Measured, free: np.ndarray) -> dict[str, str]:
    """The free lost motions no capture of ``m`` can see: their joint's flank is unknown on
    every one (captures without times, whose order of moves is unknown), by name, with why."""
    out = {}
    for robot, flanks in ((holders.camera, m.camera_flank), (holders.target, m.target_flank)):
        if not isinstance(robot, HolderModel):
            continue
        for joint, column in zip(robot.chain.joint_names, flanks.T, strict=True):
            name = f"{robot.robot}.{joint}.lost_motion"
            if free[holders.names.index(name)] and not np.any(column):
                out[name] = ("no capture tells its flank: the order of the moves is unknown (captures without "
                             "capture_time_s) and its gravity torque never exceeds calibrate.backlash_preload_nm")
    return out


#: a lost motion is fitted only where at least this many captures rest on the flank their last
#: move chose whatever the lab's mass model errs by (``loaded_flanks``)
MIN_FREE_FLANKS = 8


def loaded_flanks(holders: Holders, m: Measured, free: np.ndarray, preload_nm: float, mass_uncertainty: float,
                  world_up: np.ndarray) -> dict[str, str]:
    """The free lost motions whose joint rests on the flank its last move chose on fewer than
    ``MIN_FREE_FLANKS`` captures of ``m`` beyond doubt: where its nominal gravity torque
    plus twice its links' share times ``mass_uncertainty`` (the lab's link masses' relative
    1-sigma) stays under ``preload_nm`` and the move's direction is known. On the others the
    load decides the flank, and the masses may have decided it wrongly: fitted there, the
    lost motion takes up the windup those masses misplace (docs/accuracy.md, issue 57 part 7).
    By name, with why."""
    out = {}
    for robot, joints, torque, flanks in ((holders.camera, m.camera_joints, m.camera_torque, m.camera_flank),
                                          (holders.target, m.target_joints, m.target_torque, m.target_flank)):
        if not isinstance(robot, HolderModel):
            continue
        links = robot.torques(joints, m.rail_m, 0.0, np.zeros((len(joints), 3)), world_up)
        unloaded = np.abs(torque) + 2.0 * mass_uncertainty * np.abs(links) < preload_nm
        for joint, below, known in zip(robot.chain.joint_names, unloaded.sum(axis=0),
                                       (unloaded & (flanks != 0)).sum(axis=0), strict=True):
            name = f"{robot.robot}.{joint}.lost_motion"
            if not free[holders.names.index(name)] or known >= MIN_FREE_FLANKS:
                continue
            if below >= MIN_FREE_FLANKS:
                out[name] = (f"the order of the moves is known on {int(known)} of the {int(below)} calibration "
                             "captures where its last move decides its flank (captures without capture_time_s)")
            else:
                out[name] = (f"its load decides its flank on all but {int(below)} calibration captures, beyond the "
                             "doubt of the link masses (calibrate.link_mass_uncertainty): too few to tell its lost "
                             "motion from the windup those masses misplace (calibrate.lost_motion = on fits it "
                             "anyway)")
    return out


def flank_variances(holders: Holders, m: Measured, chains: ChainFit,
                    lost_motion_rad: tuple[float, ...] | None, parameter_scale: float = 1.0) -> np.ndarray:
    """(N, joints of both robots) variance (rad^2) of each joint's angle from its gearbox's
    lost motion that the fitted arms ``chains`` leave out. A joint whose gravity torque
    exceeds the fit's preload rests on its loaded flank, at the same place for every capture
    with that load, which the offsets absorb. Any other rests on the flank its last move left
    it on, ``+-l / 2`` from the middle:

    - where the fit estimated ``l`` (``errors.py``) and ``m`` knows the flank, the fit's
      covariance carries it (``pose_jacobians``): 0 here;
    - where it estimated ``l`` but the flank is unknown (the session's first capture),
      ``(l^2 + var l) / 4``, ``var l`` widened by ``parameter_scale`` as the parameters' is;
    - where it did not, the rating ``lost_motion_rad`` (one per joint, the same for both
      robots; None: none) is a maximum, a unit's ``l`` uniform on 50-100% of it, so the
      variance is ``E[l^2] / 4 = 7 / 12 (rating / 2)^2`` (``arms.UNIT_SHARE``)."""
    out = []
    parameters = np.asarray(chains.parameters, float)
    covariance = np.asarray(chains.covariance, float) * parameter_scale**2
    for robot, torque, flanks in ((holders.camera, m.camera_torque, m.camera_flank),
                                  (holders.target, m.target_torque, m.target_flank)):
        if not isinstance(robot, HolderModel):
            continue
        unloaded = np.abs(torque) <= chains.backlash_preload_nm
        rating = np.zeros(robot.joints) if lost_motion_rad is None else np.asarray(lost_motion_rad, float)
        if rating.shape != (robot.joints,):
            raise ValueError(f"{robot.robot}: {len(rating)} lost-motion ratings for {robot.joints} joints")
        variance = np.where(unloaded, arms.UNIT_SHARE * (rating / 2) ** 2, 0.0)
        for joint, name in enumerate(robot.chain.joint_names):
            index = holders.names.index(f"{robot.robot}.{name}.lost_motion")
            if chains.prior_sigma[index] > 0 and chains.parameter_names[index] not in chains.dropped:
                fitted = (parameters[index] ** 2 + covariance[index, index]) / 4
                variance[:, joint] = np.where(flanks[:, joint] == 0, fitted, 0.0)
        out.append(variance)
    return np.concatenate(out, axis=1) if out else np.zeros((len(m.rail_m), 0))
