"""The virtual testbed's unmodelled errors, without rendering: each source switches on and
off on its own, and each behaves as its physics says (docs/architecture.md section 5)."""

import dataclasses

import numpy as np
import pytest

from core.config import UNMODELLED_SOURCES, parse_override, with_overrides
from pipeline.config import load_config
from stages.acquire.virtual import mocap, robots
from stages.acquire.virtual.timeline import Moment, timeline
from stages.acquire.virtual.truth import draw_truth
from stages.acquire.virtual.unmodelled import draw_unmodelled
from stages.common import geometry as g
from stages.common.kinematics import KR16_2, forward
from stages.common.statics import GRAVITY_M_S2, KR16_2_MASSES, gravity_torques, potential_energy
from stages.plan.stage import plan_sample, planned_samples


def only(config, *sources):
    return with_overrides(config, [parse_override(f"virtual.unmodelled={list(sources)!r}".replace("'", '"'))])


@pytest.fixture(scope="module")
def config():
    return load_config("default")


@pytest.fixture(scope="module")
def rows(config):
    return [plan_sample(config, *item) for item in planned_samples(config)]


def relative(state):
    return g.invert(state.world_from_cam) @ state.world_from_target


def test_a_source_switched_off_leaves_the_others_draws_unchanged(config):
    every = draw_unmodelled(config)
    for source in UNMODELLED_SOURCES:
        without = draw_unmodelled(only(config, *(s for s in UNMODELLED_SOURCES if s != source)))
        alone = draw_unmodelled(only(config, source))
        for field in dataclasses.fields(every):
            a, b = getattr(every, field.name), getattr(without, field.name)
            # every field belongs to one source: equal to "all on" either without it or alone
            assert _equal(a, b) or _equal(a, getattr(alone, field.name)), (source, field.name)


def _equal(a, b):
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return a == b


def test_with_no_unmodelled_source_the_arm_is_its_geometric_model(config, rows):
    """Off means exactly nothing: the true flange is the true arm's forward kinematics of
    encoder + zero offset, whatever the moment."""
    config = only(config)
    truth = draw_truth(config)
    row = rows[70]
    state = robots.move(config, truth, row, np.random.default_rng(4), Moment(999.0, -np.ones(6), np.ones(6)))
    expected = state.world_from_target_base @ forward(truth.target_arm, state.target_joints_rad
                                                      + truth.target_joint_offsets_rad)
    np.testing.assert_array_equal(state.world_from_targetee, expected)
    assert draw_unmodelled(config).camera_by_session["dataset"] == config.camera


def test_gravity_torque_is_weight_times_lever():
    """A point payload only: A2 carries m g times its horizontal distance from the A2 axis;
    A1 (vertical) carries nothing."""
    massless = dataclasses.replace(KR16_2_MASSES, lower_arm_kg=0.0, upper_arm_kg=0.0, wrist_kg=0.0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        joints = rng.uniform(-0.6, 0.6, 6) + np.array([0, -np.pi / 2, np.pi / 2, 0, 0, 0])
        torque = gravity_torques(KR16_2, massless, np.eye(4), joints, 10.0, np.zeros(3))
        flange = forward(KR16_2, joints)[:3, 3]
        radial = np.array([np.cos(-joints[0]), np.sin(-joints[0]), 0.0])  # in the arm's plane (A1's sign is -1)
        lever = (flange - KR16_2.a1 * radial) @ radial  # horizontal distance from the A2 axis
        assert abs(torque[0]) < 1e-6
        assert abs(abs(torque[1]) - 10.0 * GRAVITY_M_S2 * lever) < 1e-3 * abs(torque[1]) + 1e-6


def test_elasticity_lets_the_arms_sag_under_gravity(config, rows):
    """The loaded arm sits lower than the rigid one: gravity's potential energy drops."""
    rigid, elastic = only(config), only(config, "elasticity")
    truth_rigid, truth_elastic = draw_truth(rigid), draw_truth(elastic)
    u = truth_elastic.unmodelled
    for row in rows[::9]:
        a = robots.move(rigid, truth_rigid, row, np.random.default_rng(1))
        b = robots.move(elastic, truth_elastic, row, np.random.default_rng(1))
        payload = g.apply(g.invert(truth_elastic.target_from_targetee[row["mount"]]), np.zeros((1, 3)))[0]
        energy = [potential_energy(s.target_arm, u.masses["target"], s.world_from_target_base, s.target_link_rad,
                                   4.0, payload, np.array([0, 0, 1.0]))
                  for s in (a, b)]
        assert energy[1] < energy[0]
        assert 1e-5 < np.abs(b.target_link_rad - a.target_link_rad).max() < 5e-3  # tens of arcseconds to 0.3 deg


def test_backlash_depends_on_the_direction_of_the_last_move(config, rows):
    lash = only(config, "backlash")
    truth = draw_truth(lash)
    row = rows[80]
    up = robots.move(lash, truth, row, np.random.default_rng(2), Moment(0.0, np.ones(6), np.ones(6)))
    down = robots.move(lash, truth, row, np.random.default_rng(2), Moment(0.0, -np.ones(6), -np.ones(6)))
    change = down.camera_link_rad - up.camera_link_rad
    lost = truth.unmodelled.lost_motion_rad["camera"]
    # joints loaded beyond the preload rest on one flank; the others move by their lost motion
    moved = np.abs(change) > 0
    assert moved.any()
    np.testing.assert_allclose(np.abs(change[moved]), lost[moved], rtol=1e-9)
    assert not np.allclose(relative(up), relative(down))


def test_the_timeline_follows_the_plans_order(config, rows):
    start = {"camera": np.ones(6), "target": np.ones(6)}
    moments = timeline(config, rows, start)
    for session in ("calibration", "dataset"):
        times = [moments[r["sample_id"]].time_s for r in sorted(rows, key=lambda r: r["sample_id"])
                 if r["session"] == session]
        assert times[0] == 0.0 and np.all(np.diff(times) >= config.virtual.settle_s + config.virtual.expose_s)
    # the dataset session lasts tens of minutes: long enough for the arms to warm
    dataset_end = max(m.time_s for k, m in moments.items() if k.startswith("img"))
    assert 600 < dataset_end < 4 * 3600
    # another order of the same poses: other arrival directions
    reversed_ids = [r["sample_id"] for r in rows]
    shuffled = [{**r, "sample_id": reversed_ids[-1 - i]} for i, r in enumerate(rows)]
    other = timeline(config, shuffled, start)
    same_pose = {r["sample_id"]: s["sample_id"] for r, s in zip(rows, shuffled, strict=True)}
    assert any(not np.array_equal(moments[a].camera_direction, other[b].camera_direction)
               for a, b in same_pose.items())


def test_thermal_drift_grows_the_arms_over_the_session_and_between_sessions(config, rows):
    warm = only(config, "thermal")
    truth = draw_truth(warm)
    u = truth.unmodelled
    start = robots.warming_k(u, "calibration", 0.0, 3600.0)
    later = robots.warming_k(u, "calibration", 1800.0, 3600.0)
    dataset = robots.warming_k(u, "dataset", 0.0, 3600.0)
    assert start == 0.0 and 0.0 < later < u.thermal_rise_k and dataset > 0.0
    row = next(r for r in rows if r["session"] == "calibration")
    cold = robots.move(warm, truth, row, np.random.default_rng(3), Moment(0.0, np.ones(6), np.ones(6)))
    hot = robots.move(warm, truth, row, np.random.default_rng(3), Moment(7200.0, np.ones(6), np.ones(6)))
    growth = hot.camera_arm.c2 / cold.camera_arm.c2 - 1.0
    assert growth == pytest.approx(warm.virtual.link_expansion_per_k
                                   * robots.warming_k(u, "calibration", 7200.0, warm.virtual.thermal_time_constant_s))
    assert 1e-5 < np.linalg.norm(relative(hot)[:3, 3] - relative(cold)[:3, 3]) < 2e-3


def test_motion_capture_errors(config):
    """No error: the markers are triangulated where they are. A scale error scales the
    distances between markers; reflections pull a marker towards its surface."""
    cameras = mocap.camera_positions(config)
    markers = np.array([[2.0, 1.5, 1.2], [2.3, 1.4, 1.1]])
    seen = np.ones((len(cameras), 2), bool)
    exact = mocap.triangulate(cameras, seen, markers, mocap.SystemErrors(1.0, np.zeros((12, 3)), 0.0), None)
    np.testing.assert_allclose(exact, markers, atol=1e-12)
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    shifted = mocap.triangulate(cameras, seen, markers, mocap.SystemErrors(1.0, np.zeros((12, 3)), 5e-4), normals)
    assert np.all(np.einsum("ij,ij->i", shifted - markers, normals) < -1e-5)
    u = draw_unmodelled(only(config, "mocap_calibration"))
    assert u.vicon_scale != 1.0 and np.any(u.vicon_camera_errors)
    turned = mocap.triangulate(cameras, seen, markers, mocap.SystemErrors(1.0, u.vicon_camera_errors, 0.0), None)
    assert 1e-6 < np.abs(turned - markers).max() < 5e-3


def test_intrinsics_change_between_the_sessions_only(config):
    u = draw_unmodelled(only(config, "intrinsics_drift"))
    calibration, dataset = u.camera_by_session["calibration"], u.camera_by_session["dataset"]
    assert calibration == config.camera
    assert 0 < abs(dataset.cx_px - calibration.cx_px) < 3.0 and dataset.fx_px != calibration.fx_px


def test_the_mount_is_anisotropic_and_remounted_for_the_dataset(config, rows):
    mount = only(config, "mount")
    truth = draw_truth(mount)
    shape = truth.unmodelled.mount_compliance
    np.testing.assert_allclose(shape, shape.T)
    assert np.all(np.linalg.eigvalsh(shape) > 0) and np.ptp(np.linalg.eigvalsh(shape)) > 0.05
    row = next(r for r in rows if r["session"] == "calibration")
    calibration = robots.move(mount, truth, row, np.random.default_rng(5))
    dataset = robots.move(mount, truth, {**row, "session": "dataset"}, np.random.default_rng(5))
    assert 0 < np.linalg.norm(relative(calibration)[:3, 3] - relative(dataset)[:3, 3]) < 1e-3
