"""Calibration poses that load the target arm as the dataset does (docs/accuracy.md, "The
rotation tail"; issue 57).

A calibration pose drawn round the board alone puts the target arm where the board faces
the camera best; on TRON that loads its A2 with at most about 100 N m, where the dataset's
poses reach 330 N m. Calibrate's joint compliances and lost motions are then fitted on
small loads and extrapolated three times beyond them, with link masses a quarter off: the
labels' rotation tail. So ``plan.calibration_cover`` of the calibration poses hold the
target arm at a dataset pose's configuration (its joints, and its mount where that is the
fixture the session's alternation gives the sample) and bring the camera
arm and rail to a calibration pose of the board from there (``reconfigure_camera``).

Which dataset pose lends its configuration is fixed by the sample's index alone (spread
over the dataset session), and the lender is planned from its own stream, so the plan
stays the same whatever order or how many runs make it. A lender whose board no reachable
camera pose sees, or whose own plan fails (it says why when the dataset is planned), gives
way to the next; where none of ``LENDERS_TRIED`` does, the sample is an ordinary
calibration pose. The session's fixtures alternate by index, so every other covering
sample is taken one index earlier (``covering_turn``): at the default share, 8 of TRON's 16
hold the model on each mount.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from core.config import Config
from stages.common import geometry as g
from stages.common.target import Target
from stages.plan.poses import PlanningError, calibration_pose
from stages.plan.reconfigure import Reconfiguration, reconfigure_camera

#: dataset poses tried, in turn, for one covering calibration sample (about half of them hold
#: the model on the sample's fixture)
LENDERS_TRIED = 24
#: calibration poses of the board drawn for each lender
DRAWS_PER_LENDER = 64


def covering_turn(config: Config, index: int) -> int | None:
    """Which covering sample (0, 1, ...) calibration sample ``index`` is, or None: one in
    every 1 / ``plan.calibration_cover``, spread evenly over the session; none in
    trajectory mode (a sequence's frames are not the plan's to lend one by one). The
    session's fixtures alternate by index, so where the share leaves room (at most a half) a
    covering sample whose index has the parity of the one before it is taken one index
    earlier: the covering samples then hold the model on both mounts in turn."""
    plan = config.plan
    share = plan.calibration_cover
    if plan.mode != "poses" or plan.n_dataset == 0 or share == 0:
        return None

    def turn_at(i: int) -> int | None:
        if i >= plan.n_calibration:
            return None
        before, after = math.floor(i * share), math.floor((i + 1) * share)
        return before if after > before else None

    if share > 0.5:
        return turn_at(index)
    first = next((i for i in range(plan.n_calibration) if turn_at(i) == 0), 0)

    def moved(turn: int, i: int) -> bool:  # the parity of turn's own index is not the alternation's
        return i % 2 != (first + turn) % 2

    here, after = turn_at(index), turn_at(index + 1)
    if here is not None and not moved(here, index):
        return here
    return after if after is not None and moved(after, index + 1) else None


def lenders(config: Config, turn: int) -> list[int]:
    """The dataset indices tried for covering sample ``turn``: from its share of the
    session on, ``LENDERS_TRIED`` of them in turn."""
    plan = config.plan
    covering = max(1, math.floor(plan.n_calibration * plan.calibration_cover))
    start = turn * plan.n_dataset // covering
    return [(start + k) % plan.n_dataset for k in range(min(LENDERS_TRIED, plan.n_dataset))]


def held_arm(row: dict[str, Any]) -> Reconfiguration:
    """The commands of a plan row, its target arm to be held where it is."""
    def pose(key: str) -> np.ndarray:
        return g.transform_from_qt(row[f"{key}_q"], row[f"{key}_t"])

    return Reconfiguration(rail_m=float(row["rail_m"]), camera_joints_rad=np.asarray(row["camera_joints_rad"], float),
                           target_joints_rad=np.asarray(row["target_joints_rad"], float),
                           world_from_camee=pose("world_from_camee"), world_from_targetee=pose("world_from_targetee"),
                           margin_rad=0.0)


def cover(config: Config, index: int, target: Target, rng: np.random.Generator,
          lend: Callable[[int], dict[str, Any]]) -> tuple[tuple[np.ndarray, str, Reconfiguration] | None, int]:
    """Calibration sample ``index`` at a dataset pose's target-arm configuration:
    ((``cam_from_target`` (4, 4) mock-up scale, mount, commands), or None where ``index``
    does not cover or no lender's board is seen from a reachable camera pose; the relative
    poses drawn and discarded before it, kept or not). ``lend(j)``: dataset sample ``j``'s
    plan row; ``rng``: the sample's own stream."""
    turn = covering_turn(config, index)
    if turn is None:
        return None, 0
    plan, discarded = config.plan, 0
    for j in lenders(config, turn):
        try:
            row = lend(j)
        except PlanningError:  # the dataset's own plan names that sample and why
            continue
        if row["mount"] != plan.calibration_mounts[index % len(plan.calibration_mounts)]:
            continue  # the session's fixtures alternate, as the ordinary poses' do
        candidates = np.stack([calibration_pose(rng, plan, config.testbed, config.camera, target)
                               for _ in range(DRAWS_PER_LENDER)])
        reached = reconfigure_camera(candidates, held_arm(row), row["mount"], plan, config.testbed, target)
        if reached is not None:
            first, commands = reached
            return (candidates[first], row["mount"], commands), discarded + first
        discarded += DRAWS_PER_LENDER
    return None, discarded


def count_covering(rows: list[dict[str, Any]]) -> tuple[int, int]:
    """(calibration rows whose target arm stands at a dataset row's configuration,
    calibration rows) of a plan's ``rows``."""
    held = {tuple(r["target_joints_rad"]) for r in rows if r["session"] == "dataset" and r["target_joints_rad"]}
    calibration = [r for r in rows if r["session"] == "calibration"]
    return sum(1 for r in calibration if r["target_joints_rad"] and tuple(r["target_joints_rad"]) in held), len(
        calibration)
