"""A procedural Tango mesh consistent with the 11 public keypoints (renderer-independent).

The body is the hexahedron whose 8 corners are keypoints 1-8 (a prism tapered in y: the
solar-panel face is 0.77 m wide, the rear face 0.568 m); three antennas run from the body
to keypoints 9-11. Each part is a separate triangle mesh with texture coordinates, so
renderers can give the mock-up and the synthetic model different materials.
Coordinates: Tango body frame T, full scale, metres.
"""

from __future__ import annotations

import numpy as np

from stages.common.tango import KEYPOINTS_M, SOLAR_PANEL_Z_M
from stages.common.target import MeshPart

ANTENNA_RADIUS_M = 0.008
_ANTENNA_SIDES = 10


def _quad(corners: np.ndarray, name: str) -> MeshPart:
    """Two triangles over 4 corners given counter-clockwise seen from outside."""
    return MeshPart(name, corners.astype(float), np.array([[0, 1, 2], [0, 2, 3]]),
                    np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))


def _merge(parts: list[MeshPart], name: str) -> MeshPart:
    vertices, faces, uv, offset = [], [], [], 0
    for part in parts:
        vertices.append(part.vertices)
        faces.append(part.faces + offset)
        uv.append(part.uv)
        offset += len(part.vertices)
    return MeshPart(name, np.concatenate(vertices), np.concatenate(faces), np.concatenate(uv))


def _side_extent_y(z: float) -> tuple[float, float]:
    """y range of the tapered body at height z (m)."""
    f = z / SOLAR_PANEL_Z_M
    bottom, top = KEYPOINTS_M[4:8, 1], KEYPOINTS_M[0:4, 1]
    return (bottom.min() + f * (top.min() - bottom.min()), bottom.max() + f * (top.max() - bottom.max()))


def antenna_base(tip: np.ndarray) -> np.ndarray:
    """Where an antenna leaves the body: the body surface point nearest its tip, pulled 3%
    inwards so that the cylinder starts inside the body."""
    low, high = _side_extent_y(tip[2])
    half_x = KEYPOINTS_M[:, 0][:8].max()
    return np.array([np.clip(tip[0], -half_x, half_x), np.clip(tip[1], low, high), tip[2]]) * [0.97, 0.97, 1.0]


def _cylinder(start: np.ndarray, end: np.ndarray, radius: float) -> MeshPart:
    axis = end - start
    length = np.linalg.norm(axis)
    axis = axis / length
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    angles = np.linspace(0, 2 * np.pi, _ANTENNA_SIDES, endpoint=False)
    ring = radius * (np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v)
    vertices = np.concatenate([start + ring, end + ring, [end]])
    n = _ANTENNA_SIDES
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces += [[i, j, n + j], [i, n + j, n + i], [n + i, n + j, 2 * n]]
    uv = np.concatenate([np.stack([angles / (2 * np.pi), np.zeros(n)], 1),
                         np.stack([angles / (2 * np.pi), np.ones(n)], 1), [[0.5, 1.0]]])
    return MeshPart("antenna", vertices, np.array(faces), uv)


def tango_parts() -> dict[str, MeshPart]:
    """The model's parts: ``solar_panel`` (+z face), ``rear_panel`` (-z face), ``sides``
    (the four side faces) and ``antennas``; outward-facing triangles."""
    k = KEYPOINTS_M
    top = k[[0, 3, 2, 1]]  # counter-clockwise seen from +z
    bottom = k[[4, 5, 6, 7]]  # counter-clockwise seen from -z
    sides = [
        _quad(np.array([k[4], k[7], k[3], k[0]]), "side_minus_y"),
        _quad(np.array([k[6], k[5], k[1], k[2]]), "side_plus_y"),
        _quad(np.array([k[5], k[4], k[0], k[1]]), "side_minus_x"),
        _quad(np.array([k[7], k[6], k[2], k[3]]), "side_plus_x"),
    ]
    antennas = [_cylinder(antenna_base(tip), tip, ANTENNA_RADIUS_M) for tip in k[8:11]]
    return {
        "solar_panel": _quad(top, "solar_panel"),
        "rear_panel": _quad(bottom, "rear_panel"),
        "sides": _merge(sides, "sides"),
        "antennas": _merge(antennas, "antennas"),
    }
