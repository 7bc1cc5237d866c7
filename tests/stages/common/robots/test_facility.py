"""A facility as the planner sees it (stages/common/robots/facility.py): the built-in TRON
folder is the configuration's testbed; presented poses are reproduced by an independent
forward kinematics (yourdfpy's) and collide with nothing; the share a facility presents
follows what its robots can do."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.config import load_config
from stages.common import geometry as g
from stages.common.layout import camee_from_cam, world_from_camera_base, world_from_target_base
from stages.common.robots.facility import (
    load_facility,
    mount_away,
    placements,
    pose_matrix,
    present,
    presentable_share,
    presentation_points,
    wilson,
)

TESTS = Path(__file__).resolve().parents[3] / "facilities"


def test_tron_is_the_configurations_testbed():
    from stages.acquire.virtual.mocap import camera_aims, camera_positions

    config = load_config("default")
    testbed, facility = config.testbed, load_facility()
    spec = facility.spec
    camera_robot, target_robot = facility.robots
    assert spec.room_m == testbed.room_m
    assert np.allclose(camera_robot.world_from_base(1.3), world_from_camera_base(testbed, 1.3))
    assert camera_robot.rail_travel_m == (0.0, testbed.rail_length_m)
    assert np.allclose(target_robot.world_from_base(), world_from_target_base(testbed))
    assert np.allclose(pose_matrix(camera_robot.spec.flange_from_tool), camee_from_cam(testbed))
    assert camera_robot.spec.payload_kg == testbed.camera_payload_kg
    assert [box.centre_m for box in spec.light_boxes] == list(testbed.light_box_centres_m)
    assert {box.aim_m for box in spec.light_boxes} == {testbed.light_box_aim_m}
    assert {box.size_m for box in spec.light_boxes} == {testbed.light_box_size_m}
    assert spec.sun_lamp.position_m == testbed.sun_lamp_position_m
    assert spec.sun_lamp.radius_m == config.virtual.sun_lamp_radius_m
    assert np.allclose([c[0] for c in spec.motion_capture.cameras], camera_positions(config))
    assert np.allclose([c[1] for c in spec.motion_capture.cameras], camera_aims(config))
    assert spec.motion_capture.marker_sigma_m == config.virtual.vicon_marker_sigma_m
    assert all(robot.solver.closed_form is not None for robot in facility.robots)


@pytest.mark.parametrize("folder", [None, TESTS / "abb_rail", TESTS / "ur10_tripod"], ids=["tron", "abb", "ur10"])
def test_presented_poses_are_reproduced_by_an_independent_forward_kinematics(folder):
    import yourdfpy

    facility = load_facility(folder)
    rng = np.random.default_rng(1)
    distance = 1.0 if folder is not None and folder.name == "ur10_tripod" else 3.5
    found = 0
    for quat in g.random_quats(rng, 40):
        cam_from_target = g.make_transform(g.quat_to_matrix(quat), [0.0, 0.0, distance])
        for world_from_cam, world_from_target in placements(facility, cam_from_target,
                                                             presentation_points(facility, rng), rng, 4):
            presentation = present(facility, world_from_cam, world_from_target, rng)
            if presentation is None:
                continue
            found += 1
            for robot in facility.robots:
                joints, rail_m = presentation.commands[robot.spec.name]
                urdf = yourdfpy.URDF.load(str(facility.directory / robot.spec.urdf), load_meshes=False,
                                          build_collision_scene_graph=False)
                urdf.update_cfg(dict(zip(robot.chain.joint_names, joints, strict=True)))
                flange = robot.world_from_base(rail_m) @ urdf.get_transform(robot.spec.flange_link,
                                                                            robot.spec.base_link)
                if robot.spec.carries == "camera":
                    assert np.abs(flange @ pose_matrix(robot.spec.flange_from_tool) - world_from_cam).max() < 1e-6
                else:  # held by the fixture away from the camera: the folder's or its half-turned twin
                    mount = mount_away(robot, g.invert(world_from_target) @ world_from_cam)
                    assert np.abs(flange @ mount - world_from_target).max() < 1e-6
                    assert (flange[:3, 3] - world_from_target[:3, 3]) @ (world_from_cam[:3, 3]
                                                                         - world_from_target[:3, 3]) < 0
                assert robot.chain.within_limits(joints)
                low, high = robot.rail_travel_m
                assert low - 1e-9 <= rail_m <= high + 1e-9
            assert facility.clear([(robot, *presentation.commands[robot.spec.name]) for robot in facility.robots])
            break
    assert found >= 3


def test_the_share_follows_what_the_robots_can_do(tmp_path):
    tron = presentable_share(load_facility(), (3.25, 4.75), samples=48)
    assert tron.interval[0] > 0.8  # both arms and the rail: nearly all of SO(3)
    tripod = presentable_share(load_facility(TESTS / "ur10_tripod"), (0.6, 1.2), samples=48)
    assert 0.0 < tripod.share < 0.5 and tripod.interval[1] < tron.interval[0]  # one arm round a fixed target
    far = presentable_share(load_facility(TESTS / "ur10_tripod"), (2.5, 3.0), samples=16)
    assert far.presented == 0  # the arm cannot stand 2.5 m from the tripod
    assert {why for why, _ in far.limits} == {"the camera would leave the room", "ur10 cannot reach the camera's pose"}


def test_wilson_interval():
    low, high = wilson(93, 96)
    assert 0.9 < low < 93 / 96 < high < 1.0
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == 1.0
    # every label under the thresholds: the card's interval must still hold its share (48 of 48
    # once gave 0.9999999999999999, which the card's reader refused)
    assert all(wilson(n, n)[1] == 1.0 and wilson(0, n)[0] == 0.0 for n in range(1, 400))
