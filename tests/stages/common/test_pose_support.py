"""A decoded pose the image cannot support is not a pose: seeded poses of a target, the crop
the model saw around its box, and the absurd poses a decoding makes of a detector's miss."""

import numpy as np
import pytest

from stages.common import geometry as g
from stages.common.keypoint_pnp import PnPSolution
from stages.common.model_input import points_box
from stages.common.pose_support import refusal

CAMERA = np.array([[2988.0, 0.0, 960.0], [0.0, 2988.0, 600.0], [0.0, 0.0, 1.0]])
DIST = np.zeros(5)
KEYPOINTS = np.random.default_rng(0).uniform(-0.4, 0.4, size=(11, 3))  # a target of about 0.8 m
WIDTH, HEIGHT = 1920, 1200


def drawn(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A pose in view 4-9 m away, and the box of the target's keypoints at it."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(4.0, 9.0)
    t = np.array([rng.uniform(-0.15, 0.15) * depth, rng.uniform(-0.1, 0.1) * depth, depth])
    q = g.quat_normalize(rng.normal(size=4))
    box = points_box(g.project(g.transform_from_qt(q, t), KEYPOINTS, CAMERA, DIST))
    return q, t, box


def solution(q, t, method="ransac"):
    return PnPSolution(np.asarray(q, float), np.asarray(t, float), method, 11, 0.5)


@pytest.mark.parametrize("seed", range(20))
def test_the_pose_the_crop_shows_stands(seed):
    q, t, box = drawn(seed)
    assert refusal(solution(q, t), KEYPOINTS, box, CAMERA, DIST, WIDTH, HEIGHT) is None
    assert refusal(solution(q, t), KEYPOINTS, None, CAMERA, DIST, WIDTH, HEIGHT) is None  # a whole-image model
    # a pose within a tenth of the range and 10 deg of the truth is what a working model gives: it stands
    rng = np.random.default_rng(100 + seed)
    axis = rng.normal(size=3)
    near = g.quat_multiply(q, g.rotvec_to_quat(np.radians(10) * axis / np.linalg.norm(axis)))
    assert refusal(solution(near, t * 1.1), KEYPOINTS, box, CAMERA, DIST, WIDTH, HEIGHT) is None


@pytest.mark.parametrize("seed", range(20))
def test_a_detector_miss_no_longer_yields_an_absurd_pose(seed):
    """EPnP on scattered keypoints: the target 34 times farther (img000044 of a default
    run), behind the camera, or beside the crop."""
    q, t, box = drawn(seed)
    assert "size" in refusal(solution(q, 34 * t, "all_points"), KEYPOINTS, box, CAMERA, DIST, WIDTH, HEIGHT)
    assert "behind" in refusal(solution(q, -t), KEYPOINTS, box, CAMERA, DIST, WIDTH, HEIGHT)
    side = float(np.max(box[2:] - box[:2]))
    beside = t + np.array([2.0 * side * t[2] / CAMERA[0, 0], 0.0, 0.0])  # the target two box sides away
    assert "outside the crop" in refusal(solution(q, beside), KEYPOINTS, box, CAMERA, DIST, WIDTH, HEIGHT)
