"""Pattern definitions agree with OpenCV and with the testbed layout."""

import numpy as np

from pipeline.config import load_config
from stages.common import layout
from stages.common.kept import Kept
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


def test_the_same_pixels_are_detected_once_and_each_caller_gets_its_own_arrays(monkeypatch):
    """``detect`` keeps what it found by the 8-bit pixels' digest and the pattern: the same
    pixels (also as 16 bits that stretch to them) are detected once; other pixels, or
    another pattern, again; a caller that edits its arrays changes no one else's."""
    import cv2

    from stages.common import patterns

    spec = PatternSpec("chessboard", (7, 5), 0.03)
    board = np.kron((np.indices((6, 8)).sum(axis=0) % 2) * 255, np.ones((40, 40))).astype(np.uint8)
    image = cv2.copyMakeBorder(board, 60, 60, 60, 60, cv2.BORDER_CONSTANT, value=255)
    calls = []
    original = patterns._detect
    monkeypatch.setattr(patterns, "_detect", lambda *args: calls.append(1) or original(*args))
    monkeypatch.setattr(patterns, "_DETECTED", Kept(16))
    pixels, ids = patterns.detect(image, spec)
    assert len(ids) == 35 and len(calls) == 1
    pixels[:] = -1.0  # the caller's own copy
    again, again_ids = patterns.detect(image.astype(np.uint16) * 257, spec)
    assert len(calls) == 1 and (again >= 0).all() and np.array_equal(again_ids, ids)
    shifted = np.roll(image, 3, axis=1)
    moved, _ = patterns.detect(shifted, spec)
    assert len(calls) == 2 and np.allclose(moved, again + [3.0, 0.0], atol=0.2)
    patterns.detect(image, PatternSpec("chessboard", (7, 5), 0.02))
    assert len(calls) == 3
    patterns.detect(image, PatternSpec("chessboard", [7, 5], 0.02))  # a size as a list: the same pattern
    assert len(calls) == 3
