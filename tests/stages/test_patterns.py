"""Pattern definitions agree with OpenCV and with the testbed layout."""

import numpy as np

from pipeline.config import load_config
from stages import layout
from stages.patterns import PatternSpec, board_pattern


def test_charuco_corners_match_the_layout_and_survive_json():
    testbed = load_config("default").testbed
    spec = board_pattern(testbed)
    np.testing.assert_allclose(spec.object_points(), layout.board_inner_corners(testbed), atol=1e-12)
    assert PatternSpec.from_json(spec.to_json()) == spec


def test_chessboard_points_start_at_the_first_inner_corner():
    spec = PatternSpec("chessboard", (8, 6), 0.0285)
    points = spec.object_points()
    assert points.shape == (48, 3)
    np.testing.assert_allclose(points[0], 0.0)
    np.testing.assert_allclose(points[1], [0.0285, 0, 0])
    np.testing.assert_allclose(points[8], [0, 0.0285, 0])
