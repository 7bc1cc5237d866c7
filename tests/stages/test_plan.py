"""The plan stage: the poses asked for, and robot commands that really realise them."""

import collections
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from pipeline.config import load_config
from stages.common import geometry as g
from stages.common import layout, tango
from stages.common.kinematics import KR16_2, forward, limit_margin
from stages.common.patterns import board_pattern
from stages.common.workspace_target import planned_target
from stages.plan.stage import PlanningError, plan_sample, planned_samples


@pytest.fixture(scope="module")
def default_config():
    return load_config("default")


@pytest.fixture(scope="module")
def default_plan(default_config):
    return [plan_sample(default_config, *item) for item in planned_samples(default_config)]


def pose(row, prefix):
    return g.transform_from_qt(row[f"{prefix}_q"], row[f"{prefix}_t"])


def dataset(rows):
    return [r for r in rows if r["session"] == "dataset"]


def test_sizes_and_ids(default_plan):
    sessions = collections.Counter(r["session"] for r in default_plan)
    assert sessions == {"calibration": 64, "dataset": 48}
    assert len({r["sample_id"] for r in default_plan}) == 112


def test_same_seed_same_plan_other_seed_other_plan(default_config, default_plan):
    items = planned_samples(default_config)
    again = [plan_sample(default_config, *item) for item in items[:5] + items[64:69]]
    expected = default_plan[:5] + default_plan[64:69]
    for a, b in zip(again, expected, strict=True):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    other = default_config.replace(plan=replace(default_config.plan, seed=7))
    assert not np.allclose(plan_sample(other, "dataset", 0, "img000000")["cam_from_target_q"],
                           default_plan[64]["cam_from_target_q"])


def test_dataset_configurations_are_balanced(default_plan):
    counts = collections.Counter((r["view"], r["light"]) for r in dataset(default_plan))
    assert counts == {(v, light): 12 for v in ("solar_panel", "rear_panel") for light in ("lightbox", "sunlamp")}


def test_dataset_orientations_are_uniform_on_so3(default_plan):
    rotation = np.stack([pose(r, "cam_from_target")[:3, :3] for r in dataset(default_plan)])
    angle = g.rotation_angle(rotation)
    assert stats.kstest(angle, lambda x: (x - np.sin(x)) / np.pi).pvalue > 0.01
    for column in range(3):  # each body axis seen from the camera points anywhere
        assert stats.kstest(rotation[:, 2, column], "uniform", args=(-1, 2)).pvalue > 0.01


def test_view_is_what_the_camera_sees(default_config, default_plan):
    scale = planned_target(default_config).mockup_scale
    for row in default_plan:
        camera_in_target = g.invert(pose(row, "cam_from_target"))[:3, 3]
        above = camera_in_target[2] > scale * tango.BODY_CENTRE_M[2]
        assert (row["view"] == "solar_panel") == above


def test_dataset_range_and_model_in_frame(default_config, default_plan):
    camera = default_config.camera
    scale = planned_target(default_config).mockup_scale
    for row in dataset(default_plan):
        cam_from_target = pose(row, "cam_from_target")
        centre = g.apply(cam_from_target, (tango.BODY_CENTRE_M * scale)[None])[0]
        assert 6.5 <= np.linalg.norm(centre) / scale <= 9.5
        pixels = g.project(cam_from_target, tango.KEYPOINTS_M * scale, camera.camera_matrix(), camera.dist_coeffs())
        assert np.all((pixels >= 0) & (pixels <= [camera.width_px - 1, camera.height_px - 1]))


def test_calibration_poses_look_at_the_board(default_config, default_plan):
    testbed, plan, camera = default_config.testbed, default_config.plan, default_config.camera
    target_from_board = layout.target_from_board(testbed, planned_target(default_config))
    corners = g.apply(target_from_board, board_pattern(testbed, planned_target(default_config)).object_points())
    tilts = []
    for row in default_plan[:64]:
        cam_from_board = pose(row, "cam_from_target") @ target_from_board
        centre = g.apply(cam_from_board, layout.board_centre(testbed)[None])[0]
        assert 0.68 <= np.linalg.norm(centre) <= 0.82  # about 0.75 m
        tilts.append(np.arccos(cam_from_board[2, 2]))  # boresight vs board normal (board z)
        pixels = g.project(pose(row, "cam_from_target"), corners, camera.camera_matrix(), camera.dist_coeffs())
        inside = np.all((pixels >= 0) & (pixels <= [camera.width_px - 1, camera.height_px - 1]), axis=1)
        assert inside.mean() >= plan.calibration_min_corner_fraction
        assert row["light"] == "ambient" and row["view"] == "solar_panel"
    assert max(tilts) <= plan.calibration_max_tilt_rad + 1e-9
    assert max(tilts) > np.radians(30)  # the tilt range is really used
    assert collections.Counter(r["mount"] for r in default_plan[:64]) == {"minus_x": 32, "plus_x": 32}


def test_commands_realise_the_relative_pose(default_config, default_plan):
    testbed = default_config.testbed
    for row in default_plan:
        world_from_camee = pose(row, "world_from_camee")
        world_from_targetee = pose(row, "world_from_targetee")
        # forward kinematics of the commanded joints reaches the flange poses
        np.testing.assert_allclose(
            layout.world_from_camera_base(testbed, row["rail_m"]) @ forward(KR16_2, row["camera_joints_rad"]),
            world_from_camee, atol=1e-9)
        np.testing.assert_allclose(
            layout.world_from_target_base(testbed) @ forward(KR16_2, row["target_joints_rad"]),
            world_from_targetee, atol=1e-9)
        # and the flanges, through the nominal fixtures, give cam_from_target
        cam_from_target = (g.invert(world_from_camee @ layout.camee_from_cam(testbed)) @ world_from_targetee
                           @ g.invert(layout.target_from_targetee(planned_target(default_config), row["mount"])))
        np.testing.assert_allclose(cam_from_target, pose(row, "cam_from_target"), atol=1e-9)
        assert limit_margin(KR16_2, row["camera_joints_rad"]) >= default_config.plan.joint_limit_margin_rad - 1e-9
        assert limit_margin(KR16_2, row["target_joints_rad"]) >= default_config.plan.joint_limit_margin_rad - 1e-9
        assert 0.0 <= row["rail_m"] <= testbed.rail_length_m
        assert row["reachable"]


def test_target_robot_is_never_between_camera_and_model(default_config, default_plan):
    testbed = default_config.testbed
    for row in dataset(default_plan):
        world_from_cam = pose(row, "world_from_camee") @ layout.camee_from_cam(testbed)
        world_from_target = pose(row, "world_from_targetee") @ g.invert(
            layout.target_from_targetee(planned_target(default_config), row["mount"]))
        centre = g.apply(world_from_target, (tango.BODY_CENTRE_M * 0.5)[None])[0]
        sight = centre - world_from_cam[:3, 3]
        for point in (pose(row, "world_from_targetee")[:3, 3], np.asarray(testbed.target_base_m)):
            assert np.dot(point - centre, sight) > 0
        # the fixture is on the far face: the camera is on the other side of the model in x
        camera_in_target = g.invert(pose(row, "cam_from_target"))[:3, 3]
        assert (row["mount"] == "minus_x") == (camera_in_target[0] > 0)


def _shoulder_torques(config, rows):
    """|gravity torque| (N m) on the target arm's A2 at each row's commands, nominal masses."""
    from stages.common.arms import Payload
    from stages.common.statics import KR16_2_MASSES, gravity_torques

    payload = Payload.of(planned_target(config))
    return np.array([abs(gravity_torques(KR16_2, KR16_2_MASSES, layout.world_from_target_base(config.testbed),
                                         r["target_joints_rad"], payload.mass_kg,
                                         payload.centre_in_flange(r["mount"]))[1]) for r in rows])


def test_a_quarter_of_the_calibration_poses_load_the_target_arm_as_the_dataset_does(default_config, default_plan):
    """``plan.calibration_cover``: 16 of 64 calibration poses hold the target arm at a dataset
    pose's joints (on the fixture the session's alternation gives them, every other one a
    sample earlier: 8 on each mount), the target robot behind the model;
    so the calibration's shoulder loads reach the dataset's, where poses
    drawn round the board alone leave most of the dataset's beyond them (issue 57)."""
    from stages.plan.covering import count_covering

    assert count_covering(default_plan) == (16, 64)
    by_joints = {tuple(r["target_joints_rad"]): r for r in dataset(default_plan)}
    testbed, target = default_config.testbed, planned_target(default_config)
    mounts = collections.Counter()
    for index, row in enumerate(default_plan[:64]):
        lender = by_joints.get(tuple(row["target_joints_rad"]))
        assert (lender is not None) == (index % 8 in (3, 6))
        if lender is not None:
            mounts[row["mount"]] += 1
            assert row["mount"] == lender["mount"] == ("minus_x", "plus_x")[index % 2]
            np.testing.assert_allclose(pose(row, "world_from_targetee"), pose(lender, "world_from_targetee"),
                                       atol=1e-12)
            world_from_cam = pose(row, "world_from_camee") @ layout.camee_from_cam(testbed)
            world_from_target = pose(row, "world_from_targetee") @ g.invert(
                layout.target_from_targetee(target, row["mount"]))
            centre = g.apply(world_from_target, (target.centre_m * target.mockup_scale)[None])[0]
            assert np.dot(np.asarray(testbed.target_base_m) - centre, centre - world_from_cam[:3, 3]) > 0
    assert mounts == {"minus_x": 8, "plus_x": 8}
    uncovered_config = default_config.replace(plan=replace(default_config.plan, calibration_cover=0.0))
    uncovered = [plan_sample(uncovered_config, *item) for item in planned_samples(uncovered_config)[:64]]
    assert count_covering(uncovered + dataset(default_plan)) == (0, 64)
    heaviest = _shoulder_torques(default_config, dataset(default_plan)).max()
    assert _shoulder_torques(default_config, default_plan[:64]).max() > 0.9 * heaviest
    assert _shoulder_torques(default_config, uncovered).max() < 0.5 * heaviest


def test_covering_needs_a_dataset_and_poses_mode(default_config):
    from stages.plan.covering import covering_turn

    assert [covering_turn(default_config, i) for i in range(8)] == [None, None, None, 0, None, None, 1, None]
    for plan in (replace(default_config.plan, n_dataset=0), replace(default_config.plan, mode="trajectory"),
                 replace(default_config.plan, calibration_cover=0.0)):
        assert covering_turn(default_config.replace(plan=plan), 3) is None
    half = default_config.replace(plan=replace(default_config.plan, calibration_cover=0.5))
    assert [covering_turn(half, i) for i in range(4)] == [None, 0, 1, None]
    every = default_config.replace(plan=replace(default_config.plan, calibration_cover=1.0))
    assert [covering_turn(every, i) for i in range(4)] == [0, 1, 2, 3]
    for share in (0.2, 0.25, 0.3, 0.4, 0.5):  # each turn once, none past the session, both mounts in turn
        config = default_config.replace(plan=replace(default_config.plan, calibration_cover=share))
        covered = [(i, t) for i in range(64) if (t := covering_turn(config, i)) is not None]
        assert [t for _, t in covered] == list(range(math.floor(64 * share))), share
        mounts = [i % 2 for i, _ in covered]  # the session's fixtures alternate by index
        assert abs(sum(mounts) - len(mounts) / 2) <= 1, (share, covered)
        if share != 0.4:  # two in a row there: turns at 2 and 3 leave no index between them
            assert all(a != b for a, b in zip(mounts, mounts[1:], strict=False)), (share, covered)


def test_light_boxes(default_config, default_plan):
    testbed = default_config.testbed
    centres = np.asarray(testbed.light_box_centres_m)
    for row in dataset(default_plan):
        if row["light"] == "lightbox":
            # the active boxes are on the camera's side of the model: they light what it sees
            world_from_cam = pose(row, "world_from_camee") @ layout.camee_from_cam(testbed)
            world_from_target = pose(row, "world_from_targetee") @ g.invert(
                layout.target_from_targetee(planned_target(default_config), row["mount"]))
            centre = g.apply(world_from_target, (tango.BODY_CENTRE_M * 0.5)[None])[0]
            facing = np.einsum("bi,i->b", centres - centre, world_from_cam[:3, 3] - centre) > 0
            if facing.sum() >= len(row["light_boxes"]):
                assert all(facing[b] for b in row["light_boxes"])
            assert 1 <= len(row["light_boxes"]) <= 3 and len(set(row["light_boxes"])) == len(row["light_boxes"])
            assert all(0 <= b < 10 for b in row["light_boxes"])
        else:
            assert row["light_boxes"] == []


def test_unreachable_poses_are_redrawn_and_counted(default_config):
    # one presentation point, one line of sight, one roll and wide joint margins: some
    # relative poses become unreachable
    testbed = replace(default_config.testbed, target_presentation_m=((1.55, 1.5, 1.25),))
    plan = replace(default_config.plan, sight_elevations_rad=(np.radians(15),), sight_azimuths_rad=(0.0,),
                   camera_roll_candidates=1, joint_limit_margin_rad=0.3)
    config = default_config.replace(testbed=testbed, plan=plan)
    rows = [plan_sample(config, "dataset", i, f"img{i:06d}") for i in range(12)]
    assert sum(r["redraws"] for r in rows) > 0
    assert all(r["reachable"] for r in rows)


def test_impossible_configuration_names_the_sample(default_config):
    testbed = replace(default_config.testbed, rail_length_m=0.0, rail_origin_m=(7.7, 1.5, 3.0))
    config = default_config.replace(testbed=testbed, plan=replace(default_config.plan, max_redraws=2))
    with pytest.raises(PlanningError, match="sample img000003: no reachable robot configuration in 3 draws"):
        plan_sample(config, "dataset", 3, "img000003")


# ----------------------------------------------------------------------- the dataset range
def test_the_default_range_is_speedplus_for_tango_to_the_bit():
    from stages.plan.poses import SPEEDPLUS_RANGE_M, dataset_range

    config = load_config("default")
    chosen = dataset_range(config.plan, planned_target(config), config.testbed)
    assert (chosen.low_m, chosen.high_m, chosen.origin) == (*SPEEDPLUS_RANGE_M, "speedplus")


@pytest.mark.parametrize("seed", range(5))
def test_another_targets_default_range_keeps_speedplus_apparent_size(tmp_path, seed):
    """A target of any size is drawn at Tango's apparent size in SPEED+: the same range in
    diameters, until the room cannot hold it; then SPEED+'s ratio at the room's farthest."""
    from stages.plan.poses import dataset_range, room_reach_m
    from tests.target_folders import boulder

    rng = np.random.default_rng(seed)
    config = load_config("default")
    tango_range = dataset_range(config.plan, planned_target(config), config.testbed)
    target = planned_target(config.replace(target=replace(config.target, path=str(boulder(tmp_path / "b")))))
    target = replace(target, diameter_m=float(rng.uniform(0.1, 4.0)), mockup_scale=float(rng.uniform(0.2, 1.0)))
    chosen = dataset_range(config.plan, target, config.testbed)
    room = room_reach_m(config.testbed, config.plan) / target.mockup_scale
    assert chosen.high_m <= room * (1 + 1e-12)
    np.testing.assert_allclose(chosen.low_m / chosen.high_m, 6.5 / 9.5)
    if chosen.origin == "speedplus":
        np.testing.assert_allclose(chosen.high_m / target.diameter_m, tango_range.high_m / 1.37, rtol=0.01)
    else:
        assert chosen.origin == "room" and 9.5 / 1.37 * target.diameter_m > room
    user = dataset_range(replace(config.plan, dataset_range_m=(7.0, 30.0)), target, config.testbed)
    assert (user.low_m, user.high_m, user.origin) == (7.0, 30.0, "metres")  # the user's metres win, unclipped


def test_a_small_target_plans_with_its_folder_alone(tmp_path):
    """Issue 42: a 6U CubeSat at 1:1 (0.78 m across) planned nothing with the defaults."""
    from tests.conftest import speedplus
    from tests.target_folders import cubesat

    folder = cubesat(tmp_path / "cubesat", mass_kg=4.0)
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(tmp_path / "w"), "--target", str(folder))
    assert result.returncode == 0, result.stderr
    said = " ".join(result.stdout.split())
    assert "= 4.75-6.94 diameters of cubesat6u" in said and "SPEED+'s apparent size" in said
    from manifests import Workspace, read_manifest

    rows = [r for r in read_manifest(Workspace(tmp_path / "w"), "plan").to_pylist() if r["session"] == "dataset"]
    distances = [np.linalg.norm(r["cam_from_target_t"]) for r in rows]  # mock-up scale 1: full scale
    diameter = planned_target(load_config("smoke", overrides=[f"target.path={folder}"])).diameter_m
    assert len(rows) == 8 and all(4.75 * diameter - 0.3 < d < 6.94 * diameter + 0.3 for d in distances)


def test_a_dataset_pose_that_cannot_be_planned_gives_way_to_the_next_lender(default_config):
    """A covering sample whose first lenders cannot be planned takes the next one, rather
    than failing under the dataset sample's message (the dataset's own plan says why), and
    a sample that does not cover draws nothing."""
    from stages.plan import covering
    from stages.plan.poses import PlanningError

    asked = []

    def lend(j):
        asked.append(j)
        if len(asked) <= 3:
            raise PlanningError(f"img{j:06d}: no reachable robot configuration")
        return plan_sample(default_config, "dataset", j, f"img{j:06d}")

    target = planned_target(default_config)
    (cam_from_target, mount, commands), discarded = covering.cover(default_config, 3, target,
                                                                   np.random.default_rng(0), lend)
    assert len(asked) > 3 and mount == "plus_x"
    assert list(commands.target_joints_rad) == lend(asked[-1])["target_joints_rad"]
    assert covering.cover(default_config, 4, target, np.random.default_rng(0), lend) == (None, 0)


def test_solving_only_the_placed_candidates_is_solving_them_all():
    """The closed form is solved only where the room, the rail and the far side leave a
    candidate (``reconfigure._solve_where``): there its joints are those of solving every
    pose, NaN and unreached elsewhere, for reachable and unreachable poses alike."""
    from stages.common.kinematics import solve
    from stages.plan import reconfigure as rc

    rng = np.random.default_rng(7)
    joints = rng.uniform(KR16_2.lower, KR16_2.upper, size=(40, 6))
    poses = forward(KR16_2, joints)
    poses[::3, :3, 3] *= rng.uniform(1.5, 3.0, size=(len(poses[::3]), 1))  # some out of reach
    poses = poses.reshape(5, 8, 4, 4)
    where = rng.random((5, 8)) < 0.6
    solved, reached = rc._solve_where(KR16_2, poses, where, 0.05)
    every, every_reached = solve(KR16_2, poses, 0.05)
    np.testing.assert_array_equal(solved[where], every[where])
    np.testing.assert_array_equal(reached, every_reached & where)
    assert np.isnan(solved[~where]).all() and 0 < reached.sum() < where.sum()


@pytest.mark.parametrize("with_previous", [False, True])
def test_a_reconfiguration_is_the_one_chosen_from_every_candidate_solved(default_config, default_plan,
                                                                         monkeypatch, with_previous):
    """What ``reconfigure`` and ``reconfigure_camera`` choose when only the candidates that the
    joint-free rules (and, for the camera arm, the target arm) leave are solved equals what
    they choose when every candidate is solved, as the plan did before it skipped them: a
    skipped candidate is one that a rule would have refused anyway."""
    from stages.common.kinematics import solve
    from stages.plan import reconfigure as rc

    plan, testbed, target = default_config.plan, default_config.testbed, planned_target(default_config)
    rows = dataset(default_plan)

    def choices() -> list:
        out = []
        previous = None
        for row in rows:
            found = rc.reconfigure(pose(row, "cam_from_target"), row["mount"], plan, testbed, target, True, previous)
            out.append(found)
            previous = found if with_previous else None
        held = out[0]
        out.append(rc.reconfigure_camera(np.stack([pose(r, "cam_from_target") for r in rows]), held, rows[0]["mount"],
                                         plan, testbed, target))
        return out

    skipping = choices()
    assert sum(c is not None for c in skipping) >= 4

    def every(arm, base_from_flange, where, margin):  # every candidate solved, whatever ``where``
        return solve(arm, base_from_flange, margin)

    monkeypatch.setattr(rc, "_solve_where", every)
    for mine, theirs in zip(skipping, choices(), strict=True):
        assert _fields(mine) == _fields(theirs)


def _fields(found) -> list:
    """A reconfiguration (or a camera's (index, reconfiguration)) as exact values: bytes of its arrays."""
    if isinstance(found, tuple):
        return [found[0], *_fields(found[1])]
    if found is None:
        return [None]
    return [np.asarray(value).tobytes() for value in vars(found).values()]
