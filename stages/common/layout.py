"""Nominal layout of the testbed (frame K) derived from ``TestbedConfig``.

Everything here is what the lab *believes*: the planner commands robots with it and the
virtual testbed perturbs it to make its hidden truth.
"""

from __future__ import annotations

import numpy as np

from core.config import TestbedConfig
from manifests.schema import MOUNTS
from stages.common import geometry as g
from stages.common.target import Target, main_body_box

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


def target_from_targetee(target: Target, mount: str) -> np.ndarray:
    """(4, 4) nominal model fixture: target flange frame T_K in T for a mount, at mock-up
    scale (``Target.fixture``).

    The ``plus_x`` mounting spot is the ``minus_x`` one turned 180 degrees about the line
    along T's z through the main body's centre (``main_body_box``: the fixtures hold the
    body, whatever its wings do to the whole mesh's box), so that each covers the half of
    the views its opposite side cannot.
    """
    minus_x = g.transform_from_qt(target.fixture.q, np.asarray(target.fixture.t) * target.mockup_scale)
    if mount == "minus_x":
        return minus_x
    if mount == "plus_x":
        low, high = main_body_box(target)
        centre = np.array([(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, 0.0]) * target.mockup_scale
        half_turn = g.make_transform(g.axis_angle_matrix("z", np.pi), centre - g.axis_angle_matrix("z", np.pi) @ centre)
        return half_turn @ minus_x
    raise ValueError(f"unknown mount {mount!r}; expected one of {MOUNT_NAMES}")


#: the calibration board's plate (m): the board's face stands this far off the mock-up
BOARD_PLATE_M = 0.003


def target_from_board(testbed: TestbedConfig, target: Target) -> np.ndarray:
    """(4, 4) ChArUco board frame (OpenCV: origin at a corner, z into the board) in T at
    mock-up scale (``board_pose``)."""
    return g.transform_from_qt(*board_pose(testbed, target))


def board_pose(testbed: TestbedConfig, target: Target) -> tuple[np.ndarray, np.ndarray]:
    """(q (4,), t (3,) m at mock-up scale) of the board frame in T: the target's declared
    one, else the testbed's board lying on the mock-up's top (T's +z: the fixtures hold its
    -x and +x sides), centred on the body centre's line along z, printed face out, board x
    along T's x, on a ``BOARD_PLATE_M`` plate."""
    if target.board is not None:
        return np.array(target.board.q, float), np.asarray(target.board.t, float) * target.mockup_scale
    top = max(float(part.vertices[:, 2].max()) for part in target.parts.values())
    face = np.array([target.centre_m[0], target.centre_m[1], top]) * target.mockup_scale + [0.0, 0.0, BOARD_PLATE_M]
    rotation = np.diag([1.0, -1.0, -1.0])  # board x along T's x, its z down into the mock-up
    return g.matrix_to_quat(rotation), face - rotation @ board_centre(testbed)


def board_centre(testbed: TestbedConfig) -> np.ndarray:
    """(3,) board centre in the board frame, metres."""
    squares_x, squares_y = testbed.board_squares
    return np.array([squares_x, squares_y, 0.0]) * testbed.board_square_m / 2
