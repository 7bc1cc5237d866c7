"""KUKA arm kinematics: IK inverts FK, FK agrees with the published URDF chain, limits hold."""

import numpy as np
import pytest

from stages.common import geometry as g
from stages.common.kinematics import KR16_2, fit_limits, forward, inverse, limit_margin, solve

# Joint origins and axes of kr16_2_macro.xacro (ROS-Industrial kuka_experimental), the
# independent description of the same arm that the OPW parameters must reproduce.
URDF_JOINTS = [
    ((0, 0, 0.675), (0, 0, -1)),
    ((0.26, 0, 0), (0, 1, 0)),
    ((0.68, 0, 0), (0, 1, 0)),
    ((0.67, 0, -0.035), (-1, 0, 0)),
    ((0, 0, 0), (0, 1, 0)),
    ((0, 0, 0), (-1, 0, 0)),
]


def urdf_forward(joints):
    pose = np.eye(4)
    for (origin, axis), q in zip(URDF_JOINTS, joints, strict=True):
        pose = pose @ g.make_transform(np.eye(3), origin) @ g.make_transform(g.rotvec_to_matrix(np.array(axis) * q),
                                                                              np.zeros(3))
    tool0 = g.make_transform(g.axis_angle_matrix("y", np.pi / 2), [0.158, 0, 0])
    return pose @ tool0


def random_joints(rng, n, margin=0.05):
    lower, upper = np.array(KR16_2.lower) + margin, np.array(KR16_2.upper) - margin
    return rng.uniform(lower, upper, size=(n, 6))


@pytest.mark.parametrize("seed", [0, 1])
def test_forward_matches_urdf_chain(seed):
    rng = np.random.default_rng(seed)
    for joints in random_joints(rng, 50):
        np.testing.assert_allclose(forward(KR16_2, joints), urdf_forward(joints), atol=1e-12)


def test_zero_pose_matches_data_sheet():
    # A2 = 0 holds the arm horizontal: flange at x = 260 + 680 + 670 + 158 mm, z = 675 - 35 mm
    pose = forward(KR16_2, np.zeros(6))
    np.testing.assert_allclose(pose[:3, 3], [1.768, 0.0, 0.640], atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inverse_recovers_the_pose_and_contains_the_joints(seed):
    rng = np.random.default_rng(seed)
    joints = random_joints(rng, 200, margin=0.1)
    joints = joints[np.abs(joints[:, 4]) > 0.05]  # away from the wrist singularity (A5 = 0)
    poses = forward(KR16_2, joints)
    solutions = inverse(KR16_2, poses)  # (n, 8, 6)
    wrapped, fits = fit_limits(KR16_2, solutions)
    found = np.zeros(len(joints), dtype=bool)
    for k in range(8):
        ok = np.all(np.isfinite(solutions[:, k]), axis=-1)
        recovered = forward(KR16_2, np.nan_to_num(solutions[:, k]))
        np.testing.assert_allclose(recovered[ok], poses[ok], atol=1e-9)
        # the original joints are one of the solutions (modulo 2 pi)
        difference = (wrapped[:, k] - joints + np.pi) % (2 * np.pi) - np.pi
        found |= fits[:, k] & np.all(np.abs(difference) < 1e-7, axis=-1)
    assert found.all()


def test_solve_respects_limits_and_rejects_unreachable_poses():
    rng = np.random.default_rng(3)
    poses = forward(KR16_2, random_joints(rng, 100, margin=0.2))
    joints, reachable = solve(KR16_2, poses, margin=0.05)
    assert reachable.all()
    assert np.all(limit_margin(KR16_2, joints) >= 0.05 - 1e-12)
    np.testing.assert_allclose(forward(KR16_2, joints), poses, atol=1e-9)
    far = g.make_transform(np.eye(3), [3.0, 0.0, 0.5])  # beyond the 1.6 m reach
    joints, reachable = solve(KR16_2, far[None])
    assert not reachable[0] and np.isnan(joints).all()


def test_link_points_follow_the_urdf_chain():
    from stages.common.kinematics import link_points

    rng = np.random.default_rng(4)
    for joints in random_joints(rng, 20):
        points = link_points(KR16_2, joints)
        pose = np.eye(4)
        chain = []
        for (origin, axis), q in zip(URDF_JOINTS, joints, strict=True):
            pose = pose @ g.make_transform(np.eye(3), origin) @ g.make_transform(
                g.rotvec_to_matrix(np.array(axis) * q), np.zeros(3))
            chain.append(pose[:3, 3])
        np.testing.assert_allclose(points[1], chain[1], atol=1e-12)  # A2 axis
        np.testing.assert_allclose(points[2], chain[2], atol=1e-12)  # A3 axis
        np.testing.assert_allclose(points[3], chain[4], atol=1e-12)  # wrist centre (A5)
        np.testing.assert_allclose(points[4], urdf_forward(joints)[:3, 3], atol=1e-12)
