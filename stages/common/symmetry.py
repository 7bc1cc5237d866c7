"""Which rigid motions map a target onto itself, and which of its keypoints they exchange
(docs/architecture.md section 7). A pose and the pose turned by a symmetry of the object
give the same image, so no model of the images can tell them apart: keypoints that the
symmetry moves (swaps, or puts where no keypoint is) are ambiguous, and a keypoint model
trained on them learns their average. Keypoints chosen on a symmetric mesh (its hull's
farthest corners) are swapped by its symmetries as a rule.

The candidates are the declared discrete symmetries and the half and quarter turns about
the body frame's axes through the body centre (meshes are drawn along their axes); one
holds when it puts every vertex within ``SYMMETRY_TOLERANCE`` of the diameter of a vertex,
the test a declared symmetry passes too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from stages.common import geometry as g
from stages.common.target import SYMMETRY_TOLERANCE, Target


@dataclass(frozen=True)
class Ambiguity:
    """A symmetry of the mesh (its name) and the keypoints it exchanges: pairs (i, j), i < j,
    with keypoint i landing on keypoint j; ``unmatched`` keypoints land on none."""

    symmetry: str
    swapped: tuple[tuple[int, int], ...]
    unmatched: tuple[int, ...]


def candidates(target: Target) -> list[tuple[str, np.ndarray]]:
    """(name, (4, 4) transform in T) of every symmetry worth testing."""
    out = [(f"declared symmetry {index}", np.asarray(m, float)) for index, m in enumerate(target.symmetries_discrete)]
    about_centre = g.make_transform(np.eye(3), target.centre_m)
    for axis in "xyz":
        for quarters in (2, 1):
            turn = g.make_transform(g.axis_angle_matrix(axis, quarters * np.pi / 2), np.zeros(3))
            name = f"{'half' if quarters == 2 else 'quarter'} turn about {axis} through the body centre"
            out.append((name, about_centre @ turn @ g.invert(about_centre)))
    return out


def symmetries(target: Target) -> list[tuple[str, np.ndarray]]:
    """The candidates that map the mesh onto itself."""
    vertices = target.vertices_m
    tree = cKDTree(vertices)
    tolerance = SYMMETRY_TOLERANCE * target.diameter_m
    return [(name, m) for name, m in candidates(target) if tree.query(g.apply(m, vertices))[0].max() <= tolerance]


def ambiguities(target: Target) -> list[Ambiguity]:
    """Per symmetry of the mesh that moves a keypoint, which keypoints it exchanges."""
    tree = cKDTree(target.keypoints_m)
    tolerance = SYMMETRY_TOLERANCE * target.diameter_m
    out = []
    for name, m in symmetries(target):
        distance, index = tree.query(g.apply(m, target.keypoints_m))
        landed = distance <= tolerance
        swapped = tuple(sorted({(min(i, int(j)), max(i, int(j))) for i, j in enumerate(index)
                                if landed[i] and j != i}))
        unmatched = tuple(int(i) for i in np.flatnonzero(~landed))
        if swapped or unmatched:
            out.append(Ambiguity(name, swapped, unmatched))
    return out
