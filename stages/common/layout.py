"""Nominal layout of the testbed (frame K) derived from ``TestbedConfig``.

Everything here is what the lab *believes*: the planner commands robots with it and the
virtual testbed perturbs it to make its hidden truth.
"""

from __future__ import annotations

import numpy as np

from manifests.schema import MOUNTS
from pipeline.config import TestbedConfig
from stages.common import geometry as g

MOUNT_NAMES = MOUNTS


def world_from_target_base(testbed: TestbedConfig) -> np.ndarray:
    """(4, 4) base frame of the floor-mounted target robot in K."""
    return g.make_transform(g.axis_angle_matrix("z", testbed.target_base_yaw_rad), testbed.target_base_m)


def world_from_camera_base(testbed: TestbedConfig, rail_m: np.ndarray | float) -> np.ndarray:
    """(..., 4, 4) base frame of the ceiling-hung camera robot at rail positions (...) in m.

    The robot hangs upside down (its A1 axis points at the floor): base z = -z of K,
    base x = +x of K (the rail direction).
    """
    rail_m = np.asarray(rail_m, dtype=float)
    position = np.asarray(testbed.rail_origin_m) + rail_m[..., None] * np.array([1.0, 0.0, 0.0])
    return g.make_transform(np.broadcast_to(np.diag([1.0, -1.0, -1.0]), rail_m.shape + (3, 3)), position)


def camee_from_cam(testbed: TestbedConfig) -> np.ndarray:
    """(4, 4) nominal camera fixture: camera frame C in the camera flange frame C_K."""
    return g.transform_from_qt(testbed.camee_from_cam_q, testbed.camee_from_cam_t_m)


def target_from_targetee(testbed: TestbedConfig, mount: str) -> np.ndarray:
    """(4, 4) nominal model fixture: target flange frame T_K in T for a mount.

    The ``plus_x`` mounting spot is the ``minus_x`` one turned 180 degrees about T's z, so
    that each covers the half of the views its opposite side cannot.
    """
    minus_x = g.transform_from_qt(testbed.mount_target_from_targetee_q, testbed.mount_target_from_targetee_t_m)
    if mount == "minus_x":
        return minus_x
    if mount == "plus_x":
        return g.make_transform(g.axis_angle_matrix("z", np.pi), np.zeros(3)) @ minus_x
    raise ValueError(f"unknown mount {mount!r}; expected one of {MOUNT_NAMES}")


def target_from_board(testbed: TestbedConfig) -> np.ndarray:
    """(4, 4) ChArUco board frame (OpenCV: origin at a corner, z into the board) in T."""
    return g.transform_from_qt(testbed.target_from_board_q, testbed.target_from_board_t_m)


def board_centre(testbed: TestbedConfig) -> np.ndarray:
    """(3,) board centre in the board frame, metres."""
    squares_x, squares_y = testbed.board_squares
    return np.array([squares_x, squares_y, 0.0]) * testbed.board_square_m / 2
