"""Numerical inverse kinematics (stages/common/robots/inverse.py), seeded property tests:
every answer is verified by forward kinematics and inside the limits; reachable poses are
found; unreachable ones give None; the KR 16-2 takes its closed form."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stages.common.facilities import builtin_folder
from stages.common.robots.chain import load_chain
from stages.common.robots.inverse import TOLERANCE_M, TOLERANCE_RAD, Solver, pose_error, solve_numeric

TESTS = Path(__file__).resolve().parents[3] / "facilities"
CHAINS = {"kr16_2": builtin_folder() / "kr16_2.urdf", "irb4600": TESTS / "abb_rail" / "irb4600_60_205.urdf",
          "ur10": TESTS / "ur10_tripod" / "ur10.urdf"}


@pytest.mark.parametrize("name", CHAINS)
def test_reachable_poses_are_solved_and_verified(name):
    chain = load_chain(CHAINS[name], "base_link", "tool0")
    rng = np.random.default_rng(5)
    solved = 0
    for joints in rng.uniform(chain.lower, chain.upper, size=(40, chain.dof)):
        wanted = chain.forward(joints)
        found = solve_numeric(chain, wanted, rng)
        if found is None:
            continue
        solved += 1
        error = pose_error(chain.forward(found), wanted)
        assert np.linalg.norm(error[:3]) < TOLERANCE_M and np.linalg.norm(error[3:]) < TOLERANCE_RAD
        assert chain.within_limits(found)
    assert solved >= 36  # 90%; measured: 98.7-100% of 150 poses of each arm, 36 ms a pose


def test_a_pose_out_of_reach_or_limits_has_no_solution():
    chain = load_chain(CHAINS["irb4600"], "base_link", "tool0")
    rng = np.random.default_rng(0)
    far = np.eye(4)
    far[:3, 3] = [5.0, 0.0, 0.5]
    assert solve_numeric(chain, far, rng) is None
    inside_a_margin = chain.forward(np.array([0.0, 0.0, 0.0, 0.0, 2.09, 0.0]))  # joint 5 at 119.7 of 120 deg
    found = solve_numeric(chain, inside_a_margin, rng, margin=0.2)
    if found is not None:  # another branch of the wrist: then it keeps the margin
        assert chain.within_limits(found, margin=0.2 - 1e-12)


def test_the_kr16_2_takes_its_closed_form_and_other_arms_the_numeric_path():
    assert Solver(load_chain(CHAINS["kr16_2"], "base_link", "tool0")).closed_form is not None
    assert Solver(load_chain(CHAINS["irb4600"], "base_link", "tool0")).closed_form is None
    chain = load_chain(CHAINS["kr16_2"], "base_link", "tool0")
    rng = np.random.default_rng(2)
    wanted = chain.forward(rng.uniform(chain.lower, chain.upper) * 0.8)
    fast = Solver(chain).solve(wanted, rng)
    assert fast is not None and np.abs(chain.forward(fast) - wanted).max() < 1e-7


TABB = Path(__file__).resolve().parents[5] / "shared" / "external" / "tabb_ds1" / "robot_cali.txt"


def test_every_stop_of_a_real_ur10_is_reached_by_the_ur10_urdf():
    """Tabb and Ahmad Yousef's UR10 (88 stops, recorded by others): each flange pose it stood
    at (0.53-1.05 m from its base) is solved and verified by forward kinematics. UR's
    controller base is ROS's base_link turned half a turn about z, so either frame is tried."""
    values = TABB.read_text().split()
    hand_from_base = np.array([float(v) for v in values[1:]]).reshape(int(values[0]), 4, 4)
    base_from_hand = np.linalg.inv(hand_from_base)
    base_from_hand[:, :3, 3] /= 1000.0  # mm
    chain = load_chain(CHAINS["ur10"], "base_link", "tool0")
    rng = np.random.default_rng(0)
    half_turn = np.diag([-1.0, -1.0, 1.0, 1.0])
    for stop, pose in enumerate(base_from_hand, start=1):
        assert any(solve_numeric(chain, frame, rng) is not None for frame in (pose, half_turn @ pose)), f"stop {stop}"


def test_the_pose_errors_rotation_is_the_rotation_vector_on_all_of_so3():
    """The inverse kinematics' fast rotation error (skew part and trace) is
    ``geometry.matrix_to_rotvec`` everywhere: at the identity, at random, and near 180 deg,
    where it hands over to the quaternion."""
    from stages.common import geometry as g

    rng = np.random.default_rng(57)
    axes = g.quat_to_rotvec(g.random_quats(rng, 3000))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi, 2000), rng.uniform(0, 1e-9, 500), np.pi - rng.uniform(0, 1e-3, 500)])
    rotations = g.quat_to_matrix(g.rotvec_to_quat(axes * angles[:, None]))
    wanted = np.eye(4)
    current = np.broadcast_to(np.eye(4), (len(angles), 4, 4)).copy()
    current[:, :3, :3] = np.swapaxes(rotations, -1, -2)  # so that wanted @ current^T is the rotation
    error = pose_error(current, wanted)[:, 3:]
    expected = g.matrix_to_rotvec(rotations)
    differs = np.abs(error - expected).max(axis=1)
    near_pi = angles > np.pi - 1e-3  # where +axis * pi and -axis * pi are the same rotation
    differs[near_pi] = np.minimum(differs[near_pi], np.abs(error + expected)[near_pi].max(axis=1))
    assert differs.max() < 1e-12
