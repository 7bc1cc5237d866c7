"""Where the motion-capture markers sit on a target's mock-up (docs/architecture.md section 7),
and what of the mock-up hides them.

Declared in ``target.toml`` (``[mockup] markers``, body frame, full scale), or chosen on the
surface of the main body (``target.main_body_part``): on its convex hull, since a point of
a convex surface is seen from its whole outward half-space (a marker there is visible from
as many directions as any can be); spread out by farthest-point sampling over the hull's
face centres, first the one farthest from the body centre; none within reach of a fixture's
flange, which covers that side. Each marker's centre stands ``STAND_OFF_M`` off the surface
along its outward normal (a 14 mm ball on its base).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from stages.common import layout
from stages.common.target import Target, farthest_points, main_body_part

#: markers chosen when the folder declares none: Vicon needs 3 of a rigid body; 6 keep 3 in
#: sight from most directions
CHOSEN_MARKERS = 6
#: a marker's centre off the surface it is stuck on, at mock-up scale (a 14 mm ball on a 3 mm base)
STAND_OFF_M = 0.01
#: no chosen marker closer than this share of the main body's diameter to a fixture's flange
FIXTURE_CLEARANCE = 0.3


@dataclass(frozen=True)
class Markers:
    """The model's markers in the body frame T at mock-up scale (m)."""

    centres_m: np.ndarray  # (M, 3)
    normals: np.ndarray  # (M, 3) outward unit normals of the surface under each marker
    chosen: bool  # True: chosen on the mesh; False: declared in target.toml


@dataclass(frozen=True)
class Hull:
    """The main body's convex hull at mock-up scale: ``normals`` (F, 3) outward unit and
    ``offsets`` (F,) of its faces' planes ``normals @ x + offsets <= 0`` inside."""

    normals: np.ndarray
    offsets: np.ndarray

    def hides(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Whether segments ``start`` -> ``end`` (N, 3) in T pass through the hull (N,):
        the segment clipped against every face's half-space (Cyrus-Beck) keeps a part."""
        direction = end - start
        along = direction @ self.normals.T  # (N, F)
        at_start = start @ self.normals.T + self.offsets  # (N, F): > 0 outside that face
        with np.errstate(divide="ignore", invalid="ignore"):
            crossing = -at_start / along
        entering, leaving = along < 0, along > 0
        t_in = np.max(np.where(entering, crossing, 0.0), axis=1, initial=0.0)
        t_out = np.min(np.where(leaving, crossing, 1.0), axis=1, initial=1.0)
        parallel_outside = np.any((along == 0) & (at_start > 0), axis=1)
        return (t_in < t_out) & ~parallel_outside


def main_body_hull(target: Target) -> Hull:
    """The convex hull of the main body part (``main_body_part``), mock-up scale."""
    hull = _hull(main_body_part(target).vertices * target.mockup_scale)
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]
    return Hull(normals, offsets)


def _hull(points: np.ndarray) -> ConvexHull:
    """A flat main body (a panel modelled as one plane) gets the hull of its points joggled
    by a rounding error: both of its faces, a sheet thin as nothing."""
    try:
        return ConvexHull(points)
    except QhullError:
        return ConvexHull(points, qhull_options="QJ")


def markers(target: Target) -> Markers:
    """The declared markers (normals from the nearest hull face), else ``chosen``."""
    hull = main_body_hull(target)
    if target.markers_m is not None:
        centres = np.asarray(target.markers_m, float) * target.mockup_scale
        # the face whose plane the marker stands farthest outside of is the one it is stuck on
        face = np.argmax(centres @ hull.normals.T + hull.offsets, axis=1)
        return Markers(centres, hull.normals[face], chosen=False)
    return chosen(target)


def chosen(target: Target) -> Markers:
    """``CHOSEN_MARKERS`` spread over the main body's hull, away from the fixtures."""
    body = main_body_part(target).vertices * target.mockup_scale
    spread = _hull(body)
    triangles = body[spread.simplices]  # (F, 3, 3)
    areas = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    centres, normals = triangles.mean(axis=1)[areas > 0], spread.equations[areas > 0, :3]
    flanges = np.stack([layout.target_from_targetee(target, mount)[:3, 3] for mount in layout.MOUNT_NAMES])
    diameter = float(np.max(np.linalg.norm(body - body.mean(axis=0), axis=1))) * 2
    clear = np.min(np.linalg.norm(centres[:, None] - flanges[None], axis=2), axis=1) > FIXTURE_CLEARANCE * diameter
    if np.count_nonzero(clear) >= CHOSEN_MARKERS:
        centres, normals = centres[clear], normals[clear]
    points = farthest_points(centres, target.centre_m * target.mockup_scale, CHOSEN_MARKERS)
    index = [int(np.argmin(np.linalg.norm(centres - p, axis=1))) for p in points]
    return Markers(centres[index] + STAND_OFF_M * normals[index], normals[index], chosen=True)
