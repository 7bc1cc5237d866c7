"""The virtual testbed on a facility folder (stages/acquire/virtual/rig.py, room.py), without
rendering: what the controllers report is the URDF's forward kinematics of the encoders (read
by yourdfpy, not by our chain), the truth departs from it by the drawn errors and by nothing
when they are zero, the joints' windup is the payload's gravity torque (checked against the
potential energy's gradient), and the room is the folder's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.config import load_config
from stages.acquire.virtual import rig as rig_module
from stages.acquire.virtual.room import room_of
from stages.acquire.virtual.truth import draw_truth
from stages.common import geometry as g
from stages.common.arms import Payload
from stages.common.statics import GRAVITY_M_S2
from stages.common.workspace_target import planned_target
from stages.plan.stage import plan_sample, planned_samples

FACILITIES = Path(__file__).resolve().parents[2] / "facilities"
RIGID = ["virtual.link_length_sigma_m=0", "virtual.joint_offset_sigma_rad=0", "virtual.base_position_sigma_m=0",
         "virtual.base_rotation_sigma_rad=0", "virtual.rail_scale_sigma=0", "virtual.repeatability_rad=0",
         "virtual.rail_noise_m=0", "virtual.unmodelled=[]", "virtual.model_compliance_rad_per_nm=0"]


@pytest.fixture(scope="module")
def abb():
    config = load_config("smoke", overrides=[f"facility.path={FACILITIES / 'abb_rail'}"])
    rows = [plan_sample(config, *item) for item in planned_samples(config)[:6]]
    return config, rows


def _yourdfpy_flange(robot, joints):
    import yourdfpy

    urdf = yourdfpy.URDF.load(str(robot.chain.source), load_meshes=False, build_collision_scene_graph=False)
    urdf.update_cfg(dict(zip(robot.chain.joint_names, joints, strict=True)))
    return urdf.get_transform(robot.spec.flange_link, robot.spec.base_link)


def test_the_controllers_report_the_urdfs_kinematics_of_their_encoders(abb):
    config, rows = abb
    truth, rig = draw_truth(config), rig_module.draw_rig(config)
    payload = Payload.of(planned_target(config))
    for index, row in enumerate(rows):
        state, segments = rig_module.move(config, truth, rig, row, np.random.default_rng(index), payload)
        camera = rig.camera.robot
        expected = camera.world_from_base(state.rail_m) @ _yourdfpy_flange(camera, state.camera_joints_rad)
        np.testing.assert_allclose(state.kuka_world_from_camee, expected, atol=1e-9)
        target = rig.target.robot
        expected = target.world_from_base(0.0) @ _yourdfpy_flange(target, state.target_joints_rad)
        np.testing.assert_allclose(state.kuka_world_from_targetee, expected, atol=1e-9)
        # the truth differs by mm and tenths of a degree, not by nothing and not wildly
        for true, told in ((state.world_from_camee, state.kuka_world_from_camee),
                           (state.world_from_targetee, state.kuka_world_from_targetee)):
            assert 1e-4 < np.linalg.norm(true[:3, 3] - told[:3, 3]) < 0.03
        assert segments.shape[1:] == (2, 3) and len(segments) >= 12  # both arms' links occlude


def test_without_errors_the_truth_is_the_plan(abb):
    config, rows = abb
    rigid = load_config("smoke", overrides=[f"facility.path={FACILITIES / 'abb_rail'}", *RIGID,
                                            "virtual.model_fixture_sigma_m=0", "virtual.model_fixture_sigma_rad=0",
                                            "virtual.camera_fixture_sigma_m=0", "virtual.camera_fixture_sigma_rad=0"])
    truth, rig = draw_truth(rigid), rig_module.draw_rig(rigid)
    for row in rows:
        state, _ = rig_module.move(rigid, truth, rig, row, np.random.default_rng(0), Payload.of(planned_target(rigid)))
        np.testing.assert_allclose(state.world_from_camee, state.kuka_world_from_camee, atol=1e-12)
        planned = g.transform_from_qt(row["cam_from_target_q"], row["cam_from_target_t"])
        np.testing.assert_allclose(g.invert(state.world_from_cam) @ state.world_from_target, planned, atol=1e-9)


def test_windup_is_the_payloads_gravity_torque(abb):
    """tau = J^T (F, M) is minus the gradient of the payload's potential energy m g z(q):
    checked by central differences at random joints (seeded)."""
    config, _ = abb
    rig = rig_module.draw_rig(config)
    holder = rig_module.Holder(rig.target.robot, rig.target.world_from_mount, rig.target.true_chain,
                               rig.target.joint_offsets_rad, rig.target.base_error, 1.0, np.ones(6))
    rng = np.random.default_rng(46)
    base = holder.robot.world_from_base(0.0)
    mass, load = 7.5, np.array([0.05, -0.02, 0.2])
    for _ in range(5):
        links = rng.uniform(holder.robot.chain.lower, holder.robot.chain.upper) * 0.8
        torque = rig_module.windup(holder, base, links, mass, load)  # stiffness 1: the torque itself

        def height(q):
            return (base @ holder.true_chain.forward(q) @ np.append(load, 1.0))[2]

        step = 1e-6
        gradient = np.array([(height(links + step * e) - height(links - step * e)) / (2 * step) for e in np.eye(6)])
        np.testing.assert_allclose(torque, -mass * GRAVITY_M_S2 * gradient, atol=1e-5)


def test_the_room_is_the_folders():
    config = load_config("smoke", overrides=[f"facility.path={FACILITIES / 'ur10_tripod'}"])
    room = room_of(config)
    assert room.size_m == (5.0, 4.0, 2.8)
    assert len(room.light_boxes) == 1 and room.sun_lamp_m is None and room.mocap_cameras == 0
    abb = room_of(load_config("smoke", overrides=[f"facility.path={FACILITIES / 'abb_rail'}"]))
    assert abb.size_m == (12.0, 4.5, 3.5) and len(abb.light_boxes) == 2  # read in mm, held in m
    tron = room_of(load_config("smoke"))
    assert tron.mocap_cameras == 12 and len(tron.light_boxes) == 10


def test_a_target_on_the_rail_is_moved_and_reported_there(tmp_path):
    """With the rail under the target's arm, the plan's rail_m carries it: the controller
    reports the flange from the base moved along the rail, and the truth follows it."""
    import shutil

    from stages.common.robots.facility import load_facility
    from tests.stages.test_plan_facility import _rail_on_target

    folder = tmp_path / "lab"
    shutil.copytree(FACILITIES / "abb_rail", folder)
    text = (folder / "facility.toml").read_text()
    text = text.replace("[robot.rail]\naxis = [1.0, 0.0, 0.0]\ntravel = [0.0, 7000.0]\n", "")
    (folder / "facility.toml").write_text(_rail_on_target(text))
    config = load_config("smoke", overrides=[f"facility.path={folder}", "plan.n_dataset=0", "plan.n_calibration=3"])
    truth, rig = draw_truth(config), rig_module.draw_rig(config)
    target = load_facility(folder).holder("target")
    payload = Payload.of(planned_target(config))
    for row in (plan_sample(config, *item) for item in planned_samples(config)):
        state, _ = rig_module.move(config, truth, rig, row, np.random.default_rng(0), payload)
        expected = target.world_from_base(state.rail_m) @ _yourdfpy_flange(target, state.target_joints_rad)
        np.testing.assert_allclose(state.kuka_world_from_targetee, expected, atol=1e-9)
        assert np.linalg.norm(state.world_from_targetee[:3, 3] - expected[:3, 3]) < 0.03
