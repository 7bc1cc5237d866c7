"""The procedural Tango mesh agrees with the public keypoints and is closed and outward."""

import numpy as np

from stages.common.tango import KEYPOINTS_M
from stages.common.tango_mesh import tango_parts


def face_normals(part):
    a, b, c = (part.vertices[part.faces[:, i]] for i in range(3))
    return np.cross(b - a, c - a)


def test_body_corners_and_antenna_tips_are_the_keypoints():
    parts = tango_parts()
    body = np.concatenate([parts["solar_panel"].vertices, parts["rear_panel"].vertices, parts["sides"].vertices])
    for keypoint in KEYPOINTS_M[:8]:
        assert np.min(np.linalg.norm(body - keypoint, axis=1)) < 1e-12
    for tip in KEYPOINTS_M[8:]:
        assert np.min(np.linalg.norm(parts["antennas"].vertices - tip, axis=1)) < 1e-12


def test_body_faces_point_outwards():
    parts = tango_parts()
    centre = KEYPOINTS_M[:8].mean(axis=0)
    for name in ("solar_panel", "rear_panel", "sides"):
        part = parts[name]
        centroids = part.vertices[part.faces].mean(axis=1)
        assert np.all(np.einsum("ij,ij->i", face_normals(part), centroids - centre) > 0), name
    np.testing.assert_allclose(face_normals(parts["solar_panel"])[:, :2], 0, atol=1e-12)
    assert np.all(face_normals(parts["solar_panel"])[:, 2] > 0)


def test_uvs_are_in_the_unit_square():
    for part in tango_parts().values():
        assert part.uv.shape == (len(part.vertices), 2)
        assert np.all((part.uv >= 0) & (part.uv <= 1))
