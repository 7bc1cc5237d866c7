"""Planning on a facility folder (stages/plan/facility_plan.py), as a lab would: two labs
besides TRON, written from published dimensions. Each plan's flange poses are reproduced by
an independent forward kinematics of the URDFs (yourdfpy's), its configurations collide
with nothing, its relative poses are the ones the rows state, the robot programs carry the
same joints. Their rehearsal on the virtual testbed: tests/stages/acquire/test_facility_rehearsal.py."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.config import load_config
from pipeline.registry import stage
from stages.common import geometry as g
from stages.common import layout
from stages.common.robots.facility import load_facility, pose_matrix
from stages.common.target import load_target
from tests.conftest import speedplus
from tests.target_folders import cubesat

FACILITIES = Path(__file__).resolve().parents[1] / "facilities"


def _plan(workspace: Path, facility: Path, *args: str) -> list[dict]:
    result = speedplus("plan", "-w", str(workspace), "--profile", "smoke", "--facility", str(facility), *args)
    assert result.returncode == 0, result.stderr
    assert "presented" in result.stdout and "of SO(3) x the range" in result.stdout
    return pq.read_table(workspace / "manifests" / "plan").to_pylist()


@pytest.fixture(scope="module")
def abb(tmp_path_factory):
    workspace = tmp_path_factory.mktemp("abb") / "w"
    return workspace, _plan(workspace, FACILITIES / "abb_rail")


@pytest.fixture(scope="module")
def tripod(tmp_path_factory):
    root = tmp_path_factory.mktemp("tripod")
    target = cubesat(root / "cubesat")
    workspace = root / "w"
    rows = _plan(workspace, FACILITIES / "ur10_tripod", "--target", str(target), "--set", 'plan.lights=["lightbox"]',
                 "--set", "plan.dataset_range_m=[1.3, 1.8]")
    return workspace, rows, target


def _independent_flange(robot, joints, rail_m):
    import yourdfpy

    urdf = yourdfpy.URDF.load(str(robot.chain.source), load_meshes=False, build_collision_scene_graph=False)
    urdf.update_cfg(dict(zip(robot.chain.joint_names, joints, strict=True)))
    return robot.world_from_base(rail_m) @ urdf.get_transform(robot.spec.flange_link, robot.spec.base_link)


def _check_rows(rows: list[dict], facility_dir: Path, target_dir: Path | None, count: int = 24) -> None:
    facility = load_facility(facility_dir)
    target = load_target(target_dir) if target_dir else load_target(
        Path(__file__).resolve().parents[2] / "stages" / "common" / "targets" / "tango")
    assert len(rows) == count
    for row in rows:
        placed = []
        for robot in facility.robots:
            column = "camera" if robot.spec.carries == "camera" else "target"
            joints = np.asarray(row[f"{column}_joints_rad"])
            rail = row["rail_m"] if robot.spec.rail is not None else 0.0
            flange = _independent_flange(robot, joints, rail)
            flange_column = "world_from_camee" if column == "camera" else "world_from_targetee"
            planned = g.transform_from_qt(row[f"{flange_column}_q"], row[f"{flange_column}_t"])
            assert np.abs(flange - planned).max() < 1e-6
            assert robot.chain.within_limits(joints)
            low, high = robot.rail_travel_m
            assert low - 1e-9 <= rail <= high + 1e-9
            placed.append((robot, joints, rail))
        assert facility.clear(placed)
        world_from_camee = g.transform_from_qt(row["world_from_camee_q"], row["world_from_camee_t"])
        world_from_targetee = g.transform_from_qt(row["world_from_targetee_q"], row["world_from_targetee_t"])
        camera = facility.holder("camera")
        world_from_cam = world_from_camee @ pose_matrix(camera.spec.flange_from_tool)
        world_from_target = world_from_targetee @ g.invert(layout.target_from_targetee(target, row["mount"]))
        cam_from_target = g.transform_from_qt(row["cam_from_target_q"], row["cam_from_target_t"])
        assert np.abs(g.invert(world_from_cam) @ world_from_target - cam_from_target).max() < 1e-6


def test_two_arms_on_a_floor_track_plan_what_they_reach(abb):
    workspace, rows = abb
    _check_rows(rows, FACILITIES / "abb_rail", None)
    dataset = [row for row in rows if row["session"] == "dataset"]
    assert {row["light"] for row in dataset} == {"lightbox", "sunlamp"}
    assert all(set(row["light_boxes"]) <= {0, 1} for row in dataset)
    assert any(row["rail_m"] > 0.1 for row in rows)  # the track is used


def test_one_arm_round_a_tripod_plans_what_it_reaches_and_says_its_share(tripod):
    workspace, rows, target = tripod
    _check_rows(rows, FACILITIES / "ur10_tripod", target)
    assert all(row["target_joints_rad"] is None for row in rows)  # the tripod stands still
    mount = pose_matrix(load_facility(FACILITIES / "ur10_tripod").spec.statics[0].world_from_mount)
    for row in rows:
        assert np.abs(g.transform_from_qt(row["world_from_targetee_q"], row["world_from_targetee_t"])
                      - mount).max() < 1e-9
    dataset = [row for row in rows if row["session"] == "dataset"]
    drawn = len(dataset) + sum(row["redraws"] for row in dataset)
    assert drawn > 2 * len(dataset)  # most of SO(3) is out of its reach
    status = " ".join(speedplus("status", "-w", str(workspace)).stdout.replace("│", " ").split())
    assert f"ur10-tripod presented {len(dataset)} of {drawn} dataset poses drawn" in status, status


def test_sequences_are_held_by_the_facilitys_robots(tmp_path):
    """plan.mode = trajectory on a facility folder: every frame reached and clear as the
    plan's poses are, the frames in order, and the plan says the sequences were held whole."""
    workspace = tmp_path / "w"
    result = speedplus("plan", "-w", str(workspace), "--profile", "smoke", "--facility", str(FACILITIES / "abb_rail"),
                       "--set", "plan.mode=trajectory")
    assert result.returncode == 0, result.stderr
    assert "abb-rail held every frame of 2 sequence(s), 8 frames" in " ".join(result.stdout.split())
    rows = pq.read_table(workspace / "manifests" / "plan").to_pylist()
    _check_rows(rows, FACILITIES / "abb_rail", None)
    frames = sorted((row["sample_id"], row["sequence_id"], row["frame"]) for row in rows if row["session"] == "dataset")
    assert [frame for _, _, frame in frames] == [0, 1, 2, 3, 0, 1, 2, 3]


def test_the_programs_carry_the_plans_joints(abb, tripod):
    for workspace, column, robot, unit in ((abb[0], "camera_joints_rad", "camera_arm", "rad"),
                                           (tripod[0], "camera_joints_rad", "ur10", "rad")):
        result = speedplus("export", "-w", str(workspace), "--format", "robot")
        assert result.returncode == 0, result.stderr
        if robot == "camera_arm":  # an ABB arm: no program, and the command says why
            said = " ".join(result.stdout.split())
            assert "camera_arm: its joint waypoints only" in said and "controller 'none'" in said, said
        plan = {row["sample_id"]: row for row in pq.read_table(workspace / "manifests" / "plan").to_pylist()}
        with open(workspace / "export" / "robot" / f"{robot}.csv", newline="") as handle:
            for row in csv.DictReader(handle):
                values = [float(v) for k, v in row.items() if k.endswith(f"_{unit}") and not k.startswith("rail")]
                assert np.allclose(values, plan[row["sample_id"]][column], atol=1e-6)
    assert (tripod[0] / "export" / "robot" / "speedplus_ur10.script").exists()


def test_the_facilitys_files_are_in_the_plans_fingerprint(tmp_path):
    folder = tmp_path / "lab"
    shutil.copytree(FACILITIES / "abb_rail", folder)
    config = load_config("smoke", overrides=[f"facility.path={folder}"])
    before = stage("plan").resolved(config, None).extra["facility"]
    urdf = folder / "irb4600_60_205.urdf"
    urdf.write_text(urdf.read_text().replace('xyz="0 0 0.9"', 'xyz="0 0 0.91"'))
    assert stage("plan").resolved(config, None).extra["facility"] != before
    assert "facility" not in stage("plan").resolved(load_config("smoke"), None).extra  # TRON's stays as it was


@pytest.mark.parametrize(("edit", "setting", "message"), [
    (("[[light_box]]", "[[other_box]]"), None, "unknown key"),
    ('travel = [0.0, 7000.0]\n', None, None),
])
def test_what_a_facility_plan_cannot_do_is_refused(tmp_path, edit, setting, message):
    folder = tmp_path / "lab"
    shutil.copytree(FACILITIES / "abb_rail", folder)
    text = (folder / "facility.toml").read_text()
    if edit is not None and isinstance(edit, tuple):
        text = text.replace(*edit)
    elif edit is not None:  # the target's arm gets a rail too
        text = _rail_on_target(text)
        message = "robots 'camera_arm' and 'target_arm' both ride rails; the plan records one rail position"
    (folder / "facility.toml").write_text(text)
    args = ["--set", setting] if setting else []
    result = speedplus("plan", "-w", str(tmp_path / "w"), "--profile", "smoke", "--facility", str(folder), *args)
    assert result.returncode == 1 and message in " ".join(result.stderr.split()), result.stderr
    assert not (tmp_path / "w" / "manifests" / "plan").exists() or not any((tmp_path / "w" / "manifests" /
                                                                            "plan").glob("*.parquet"))


def _rail_on_target(text: str) -> str:
    """abb_rail's facility.toml with a 1 m rail under the target's arm."""
    return text.replace('flange_from_tool_q = [1.0, 0.0, 0.0, 0.0]\n\n[sun_lamp]',
                        'flange_from_tool_q = [1.0, 0.0, 0.0, 0.0]\n[robot.rail]\naxis = [1.0, 0.0, 0.0]\n'
                        'travel = [0.0, 1000.0]\n\n[sun_lamp]')


def test_the_target_may_ride_the_rail_instead(tmp_path):
    """One robot on a rail, whichever it is: the track under the target's arm, not the camera's."""
    folder = tmp_path / "lab"
    shutil.copytree(FACILITIES / "abb_rail", folder)
    text = (folder / "facility.toml").read_text().replace("[robot.rail]\naxis = [1.0, 0.0, 0.0]\ntravel = [0.0, "
                                                          "7000.0]\n", "")
    (folder / "facility.toml").write_text(_rail_on_target(text))
    assert load_facility(folder).holder("target").spec.rail is not None
    assert load_facility(folder).holder("camera").spec.rail is None
    # the calibration session only: without its track the camera's arm presents 3% of the
    # dataset's poses (4 of 120 drawn), which would make this test slow, not stronger
    result = speedplus("plan", "-w", str(tmp_path / "w"), "--profile", "smoke", "--facility", str(folder),
                       "--set", "plan.n_calibration=6", "--set", "plan.n_dataset=0")
    assert result.returncode == 0, result.stderr
    rows = pq.read_table(tmp_path / "w" / "manifests" / "plan").to_pylist()
    _check_rows(rows, folder, None, 6)
    assert any(row["rail_m"] > 0.05 for row in rows)  # the target's track is used
    result = speedplus("export", "-w", str(tmp_path / "w"), "--format", "robot")
    assert result.returncode == 0, result.stderr
    with open(tmp_path / "w" / "export" / "robot" / "target_arm.csv", newline="") as handle:
        header = next(csv.reader(handle))
    assert "rail_m" in header or "rail_mm" in header


def test_a_relative_facility_path_is_saved_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(FACILITIES)
    config = load_config("smoke", overrides=["facility.path=abb_rail"])
    assert config.facility.path == str(FACILITIES / "abb_rail")  # the same folder from any directory


def test_an_arm_of_seven_joints_is_checked_but_not_planned(tmp_path):
    folder = tmp_path / "lab"
    shutil.copytree(FACILITIES / "ur10_tripod", folder)
    urdf = folder / "ur10.urdf"
    urdf.write_text(urdf.read_text().replace(
        '<joint name="wrist_3-tool0" type="fixed">\n    <parent link="wrist_3_link"/>',
        '<link name="extra"/><joint name="extra_joint" type="revolute"><parent link="wrist_3_link"/>'
        '<child link="extra"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>\n'
        '  <joint name="wrist_3-tool0" type="fixed">\n    <parent link="extra"/>'))
    assert load_facility(folder).robots[0].chain.dof == 7
    result = speedplus("plan", "-w", str(tmp_path / "w"), "--profile", "smoke", "--facility", str(folder))
    message = " ".join(result.stderr.split())
    assert result.returncode == 1 and "has 7 moving joints; the plan records 6" in message, message
    assert not (tmp_path / "w").exists()


def test_a_facility_that_presents_few_poses_is_drawn_from_not_failed(tmp_path):
    """A UR10 round a tripod presents a few per cent of SO(3) x the range: with too few
    redraws allowed for that share, the plan raises them to what the measured share needs
    (issue 57, part 8) instead of failing on the one pose that ran out, and says so."""
    target = cubesat(tmp_path / "cubesat")
    result = speedplus("plan", "-w", str(tmp_path / "w"), "--profile", "smoke", "--facility",
                       str(FACILITIES / "ur10_tripod"), "--target", str(target), "--set", 'plan.lights=["lightbox"]',
                       "--set", "plan.dataset_range_m=[1.3, 1.8]", "--set", "plan.max_redraws=25")
    assert result.returncode == 0, result.stderr
    said = " ".join(result.stdout.split())
    assert "each dataset pose may take up to" in said and "(plan.max_redraws 25)" in said, said
    rows = [r for r in pq.read_table(tmp_path / "w" / "manifests" / "plan").to_pylist() if r["session"] == "dataset"]
    assert len(rows) == 8


def test_a_facility_that_presents_nothing_is_refused_before_planning(tmp_path):
    result = speedplus("plan", "-w", str(tmp_path / "w"), "--profile", "smoke", "--facility",
                       str(FACILITIES / "ur10_tripod"), "--set", 'plan.lights=["lightbox"]',
                       "--set", "plan.dataset_range_m=[30.0, 40.0]")
    said = " ".join(result.stderr.split())
    assert result.returncode == 1 and "presents none of 96 relative poses" in said and "what stops it" in said, said
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "w" / "manifests" / "plan").exists() or not any(
        (tmp_path / "w" / "manifests" / "plan").glob("*.parquet"))


def test_the_redraws_a_share_needs():
    from stages.plan.facility_plan import needed_redraws

    def all_drawn(share: float, count: int, cap: int) -> float:
        return (1 - (1 - share) ** (cap + 1)) ** count

    for share, count in ((0.01, 48), (0.05, 8), (0.3, 100)):
        cap = needed_redraws(share, count)
        assert all_drawn(share, count, cap) >= 0.99 > all_drawn(share, count, cap - 1)
    assert needed_redraws(1.0, 10) == 0


def test_calibration_poses_are_chosen_for_what_they_determine(abb, monkeypatch):
    """Where calibrate will fit the arms, the plan keeps, of each calibration sample's
    candidates, the one that best determines the robots (stages/plan/calibration_choice.py):
    its smallest singular value is above that of the poses drawn one by one, which the smoke
    profile's plan keeps (16 captures for 90 parameters: the arms stay at their URDFs), and
    ``speedplus facility`` measures the same poses as the plan."""
    from stages.common.robots.observability import measure_of
    from stages.plan import calibration_choice
    from stages.plan.stage import facility_rows

    workspace, rows = abb
    folder = FACILITIES / "abb_rail"
    drawn = [row for row in rows if row["session"] == "calibration"]
    smoke = load_config("smoke", overrides=[f"facility.path={folder}"])
    facility, target = load_facility(folder), load_target(workspace / "target")
    assert calibration_choice.arms_fitted(smoke, facility, target) == (
        False, "16 calibration captures for 90 parameters (calibrate.min_arm_redundancy = 3: 45 needed)")
    (_, said), = facility_rows(smoke)
    assert said.startswith(measure_of(calibration_choice.rows_of(facility, drawn, target)).describe(16))
    assert said.endswith("drawn, not chosen: calibrate will leave the arms at their URDFs (16 calibration captures "
                         "for 90 parameters (calibrate.min_arm_redundancy = 3: 45 needed))")
    from stages.plan import stage as plan_stage
    from stages.plan.stage import _calibration_ids, plan_sample

    # 24 poses, where the choice's criterion decides most slots: of the smoke profile's 16
    # (96 equations for 66 unknowns) the first 11 leave the data's smallest eigenvalue at
    # zero, and the log-determinant breaks those ties
    wider = load_config("smoke", overrides=[f"facility.path={folder}", "calibrate.arm_kinematics=on",
                                            "plan.n_calibration=24"])
    planned: list[list[dict]] = []  # the plan's own choice, as speedplus facility runs it (made once)
    original = plan_stage._choose

    def choose(*arguments):
        planned.append(original(*arguments))
        return planned[-1]

    monkeypatch.setattr(plan_stage, "_choose", choose)
    said = facility_rows(wider)
    chosen = measure_of(calibration_choice.rows_of(facility, planned[0], target))
    assert said == [("calibration poses", chosen.describe(24))]
    ids = _calibration_ids(wider)
    drawn = measure_of(calibration_choice.rows_of(
        facility, [plan_sample(wider, "calibration", i, ids[i], target, wider.plan.max_redraws)
                   for i in range(len(ids))], target))
    assert chosen.smallest > drawn.smallest
    assert len(chosen.weak) <= len(drawn.weak)


def test_a_further_calibration_draw_that_runs_out_is_left_out(abb):
    """A candidate beyond a sample's own draw that finds no configuration does not fail the
    plan; the sample's own draw still does, as a plan without the choice would."""
    from stages.plan import calibration_choice
    from stages.plan.poses import PlanningError

    workspace, rows = abb
    chosen = [row for row in rows if row["session"] == "calibration"][:4]
    facility, target = load_facility(FACILITIES / "abb_rail"), load_target(workspace / "target")

    def draw(i: int, k: int) -> dict:
        if k > 0:
            raise PlanningError(f"sample {i}: no reachable robot configuration")
        return chosen[i]

    assert calibration_choice.choose_calibration(facility, target, 4, draw) == chosen

    def failing(i: int, k: int) -> dict:
        raise PlanningError(f"sample {i}: no reachable robot configuration")

    with pytest.raises(PlanningError, match="sample 0"):
        calibration_choice.choose_calibration(facility, target, 4, failing)


def test_calibration_poses_nobody_can_reach_are_said_not_raised_by_the_facility_report():
    """``speedplus facility`` keeps its table when the profile's calibration poses cannot be
    planned there: its row says why, naming the sample."""
    from stages.plan.stage import facility_rows

    config = load_config("smoke", overrides=[f"facility.path={FACILITIES / 'ur10_tripod'}",
                                             "plan.calibration_distance_m=[30.0, 31.0]", "plan.max_redraws=1"])
    (what, said), = facility_rows(config, calibration_poses=2)
    assert what == "calibration poses"
    assert said.startswith("none planned: sample cal000000: no reachable robot configuration in 2 draws"), said
