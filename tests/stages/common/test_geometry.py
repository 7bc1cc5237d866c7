"""Seeded property tests of the geometry core, cross-checked with SciPy and OpenCV."""

import cv2
import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from stages.common import geometry as g
from stages.common.json_arrays import matrix, record

SEEDS = [0, 1, 2]


def scipy_quat(q_wxyz):
    return np.concatenate([q_wxyz[..., 1:], q_wxyz[..., :1]], axis=-1)


@pytest.mark.parametrize("seed", SEEDS)
def test_quat_matrix_round_trip_and_scipy_agreement(seed):
    rng = np.random.default_rng(seed)
    q = g.random_quats(rng, 500)
    rotation = g.quat_to_matrix(q)
    np.testing.assert_allclose(rotation, Rotation.from_quat(scipy_quat(q)).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(g.matrix_to_quat(rotation), q, atol=1e-12)
    assert np.all(g.matrix_to_quat(rotation)[:, 0] >= 0)


def test_matrix_to_quat_near_pi_rotations():
    # pivots other than w are needed here: trace ~ -1
    angles = np.pi - np.array([0.0, 1e-9, 1e-6])
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.6, 0, 0.8]])
    rotvec = angles[:, None] * axes
    rotation = Rotation.from_rotvec(rotvec).as_matrix()
    q = g.matrix_to_quat(rotation)
    np.testing.assert_allclose(g.quat_to_matrix(q), rotation, atol=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_q_and_minus_q_are_the_same_rotation(seed):
    rng = np.random.default_rng(seed)
    q = g.random_quats(rng, 100)
    np.testing.assert_allclose(g.quat_to_matrix(q), g.quat_to_matrix(-q), atol=1e-15)
    np.testing.assert_allclose(g.quat_angular_distance(q, -q), 0.0, atol=1e-7)
    np.testing.assert_allclose(g.quat_normalize(-q), q, atol=1e-15)


@pytest.mark.parametrize("seed", SEEDS)
def test_rotvec_round_trip_and_scipy_agreement(seed):
    rng = np.random.default_rng(seed)
    rotvec = rng.standard_normal((300, 3))
    rotvec *= (rng.uniform(0, np.pi - 1e-6, 300) / np.linalg.norm(rotvec, axis=1))[:, None]
    np.testing.assert_allclose(g.rotvec_to_matrix(rotvec), Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(g.matrix_to_rotvec(g.rotvec_to_matrix(rotvec)), rotvec, atol=1e-9)
    # agrees with OpenCV's Rodrigues, the parametrisation the paper uses
    for r in rotvec[:20]:
        np.testing.assert_allclose(cv2.Rodrigues(r)[0], g.rotvec_to_matrix(r), atol=1e-12)


def test_rotvec_is_accurate_at_tiny_angles():
    rotvec = np.array([[1e-12, 0, 0], [0, 3e-9, 0], [1e-7, -2e-7, 5e-8], [0, 0, 0]])
    np.testing.assert_allclose(g.matrix_to_rotvec(g.rotvec_to_matrix(rotvec)), rotvec, atol=1e-15)
    angle = g.rotation_angle(g.rotvec_to_matrix(rotvec))
    np.testing.assert_allclose(angle, np.linalg.norm(rotvec, axis=1), rtol=1e-6, atol=1e-15)


@pytest.mark.parametrize("seed", SEEDS)
def test_invert_and_compose(seed):
    rng = np.random.default_rng(seed)
    a_from_b = g.transform_from_qt(g.random_quats(rng, 50), rng.normal(size=(50, 3)))
    b_from_c = g.transform_from_qt(g.random_quats(rng, 50), rng.normal(size=(50, 3)))
    b_from_a = g.invert(a_from_b)
    np.testing.assert_allclose(a_from_b @ b_from_a, np.broadcast_to(np.eye(4), (50, 4, 4)), atol=1e-12)
    np.testing.assert_allclose(g.invert(b_from_a), a_from_b, atol=1e-12)
    a_from_c = a_from_b @ b_from_c
    np.testing.assert_allclose(g.invert(a_from_c), g.invert(b_from_c) @ b_from_a, atol=1e-12)
    points_c = rng.normal(size=(50, 7, 3))
    np.testing.assert_allclose(g.apply(a_from_c, points_c), g.apply(a_from_b, g.apply(b_from_c, points_c)), atol=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_qt_round_trip(seed):
    rng = np.random.default_rng(seed)
    q, t = g.random_quats(rng, 40), rng.normal(size=(40, 3))
    q2, t2 = g.transform_to_qt(g.transform_from_qt(q, t))
    np.testing.assert_allclose(q2, q, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=0)


@pytest.mark.parametrize("seed", SEEDS)
def test_angular_distance_matches_scipy_and_is_symmetric(seed):
    rng = np.random.default_rng(seed)
    qa, qb = g.random_quats(rng, 200), g.random_quats(rng, 200)
    expected = (Rotation.from_quat(scipy_quat(qa)).inv() * Rotation.from_quat(scipy_quat(qb))).magnitude()
    ra, rb = g.quat_to_matrix(qa), g.quat_to_matrix(qb)
    np.testing.assert_allclose(g.angular_distance(ra, rb), expected, atol=1e-9)
    np.testing.assert_allclose(g.angular_distance(rb, ra), expected, atol=1e-9)
    np.testing.assert_allclose(g.quat_angular_distance(qa, qb), expected, atol=1e-9)


@pytest.mark.parametrize("seed", SEEDS)
def test_weighted_chordal_mean_matches_scipy(seed):
    rng = np.random.default_rng(seed)
    base = Rotation.from_quat(scipy_quat(g.random_quats(rng, 1)))
    noise = Rotation.from_rotvec(rng.normal(scale=0.2, size=(6, 3)))
    rotations = (base * noise).as_matrix()
    weights = rng.uniform(0.1, 2.0, 6)
    expected = Rotation.from_matrix(rotations).mean(weights=weights).as_matrix()
    np.testing.assert_allclose(g.chordal_mean(rotations, weights), expected, atol=1e-9)


def test_chordal_mean_of_two_equal_weights_is_the_midpoint_and_has_det_one():
    a = g.rotvec_to_matrix([0, 0, 0.3])
    b = g.rotvec_to_matrix([0, 0, -0.1])
    mean = g.chordal_mean(np.stack([a, b]))
    np.testing.assert_allclose(mean, g.rotvec_to_matrix([0, 0, 0.1]), atol=1e-12)
    reflected = g.project_to_so3(np.diag([1.0, 1.0, -1.0]) + 1e-3)
    assert np.isclose(np.linalg.det(reflected), 1.0)


def test_chordal_mean_rejects_bad_weights():
    with pytest.raises(ValueError):
        g.chordal_mean(np.stack([np.eye(3), np.eye(3)]), np.array([0.0, 0.0]))


def test_random_quats_are_uniform_on_so3():
    rng = np.random.default_rng(7)
    rotation = g.quat_to_matrix(g.random_quats(rng, 4000))
    angle = g.rotation_angle(rotation)
    # Haar measure: the rotation angle has CDF (theta - sin theta) / pi
    assert stats.kstest(angle, lambda x: (x - np.sin(x)) / np.pi).pvalue > 0.01
    # any body axis maps to a uniform direction: its z component is uniform on [-1, 1]
    for column in range(3):
        assert stats.kstest(rotation[:, 2, column], "uniform", args=(-1, 2)).pvalue > 0.01


def test_random_quats_detects_a_non_uniform_sampler():
    # the uniformity check above must be able to fail: uniform Euler angles are not uniform
    rng = np.random.default_rng(7)
    euler = rng.uniform(-np.pi, np.pi, size=(4000, 3))
    rotation = Rotation.from_euler("zyx", euler).as_matrix()
    pvalues = [stats.kstest(rotation[:, 2, c], "uniform", args=(-1, 2)).pvalue for c in range(3)]
    assert min(pvalues) < 1e-6


@pytest.mark.parametrize("seed", SEEDS)
def test_kuka_round_trip_and_convention(seed):
    rng = np.random.default_rng(seed)
    xyzabc = np.concatenate(
        [rng.uniform(-2000, 2000, (100, 3)), rng.uniform(-180, 180, (100, 1)),
         rng.uniform(-89.9, 89.9, (100, 1)), rng.uniform(-180, 180, (100, 1))], axis=1)
    transform = g.kuka_to_transform(xyzabc)
    np.testing.assert_allclose(transform[:, :3, 3], xyzabc[:, :3] / 1000.0)
    expected = Rotation.from_euler("ZYX", xyzabc[:, 3:], degrees=True).as_matrix()
    np.testing.assert_allclose(transform[:, :3, :3], expected, atol=1e-12)
    np.testing.assert_allclose(g.transform_to_kuka(transform), xyzabc, atol=1e-8)


def test_kuka_gimbal_lock_round_trips_the_transform():
    xyzabc = np.array([[100.0, 0, 0, 30.0, 90.0, 10.0], [0, 50.0, 0, -20.0, -90.0, 45.0]])
    transform = g.kuka_to_transform(xyzabc)
    np.testing.assert_allclose(g.kuka_to_transform(g.transform_to_kuka(transform)), transform, atol=1e-9)


@pytest.mark.parametrize("seed", SEEDS)
def test_projection_matches_opencv(seed):
    rng = np.random.default_rng(seed)
    camera_matrix = np.array([[2988.5795, 0, 960.0], [0, 2988.3401, 600.0], [0, 0, 1]])
    dist = np.array([-0.22383017, 0.51409797, -0.00066500, -0.00021405, -0.13124227])
    cam_from_target = g.transform_from_qt(g.random_quats(rng, 1)[0], [0.1, -0.05, 4.0])
    points = rng.uniform(-0.5, 0.5, (30, 3))
    ours = g.project(cam_from_target, points, camera_matrix, dist)
    rvec = g.matrix_to_rotvec(cam_from_target[:3, :3])
    theirs, _ = cv2.projectPoints(points, rvec, cam_from_target[:3, 3], camera_matrix, dist)
    np.testing.assert_allclose(ours, theirs[:, 0, :], atol=1e-6)


def test_look_at_rotation_points_boresight_and_keeps_image_up():
    world_from_cam = g.look_at_rotation([1.0, 0, 0], [0, 0, 1.0])
    np.testing.assert_allclose(world_from_cam[:, 2], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(world_from_cam[:, 1], [0, 0, -1], atol=1e-15)  # y down
    assert np.isclose(np.linalg.det(world_from_cam), 1.0)


def test_pose_json_and_manifest_columns_round_trip():
    rng = np.random.default_rng(9)
    a_from_b = g.transform_from_qt(g.random_quats(rng, 1)[0], rng.normal(size=3))
    np.testing.assert_allclose(matrix(record(a_from_b)), a_from_b, atol=1e-12)  # the JSON files' Pose
    columns = g.pose_columns("cam_from_target", a_from_b)
    np.testing.assert_allclose(g.transform_from_qt(columns["cam_from_target_q"], columns["cam_from_target_t"]),
                               a_from_b, atol=1e-12)
    assert g.pose_columns("vicon", None) == {"vicon_q": None, "vicon_t": None}
