"""``export --format robot``: the plan as programs for the robots' controllers.

Per robot of the facility the plan is made for (``facility.path``; empty: TRON's, the
built-in folder):
- ``<robot>.csv`` and ``<robot>.json``: the ordered joint waypoints in the controller's
  units (KUKA: degrees, the rail as E1 in mm; UR and others: radians, the rail in m),
  each with the sample it captures and a capture flag;
- ``speedplus_<robot>.src`` (KUKA KRL, ``PTP`` with the rail as E1) or ``.script``
  (URScript, ``movej``), NOT YET VALIDATED ON HARDWARE: each waits at a capture for the
  logger's handshake (digital output 1 raised in position, input 1 from the logger once
  every robot is in position and the image is taken).

Order: each session in turn (calibration, then dataset); within one, the waypoints are
ordered to shorten the session (nearest neighbour, then 2-opt; Croes, Operations Research
6(6), 1958) by a move's time, the slowest axis of either robot at the programmed speed
override or the rail, plus a light change where the light set-up differs. A trajectory
plan keeps each sequence's frames in the plan's order. The virtual testbed captured in
the plan's order: its timeline (thermal drift, backlash) is the plan's, not this one's.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from manifests.files import write_bytes_atomic
from manifests.schema import SESSIONS
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common.robots.facility import Facility, Robot

ROBOT_EXPORT_VERSION = 1
#: a planned flange pose and the URDF's forward kinematics of its joints agree to this (m)
AGREEMENT_M = 1e-6


@dataclass(frozen=True)
class Waypoint:
    """One capture: where every robot goes (joints rad, rail m or None)."""

    sample_id: str
    session: str
    lights: str  # the light set-up (light, active boxes): changing it takes time
    sequence_id: str | None
    commands: dict[str, tuple[np.ndarray, float | None]]


@dataclass(frozen=True)
class Timing:
    """What a move costs: the arms at ``speed_override`` of their axis speeds, the rail at
    ``rail_speed_m_s``, a light change ``light_change_s``."""

    speed_override: float
    rail_speed_m_s: float
    light_change_s: float


def waypoints(plan: list[dict[str, Any]], facility: Facility) -> list[Waypoint]:
    """The plan's reachable rows in its order (session, then sample), each robot's command
    checked: its URDF's forward kinematics must put the flange where the plan says."""
    columns = {"camera": ("camera_joints_rad", "world_from_camee"),
               "target": ("target_joints_rad", "world_from_targetee")}
    rank = {name: index for index, name in enumerate(SESSIONS)}
    out = []
    for row in sorted(plan, key=lambda r: (rank[r["session"]], r["sample_id"])):
        if not row["reachable"]:
            continue
        commands = {}
        for robot in facility.robots:
            joints_column, pose_column = columns[robot.spec.carries]
            joints = np.asarray(row[joints_column], dtype=float)
            rail_m = float(row["rail_m"]) if robot.spec.rail is not None else None
            _agree(robot, joints, rail_m or 0.0, row, pose_column)
            commands[robot.spec.name] = (joints, rail_m)
        lights = f"{row['light']}:{','.join(str(b) for b in row['light_boxes'])}"
        out.append(Waypoint(row["sample_id"], row["session"], lights, row.get("sequence_id"), commands))
    return out


def _agree(robot: Robot, joints: np.ndarray, rail_m: float, row: dict[str, Any], pose_column: str) -> None:
    planned = g.transform_from_qt(row[f"{pose_column}_q"], row[f"{pose_column}_t"])
    flange = robot.world_from_base(rail_m) @ robot.chain.forward(joints)
    off = float(np.linalg.norm(flange[:3, 3] - planned[:3, 3]))
    if off > AGREEMENT_M or np.abs(flange[:3, :3] - planned[:3, :3]).max() > 1e-6:
        raise InputError(f"plan: sample {row['sample_id']}: {robot.spec.name}'s URDF ({robot.chain.source}) puts "
                         f"the flange {off * 1e3:.3f} mm from the planned {pose_column}; the plan was made for "
                         "another room or arm than this facility's (see speedplus facility)")


def move_s(a: Waypoint, b: Waypoint, facility: Facility, timing: Timing) -> float:
    """Seconds from ``a`` to ``b``: the slowest axis of any robot (at its URDF's ``<limit
    velocity>``, 1 rad/s or m/s where it gives none, times the override), plus the light change."""
    slowest = 0.0
    for robot in facility.robots:
        (joints_a, rail_a), (joints_b, rail_b) = a.commands[robot.spec.name], b.commands[robot.spec.name]
        speed = np.nan_to_num(robot.chain.velocity, nan=1.0) * timing.speed_override
        slowest = max(slowest, float(np.max(np.abs(joints_b - joints_a) / speed)))
        if rail_a is not None and rail_b is not None:
            slowest = max(slowest, abs(rail_b - rail_a) / timing.rail_speed_m_s)
    return slowest + (timing.light_change_s if a.lights != b.lights else 0.0)


def ordered(points: list[Waypoint], facility: Facility, timing: Timing) -> list[Waypoint]:
    """Each session in turn, its waypoints in a short tour from the plan's first (sequences
    as blocks in their frames' order)."""
    out: list[Waypoint] = []
    for session in SESSIONS:
        blocks: dict[str, list[Waypoint]] = {}
        for point in (p for p in points if p.session == session):
            blocks.setdefault(point.sequence_id or point.sample_id, []).append(point)
        out += [point for block in _tour(list(blocks.values()), facility, timing) for point in block]
    return out


def _tour(blocks: list[list[Waypoint]], facility: Facility, timing: Timing) -> list[list[Waypoint]]:
    if len(blocks) < 3:
        return blocks
    cost = np.array([[move_s(a[-1], b[0], facility, timing) for b in blocks] for a in blocks])
    tour, left = [0], set(range(1, len(blocks)))
    while left:
        nearest = min(left, key=lambda j: (cost[tour[-1], j], j))
        tour.append(nearest)
        left.remove(nearest)
    if all(len(block) == 1 for block in blocks):  # 2-opt reverses stretches: only where costs are symmetric
        tour = _two_opt(tour, cost)
    return [blocks[i] for i in tour]


def _two_opt(tour: list[int], cost: np.ndarray, rounds: int = 20) -> list[int]:
    """Reverse any stretch whose reversal shortens the open tour (the first stays first)."""
    for _ in range(rounds):
        improved = False
        for i in range(1, len(tour) - 1):
            for j in range(i + 1, len(tour)):
                after = cost[tour[j], tour[j + 1]] if j + 1 < len(tour) else 0.0
                before = cost[tour[i - 1], tour[i]] + after
                swapped = cost[tour[i - 1], tour[j]] + (cost[tour[i], tour[j + 1]] if j + 1 < len(tour) else 0.0)
                if swapped < before - 1e-9:
                    tour[i:j + 1] = tour[i:j + 1][::-1]
                    improved = True
        if not improved:
            break
    return tour


def session_s(points: list[Waypoint], facility: Facility, timing: Timing) -> float:
    """Seconds of moves and light changes along ``points`` in this order."""
    return sum(move_s(a, b, facility, timing) for a, b in zip(points, points[1:], strict=False))


def units(robot: Robot) -> tuple[str, float, str, float]:
    """(joint unit, per rad; rail unit, per m) of the robot's controller."""
    return ("deg", 180.0 / math.pi, "mm", 1000.0) if robot.spec.controller == "kuka" else ("rad", 1.0, "m", 1.0)


def table(robot: Robot, points: list[Waypoint]) -> tuple[list[str], list[list[Any]]]:
    """The robot's waypoints as a header and rows, in its controller's units."""
    joint_unit, per_rad, rail_unit, per_m = units(robot)
    header = ["step", "sample_id", "session", "capture", *(f"{name}_{joint_unit}" for name in robot.chain.joint_names)]
    if robot.spec.rail is not None:
        header.append(f"rail_{rail_unit}")
    rows = []
    for step, point in enumerate(points, start=1):
        joints, rail_m = point.commands[robot.spec.name]
        values = [round(float(v) * per_rad, 6) for v in joints]
        rows.append([step, point.sample_id, point.session, 1, *values]
                    + ([round(float(rail_m) * per_m, 4)] if rail_m is not None else []))
    return header, rows


def csv_text(header: list[str], rows: list[list[Any]]) -> str:
    """A header and rows as CSV text (the export formats' tables)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return buffer.getvalue()


def program_name(robot: Robot) -> str:
    """The program's name (KRL: also its file's, at most 24 characters)."""
    return f"speedplus_{robot.spec.name}".replace("-", "_")[:24]


def krl(robot: Robot, rows: list[list[Any]], timing: Timing) -> str:
    """A KUKA KRL program: ``PTP`` to each waypoint in axis coordinates (A1..A6 deg, E1 mm)
    at the speed override the rehearsal timed, then the capture handshake."""
    percent = round(100 * timing.speed_override)
    lines = ["&ACCESS RVP", "&REL 1", f"DEF {program_name(robot)}( )", "; speedplus export --format robot: NOT YET "
             "VALIDATED ON HARDWARE. Run it in T1 first.", f"; {len(rows)} waypoints; $OUT[1]: in position at a "
             "capture; $IN[1]: the logger has captured", "DECL E6AXIS P", "BAS(#INITMOV, 0)",
             *(f"$VEL_AXIS[{axis}] = {percent}" for axis in range(1, robot.chain.dof + 1))]
    for row in rows:
        dof = robot.chain.dof
        axes = ", ".join(f"A{i + 1} {value:.6f}" for i, value in enumerate(row[4:4 + dof]))
        rail = f", E1 {row[4 + dof]:.4f}" if len(row) > 4 + dof else ""
        lines += [f"; step {row[0]}: {row[1]} ({row[2]})", f"P = {{{axes}{rail}}}", "PTP P"]
        if row[3]:
            lines += ["WAIT SEC 0", "$OUT[1] = TRUE", "WAIT FOR $IN[1]", "$OUT[1] = FALSE", "WAIT FOR NOT $IN[1]"]
    return "\n".join([*lines, "END", ""])


def urscript(robot: Robot, rows: list[list[Any]]) -> str:
    """A URScript program: ``movej`` to each waypoint (rad), then the capture handshake on
    standard digital output 0 and input 0."""
    name = program_name(robot)
    lines = [f"def {name}():", "  # speedplus export --format robot: NOT YET VALIDATED ON HARDWARE. Run it at low "
             "speed first.", f"  # {len(rows)} waypoints; digital out 0: in position; digital in 0: captured"]
    for row in rows:
        joints = ", ".join(f"{value:.6f}" for value in row[4:4 + robot.chain.dof])
        lines += [f"  # step {row[0]}: {row[1]} ({row[2]})", f"  movej([{joints}], a=0.5, v=0.3)"]
        if row[3]:
            lines += ["  set_standard_digital_out(0, True)", "  while not get_standard_digital_in(0):",
                      "    sync()", "  end", "  set_standard_digital_out(0, False)",
                      "  while get_standard_digital_in(0):", "    sync()", "  end"]
    return "\n".join([*lines, "end", f"{name}()", ""])


#: the controllers a program is written for, and its language
PROGRAMS = {"kuka": "KRL", "ur": "URScript"}


def write_programs(out: Path, facility: Facility, points: list[Waypoint], timing: Timing,
                   plan_order_s: float) -> dict[str, float]:
    """Every robot's CSV, JSON and controller program in ``out``; returns the tour's time."""
    tour_s = session_s(points, facility, timing)
    for robot in facility.robots:
        header, rows = table(robot, points)
        joint_unit, _, rail_unit, _ = units(robot)
        document = {"format": "speedplus-robot-waypoints", "version": ROBOT_EXPORT_VERSION, "robot": robot.spec.name,
                    "controller": robot.spec.controller, "urdf": Path(robot.chain.source).name,
                    "joints": list(robot.chain.joint_names), "joint_unit": joint_unit,
                    "rail_unit": rail_unit if robot.spec.rail is not None else None, "validated_on_hardware": False,
                    "moves_s": round(tour_s, 3), "plan_order_moves_s": round(plan_order_s, 3),
                    "waypoints": [dict(zip(header, row, strict=True)) for row in rows]}
        write_bytes_atomic(out / f"{robot.spec.name}.csv", csv_text(header, rows).encode())
        write_bytes_atomic(out / f"{robot.spec.name}.json", (json.dumps(document, indent=1) + "\n").encode())
        if robot.spec.controller == "kuka":
            write_bytes_atomic(out / f"{program_name(robot)}.src", krl(robot, rows, timing).encode())
        elif robot.spec.controller == "ur":
            write_bytes_atomic(out / f"{program_name(robot)}.script", urscript(robot, rows).encode())
    return {"moves_s": tour_s, "plan_order_moves_s": plan_order_s}
