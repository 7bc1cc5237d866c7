"""When each capture happens and how the robots got there: the session's timeline.

The robots visit the plan's samples in capture order (sample_id order within a session).
Between two captures they move (all axes and the rail at once: the slowest one decides),
wait for vibration to settle, and expose; a change of light set-up adds its own time.
Each capture's time since the session's first exposure drives the thermal drift, and the
direction each joint last moved in decides on which gear flank it rests (backlash): the
plan's order of moves matters, as on a real arm. Everything here is a function of the plan,
never of the order in which workers finish.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.config import Config

#: KR 16-2 axis speeds at 100 % override (data sheet), A1-A6
AXIS_SPEEDS_RAD_S = tuple(math.radians(v) for v in (156.0, 156.0, 156.0, 335.0, 355.0, 647.0))
_MOVED_RAD = 1e-9


@dataclass(frozen=True)
class Moment:
    """A capture's time (s since its session's first exposure) and the sign (+1, -1) of each
    joint's last move, per robot (6,)."""

    time_s: float
    camera_direction: np.ndarray
    target_direction: np.ndarray
    previous_target_joints_rad: np.ndarray | None = None  # commanded at the session's capture before; None: first
    move_s: float | None = None  # the robots' move from the capture before; None: first


def _light(row: dict[str, Any]) -> tuple[str, tuple[int, ...]]:
    return row["light"], tuple(row["light_boxes"])


def move_seconds(config: Config, previous: dict[str, Any], row: dict[str, Any]) -> float:
    """Duration (s) of the move from one plan row's commands to the next's."""
    v = config.virtual
    speeds = np.asarray(AXIS_SPEEDS_RAD_S) * v.speed_override
    axes = max(float(np.max(np.abs(np.subtract(_joints(row, key), _joints(previous, key))) / speeds))
               for key in ("camera_joints_rad", "target_joints_rad"))
    rail = abs(float(row["rail_m"]) - float(previous["rail_m"])) / v.rail_speed_m_s
    return max(axes, rail)


def _joints(row: dict[str, Any], key: str) -> np.ndarray:
    """(6,) a plan row's commanded joints; zeros for a static mount (a facility's, null)."""
    return np.zeros(6) if row[key] is None else np.asarray(row[key], float)


def _directions(previous: np.ndarray, current: np.ndarray, last: np.ndarray) -> np.ndarray:
    change = np.asarray(current, float) - np.asarray(previous, float)
    return np.where(np.abs(change) > _MOVED_RAD, np.sign(change), last)


def timeline(config: Config, rows: list[dict[str, Any]], start_direction: dict[str, np.ndarray]
             ) -> dict[str, Moment]:
    """Every plan row's ``Moment`` by sample_id; ``start_direction`` per robot (6,): each
    joint's last move before the session's first capture."""
    v = config.virtual
    moments: dict[str, Moment] = {}
    for session in ("calibration", "dataset"):
        ordered = sorted((r for r in rows if r["session"] == session), key=lambda r: r["sample_id"])
        time_s = 0.0
        camera, target = np.asarray(start_direction["camera"], float), np.asarray(start_direction["target"], float)
        for index, row in enumerate(ordered):
            move = None
            if index:
                previous = ordered[index - 1]
                move = move_seconds(config, previous, row)
                time_s += move + v.settle_s + v.expose_s
                if _light(previous) != _light(row):
                    time_s += v.light_change_s
                camera = _directions(_joints(previous, "camera_joints_rad"), _joints(row, "camera_joints_rad"), camera)
                target = _directions(_joints(previous, "target_joints_rad"), _joints(row, "target_joints_rad"), target)
            previous_joints = _joints(ordered[index - 1], "target_joints_rad") if index else None
            moments[row["sample_id"]] = Moment(time_s, camera, target, previous_joints, move)
    return moments
