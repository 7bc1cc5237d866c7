"""Pattern definitions agree with OpenCV and with the testbed layout."""

import numpy as np

from pipeline.config import load_config
from stages.common import layout
from stages.common.patterns import PatternSpec, board_pattern
from stages.common.workspace_target import planned_target


def test_charuco_corners_are_the_inner_corners_row_by_row_and_survive_json():
    config = load_config("default")
    testbed = config.testbed
    spec = board_pattern(testbed, planned_target(config))
    xs, ys = np.meshgrid(np.arange(1, 11), np.arange(1, 11))
    expected = np.stack([xs.ravel(), ys.ravel(), np.zeros(100)], axis=1) * 0.030
    np.testing.assert_allclose(spec.object_points(), expected, atol=1e-12)
    np.testing.assert_allclose(layout.board_centre(testbed), [0.165, 0.165, 0.0])
    assert PatternSpec.from_json(spec.to_json()) == spec


def test_chessboard_points_start_at_the_first_inner_corner():
    spec = PatternSpec("chessboard", (8, 6), 0.0285)
    points = spec.object_points()
    assert points.shape == (48, 3)
    np.testing.assert_allclose(points[0], 0.0)
    np.testing.assert_allclose(points[1], [0.0285, 0, 0])
    np.testing.assert_allclose(points[8], [0, 0.0285, 0])
