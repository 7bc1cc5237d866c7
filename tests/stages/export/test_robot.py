"""``export --format robot`` (stages/export/robot.py): each robot's waypoints are the plan's
commands in the controller's units, in every file it writes; an independent forward
kinematics of the URDF (yourdfpy's) reproduces the planned flange poses; the order
shortens the session and keeps a sequence's frames in order; a plan made for another room
is refused."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from stages.common import geometry as g
from stages.common.robots.facility import load_facility
from stages.export.robot import Timing, Waypoint, program_name, session_s, table, urscript
from tests.conftest import speedplus

TESTS = Path(__file__).resolve().parents[2] / "facilities"


def _planned(tmp_path: Path, *settings: str) -> Path:
    workspace = tmp_path / "w"
    result = speedplus("plan", "-w", str(workspace), "--profile", "smoke", *settings)
    assert result.returncode == 0, result.stderr
    result = speedplus("export", "-w", str(workspace), "--format", "robot")
    assert result.returncode == 0, result.stderr
    return workspace


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    return _planned(tmp_path_factory.mktemp("robot"))


def _plan(workspace: Path) -> dict[str, dict]:
    rows = pq.read_table(workspace / "manifests" / "plan").to_pylist()
    return {row["sample_id"]: row for row in rows}


def test_every_file_carries_the_plans_commands_in_the_controllers_units(exported):
    plan, out = _plan(exported), exported / "export" / "robot"
    for robot, column in (("camera_robot", "camera_joints_rad"), ("target_robot", "target_joints_rad")):
        with open(out / f"{robot}.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
        assert sorted(row["sample_id"] for row in rows) == sorted(plan)  # each capture once
        assert [row["session"] for row in rows] == sorted((row["session"] for row in rows),
                                                          key=("calibration", "dataset").index)
        document = json.loads((out / f"{robot}.json").read_text())
        assert document["joint_unit"] == "deg" and not document["validated_on_hardware"]
        program = (out / f"speedplus_{robot}.src").read_text()
        moves = re.findall(r"P = \{(.*)\}", program)
        assert len(moves) == len(rows) and program.count("WAIT FOR $IN[1]") == len(rows)
        for row, waypoint, move in zip(rows, document["waypoints"], moves, strict=True):
            degrees = [float(row[f"joint_a{i}_deg"]) for i in range(1, 7)]
            assert np.allclose(np.radians(degrees), plan[row["sample_id"]][column], atol=1e-7)
            assert waypoint["sample_id"] == row["sample_id"]
            krl = dict(re.findall(r"(A\d|E1) (-?[\d.]+)", move))
            assert np.allclose([float(krl[f"A{i}"]) for i in range(1, 7)], degrees, atol=1e-6)
            if robot == "camera_robot":
                assert float(krl["E1"]) == pytest.approx(plan[row["sample_id"]]["rail_m"] * 1000, abs=1e-3)
                assert float(row["rail_mm"]) == pytest.approx(plan[row["sample_id"]]["rail_m"] * 1000, abs=1e-3)


def test_an_independent_forward_kinematics_reproduces_the_planned_flanges(exported):
    import yourdfpy

    plan, facility = _plan(exported), load_facility()
    urdf = yourdfpy.URDF.load(str(facility.directory / "kr16_2.urdf"), load_meshes=False,
                              build_collision_scene_graph=False)
    for robot, column, pose in ((facility.robots[0], "camera_joints_rad", "world_from_camee"),
                                (facility.robots[1], "target_joints_rad", "world_from_targetee")):
        for row in plan.values():
            urdf.update_cfg(dict(zip(robot.chain.joint_names, row[column], strict=True)))
            rail = row["rail_m"] if robot.spec.rail is not None else 0.0
            flange = robot.world_from_base(rail) @ urdf.get_transform("tool0", "base_link")
            assert np.abs(flange - g.transform_from_qt(row[f"{pose}_q"], row[f"{pose}_t"])).max() < 1e-9


def test_the_order_shortens_the_session_and_keeps_sequences(exported, tmp_path):
    document = json.loads((exported / "export" / "robot" / "camera_robot.json").read_text())
    assert document["moves_s"] < document["plan_order_moves_s"]
    sequences = _planned(tmp_path, "--set", "plan.mode=trajectory")
    plan = _plan(sequences)
    with open(sequences / "export" / "robot" / "camera_robot.csv", newline="") as handle:
        order = [row["sample_id"] for row in csv.DictReader(handle)]
    for sequence in {row["sequence_id"] for row in plan.values() if row["sequence_id"]}:
        frames = [plan[s]["frame"] for s in order if plan[s]["sequence_id"] == sequence]
        assert frames == sorted(frames)


def test_a_plan_for_another_room_is_refused(tmp_path):
    workspace = tmp_path / "moved"
    assert speedplus("plan", "-w", str(workspace), "--profile", "smoke", "--set",
                     "testbed.rail_origin_m=[1.7, 1.5, 2.9]").returncode == 0
    before = sorted(str(p.relative_to(workspace)) for p in workspace.rglob("*"))
    result = speedplus("export", "-w", str(workspace), "--format", "robot")
    message = " ".join(result.stderr.split())
    assert result.returncode == 1 and "camera_robot's URDF" in message and "100.000 mm" in message, message
    assert "another room" in message and "Traceback" not in result.stderr
    assert sorted(str(p.relative_to(workspace)) for p in workspace.rglob("*")) == before


def test_urscript_moves_in_radians_with_the_handshake():
    facility = load_facility(TESTS / "ur10_tripod")
    ur10 = facility.robots[0]
    rng = np.random.default_rng(4)
    points = [Waypoint(f"img{i:06d}", "dataset", "ambient:", None,
                       {"ur10": (rng.uniform(-math.pi, math.pi, 6), None)}) for i in range(5)]
    header, rows = table(ur10, points)
    assert header[4:] == [f"{name}_rad" for name in ur10.chain.joint_names]
    script = urscript(ur10, rows)
    moves = [[float(v) for v in move.split(", ")] for move in re.findall(r"movej\(\[(.*?)\]", script)]
    assert np.allclose(moves, [p.commands["ur10"][0] for p in points], atol=1e-6)
    assert script.startswith(f"def {program_name(ur10)}():") and script.count("set_standard_digital_out(0, True)") == 5
    timing = Timing(0.2, 0.3, 45.0)
    assert session_s(points, facility, timing) > 0
