"""The calibration poses of a facility's own robots, chosen for what they determine
(docs/architecture.md section 11; issue 57, part 2).

Each calibration pose drawn at random sees the board at the calibration distance, but on a
facility folder's arms nothing makes the set determine the arms' parameters: a rail arm
drawn nearest first never leaves its rail's end, and its scale is left to its prior. So
each calibration sample is drawn ``CANDIDATES`` times (its own seeded streams, the rail
spread over the arm's reach) and the candidate kept is the one that most raises the
smallest eigenvalue of the identification's posterior precision, given the samples before
it (``observability.choose``), where calibrate will fit the arms (``arms_fitted``). The
measure is the smallest singular value, not the condition number: in prior sigmas it says
how well the worst direction is determined against the lab's own tolerance, which a ratio
of two singular values does not.
"""

from __future__ import annotations

from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

from core.config import Config
from core.progress import track
from stages.common.arms import Payload
from stages.common.robots import identification, observability
from stages.common.robots.errors import HolderModel, Holders
from stages.common.robots.facility import Facility
from stages.common.target import Target
from stages.plan.poses import PlanningError

#: candidates drawn for each calibration sample; the plan keeps one
CANDIDATES = 3
#: a facility's room: K's z is up (manifests/facility.py)
WORLD_UP = np.array([0.0, 0.0, 1.0])


def readings(facility: Facility, rows: list[dict[str, Any]], target: Target) -> tuple[Holders, identification.Measured]:
    """The facility's arm models and the readings of plan ``rows`` (joints, rail, fixture)."""
    holders = Holders.of(facility)

    def joints(key: str, holder: object) -> np.ndarray:
        if not isinstance(holder, HolderModel):
            return np.zeros((len(rows), 0))
        return np.array([row[key] for row in rows], float)

    m = identification.measure(holders, (joints("camera_joints_rad", holders.camera),
                                         joints("target_joints_rad", holders.target)),
                               np.array([row["rail_m"] or 0.0 for row in rows], float),
                               tuple(row["mount"] for row in rows), Payload.of(target), WORLD_UP)
    return holders, m


def rows_of(facility: Facility, rows: list[dict[str, Any]], target: Target) -> observability.Rows:
    """``observability.Rows`` of plan ``rows`` at the reference tolerances (``REFERENCE_PRIORS``:
    the plan does not read calibrate's own priors, which are not the plan's to depend on)."""
    holders, m = readings(facility, rows, target)
    prior = holders.priors(**observability.REFERENCE_PRIORS)
    return observability.jacobian_rows(holders, m, prior, Payload.of(target), WORLD_UP)


def describe(facility: Facility, rows: list[dict[str, Any]], target: Target, brief: bool = False) -> str | None:
    """What the calibration rows among ``rows`` determine of the facility's robots, in
    words; None without calibration rows or robots."""
    chosen = [row for row in rows if row["session"] == "calibration"]
    if not chosen or not Holders.of(facility).robots:
        return None
    return observability.measure_of(rows_of(facility, chosen, target)).describe(len(chosen), brief)


def arms_fitted(config: Config, facility: Facility, target: Target) -> tuple[bool, str]:
    """Whether calibrate will fit the facility's arms from ``plan.n_calibration`` captures
    (``calibrate.arm_kinematics``; under ``auto``, ``calibrate.min_arm_redundancy`` equations,
    six a capture, per parameter: the arms' identifiable ones and the offsets, as calibrate
    counts them), and why. Where it will not, the poses are
    drawn as before, nearest rail first: the offsets then absorb the arms' error where the
    captures are, and poses spread over the arms' range for parameters nobody fits only
    spread that error (issue 57's smoke cards: a UR10 round a tripod, 25 of 32 labels
    under the SPEED+ thresholds with its poses drawn, 19 with them chosen)."""
    holders = Holders.of(facility)
    setting = config.calibrate.arm_kinematics
    if not holders.robots or setting == "off":
        return False, "calibrate.arm_kinematics = off" if holders.robots else "no robot"
    if setting == "on":
        return True, "calibrate.arm_kinematics = on"
    # as calibrate counts them (FacilityArms.parameters), with the fixtures' compliance, which
    # it fits where the payload loads them
    options = SimpleNamespace(joint_compliance=config.calibrate.joint_compliance,
                              fixture_anisotropy=config.calibrate.fixture_anisotropy, lost_motion="off",
                              arm_prior_lost_motion_rad=0.0, fixture_play="off")
    parameters = identification.fitted_parameter_count(holders, options, sorted(set(config.plan.calibration_mounts)),
                                                       True, Payload.of(target), WORLD_UP)
    needed = config.calibrate.min_arm_redundancy * parameters / 6
    count = config.plan.n_calibration
    return count >= needed, (f"{count} calibration captures for {parameters} parameters (calibrate.min_arm_redundancy "
                             f"= {config.calibrate.min_arm_redundancy:g}: {int(np.ceil(needed))} needed)")


def choose_calibration(facility: Facility, target: Target, count: int,
                       draw: Callable[[int, int], dict[str, Any]]) -> list[dict[str, Any]]:
    """The ``count`` calibration rows, sample ``i`` the best of ``draw(i, k)`` for k under
    ``CANDIDATES`` (module docstring); a further draw (k > 0) that finds no reachable
    configuration is left out, the sample's own (k = 0) is the plan's error as before. All
    are drawn and chosen whatever a resumed plan has already written: the choice of a
    sample depends on those before it."""
    if count == 0 or not Holders.of(facility).robots:
        return [draw(i, 0) for i in range(count)]
    pairs = [(i, k) for i in range(count) for k in range(CANDIDATES)]
    candidates: list[dict[str, Any]] = []
    slots: list[list[int]] = [[] for _ in range(count)]
    for i, k in track(pairs, len(pairs), "plan: calibration candidates"):
        try:
            candidates.append(draw(i, k))
        except PlanningError:
            if k == 0:  # the sample's own draw: as a plan without the choice would fail
                raise
            continue  # another draw that ran out of redraws: the sample keeps those it has
        slots[i].append(len(candidates) - 1)
    picked = observability.choose(rows_of(facility, candidates, target), slots)
    return [candidates[p] for p in picked]
