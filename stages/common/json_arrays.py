"""The stages' side of the workspace's typed JSON files (``manifests.sidecars``): poses as
4 x 4 arrays, the calibrated camera as a ``LensCamera``, and the mock-up scale. Every error
names the file and the key and says what to rerun."""

from __future__ import annotations

import numpy as np

from manifests import Workspace
from manifests.sidecars import Pose, read_calibration
from stages.common import geometry as g
from stages.common.lens import LensCamera


def matrix(pose: Pose) -> np.ndarray:
    """The (4, 4) transform of a stored pose."""
    return g.transform_from_qt(pose.q, pose.t)


def record(a_from_b: np.ndarray) -> Pose:
    """The stored form of a (4, 4) rigid transform."""
    q, t = g.transform_to_qt(a_from_b)
    return Pose(tuple(q.tolist()), tuple(t.tolist()))


def calibrated_camera(workspace: Workspace) -> LensCamera:
    """The calibrated camera of the labels: K (3, 3), dist (5,), width, height."""
    intrinsics = read_calibration(workspace).intrinsics
    return LensCamera(np.array(intrinsics.camera_matrix, float), np.array(intrinsics.dist, float),
                      intrinsics.width, intrinsics.height)


