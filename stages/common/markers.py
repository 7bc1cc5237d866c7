"""Where the motion-capture markers sit on a target's mock-up (docs/architecture.md section 7),
and what of the mock-up hides them.

Declared in ``target.toml`` (``[mockup] markers``, body frame, full scale), or chosen where a
lab could stick them: on the surface of every part at least ``MIN_SURFACE_M`` wide (a 14 mm
ball on its base needs a face, not an antenna whip), none within reach of a fixture's
flange, which covers that side. They are chosen for the rigid-body fit they give over the
whole target (``marker_fit``), not for their spread on one part: from directions all round
the mock-up, the markers whose surface faces that way are the ones seen, and the set is
the one (greedy, then one exchange pass) that minimises the mean position variance of the
fit at the target's centre over those directions. Where the room's cameras and the poses
the mock-up will be held in are known (the virtual testbed, from the plan and the room:
``Sightlines``), the markers are chosen for those instead: a marker counts at a pose when
two of the room's cameras see it, inside their field of view and range, past every part
of the mock-up, as the motion capture itself will see it (issue 57: a 1:4 rocket body's
markers chosen for a ring of cameras were seen by TRON's, at the smoke profile's
calibration poses, one or two at a time). A target whose main body is a small part
of its span (a bus with long panels) thus gets markers on the panels too: on the body alone
they would sit within a few centimetres of each other, and the fit's rotation, and the
position it implies a panel's length away, would err by centimetres. Each marker's centre
stands ``STAND_OFF_M`` off the surface along its outward normal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from manifests.target import TargetError
from stages.common import geometry as g
from stages.common import layout
from stages.common.marker_fit import mean_point_variance
from stages.common.target import MeshPart, Target, farthest_points, main_body_part

if TYPE_CHECKING:
    from scipy.spatial import ConvexHull

#: markers chosen when the folder declares none: Vicon needs 3 of a rigid body; 6 keep 3 in
#: sight from most directions
CHOSEN_MARKERS = 6
#: a marker's centre off the surface it is stuck on, at mock-up scale (a 14 mm ball on a 3 mm base)
STAND_OFF_M = 0.01
#: a part takes markers when its box's second-smallest side is at least this, at mock-up
#: scale: a marker's base needs a face that wide (a panel has one, an antenna whip has not)
MIN_SURFACE_M = 0.02
#: no two chosen markers closer than this at mock-up scale: a system tells a rigid body's
#: markers apart by their distances (and two on a panel's two faces would be one there)
MIN_SEPARATION_M = 0.05
#: no chosen marker closer than this share of the main body's diameter to a fixture's flange
FIXTURE_CLEARANCE = 0.3
#: a camera sees a marker within this angle of its surface's normal (a retro-reflective
#: ball on a surface: wider than that, its own surface hides half of it)
SEEN_WITHIN_RAD = np.radians(70.0)
#: the motion-capture cameras the choice assumes: a ring all round the target on the walls,
#: this far above it (TRON's 12 at 2.8 m see the mock-up at 1-1.5 m from 2-5 m away); a
#: marker counts when two of them see it, as a system needs
CAMERA_ELEVATION_RAD = np.radians(30.0)
RING_CAMERAS = 12
#: the mock-up's attitudes the choice averages over (their up directions in the body frame,
#: a Fibonacci sphere), and the candidates it weighs at most
ATTITUDES = 96
MAX_CANDIDATES = 600
#: cameras that must see a marker for the system to place it
MIN_CAMERAS = 2

#: which candidate markers (centres (C, 3), normals (C, 3), T, mock-up scale) are placed
#: at each of D poses: (C, D)
Sight = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Markers:
    """The model's markers in the body frame T at mock-up scale (m)."""

    centres_m: np.ndarray  # (M, 3)
    normals: np.ndarray  # (M, 3) outward unit normals of the surface under each marker
    chosen: bool  # True: chosen on the mesh; False: declared in target.toml
    parts: tuple[str, ...]  # (M,) the part each marker is stuck on


@dataclass(frozen=True)
class Hull:
    """A part's convex hull at mock-up scale: ``normals`` (F, 3) outward unit and
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


@dataclass(frozen=True)
class Occluders:
    """The convex hulls of a mock-up's parts: a sight line through any of them is hidden."""

    hulls: tuple[Hull, ...]

    def hides(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        hidden = np.zeros(len(start), bool)
        for hull in self.hulls:
            hidden |= hull.hides(start, end)
        return hidden


def main_body_hull(target: Target) -> Hull:
    """The convex hull of the main body part (``main_body_part``), mock-up scale."""
    return _as_hull(main_body_part(target).vertices * target.mockup_scale)


def occluders(target: Target) -> Occluders:
    """Every part's convex hull at mock-up scale: what of the mock-up hides a marker."""
    return Occluders(tuple(_as_hull(part.vertices * target.mockup_scale) for part in target.parts.values()))


def _as_hull(points: np.ndarray) -> Hull:
    hull = _hull(points)
    return Hull(hull.equations[:, :3], hull.equations[:, 3])


def _hull(points: np.ndarray) -> ConvexHull:
    """A flat body (a panel modelled as one plane) gets the hull of its points joggled
    by a rounding error: both of its faces, a sheet thin as nothing."""
    from scipy.spatial import ConvexHull, QhullError
    try:
        return ConvexHull(points)
    except QhullError:
        return ConvexHull(points, qhull_options="QJ")


@dataclass(frozen=True)
class Sightlines:
    """A room's motion-capture cameras and the poses the mock-up will be held in, in K
    (m, mock-up scale): positions (J, 3), the points they aim at (J, 3), their full field
    of view (rad) and range (m), and ``world_from_target`` (D, 4, 4)."""

    cameras_m: np.ndarray
    aims_m: np.ndarray
    fov_rad: float
    max_range_m: float
    world_from_target: np.ndarray

    def seen(self, centres: np.ndarray, body: Occluders) -> np.ndarray:
        """(C, D) whether ``MIN_CAMERAS`` cameras see each marker centre (C, 3; T) at each
        pose: inside their field of view and range, the sight line clear of every part's
        hull (shortened by 0.5% at the marker, whose own face it ends on)."""
        boresight = self.aims_m - self.cameras_m
        boresight /= np.linalg.norm(boresight, axis=1, keepdims=True)
        out = np.zeros((len(centres), len(self.world_from_target)), bool)
        for d, world_from_target in enumerate(self.world_from_target):
            world = g.apply(world_from_target, centres)
            to_marker = world[None] - self.cameras_m[:, None]  # (J, C, 3)
            distance = np.linalg.norm(to_marker, axis=-1)
            inside = ((np.einsum("jci,ji->jc", to_marker, boresight) / distance > np.cos(self.fov_rad / 2))
                      & (distance < self.max_range_m))
            cameras_body = g.apply(g.invert(world_from_target), self.cameras_m)  # (J, 3)
            starts = np.repeat(cameras_body, len(centres), axis=0)
            ends = np.tile(centres, (len(cameras_body), 1))
            hidden = body.hides(starts, starts + 0.995 * (ends - starts)).reshape(inside.shape)
            out[:, d] = np.sum(inside & ~hidden, axis=0) >= MIN_CAMERAS
        return out


def markers(target: Target, sight: Sight | None = None) -> Markers:
    """The declared markers (normals from the main body's nearest hull face), else
    ``chosen`` (for ``sight``, the room's cameras at the planned poses, where given)."""
    if target.markers_m is not None:
        hull = main_body_hull(target)
        centres = np.asarray(target.markers_m, float) * target.mockup_scale
        # the face whose plane the marker stands farthest outside of is the one it is stuck on
        face = np.argmax(centres @ hull.normals.T + hull.offsets, axis=1)
        return Markers(centres, hull.normals[face], False, (main_body_part(target).name,) * len(centres))
    return chosen(target, sight)


def candidates(target: Target) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where a marker could stand, mock-up scale: centres (C, 3) ``STAND_OFF_M`` off the
    faces of the parts wide enough to take one, their outward normals (C, 3), and the
    index of each one's part in ``target.parts`` (C,); clear of the fixtures' flanges when
    enough are; at most ``MAX_CANDIDATES``, drawn by area (seeded, so the same every time)."""
    centres, normals, owners, areas = [], [], [], []
    for index, part in enumerate(target.parts.values()):
        vertices = part.vertices * target.mockup_scale
        if np.sort(np.ptp(vertices, axis=0))[1] < MIN_SURFACE_M:
            continue
        centre, normal, area = _faces(part, vertices)
        keep = area > 0
        centres.append(centre[keep])
        normals.append(normal[keep])
        owners.append(np.full(int(keep.sum()), index))
        areas.append(area[keep])
    if not centres:
        raise TargetError(f"target {target.name}: no part is {MIN_SURFACE_M * 1000:.0f} mm wide at mock-up scale: "
                         "declare [mockup] markers")
    centre, normal, owner = np.concatenate(centres), np.concatenate(normals), np.concatenate(owners)
    area = np.concatenate(areas)
    centre = centre + STAND_OFF_M * normal
    body = main_body_part(target).vertices * target.mockup_scale
    flanges = np.stack([layout.target_from_targetee(target, mount)[:3, 3] for mount in layout.MOUNT_NAMES])
    diameter = float(np.max(np.linalg.norm(body - body.mean(axis=0), axis=1))) * 2
    clear = np.min(np.linalg.norm(centre[:, None] - flanges[None], axis=2), axis=1) > FIXTURE_CLEARANCE * diameter
    if np.count_nonzero(clear) >= CHOSEN_MARKERS:
        centre, normal, owner, area = centre[clear], normal[clear], owner[clear], area[clear]
    if len(centre) > MAX_CANDIDATES:
        pick = np.sort(np.random.default_rng(0).choice(len(centre), MAX_CANDIDATES, replace=False,
                                                        p=area / area.sum()))
        centre, normal, owner = centre[pick], normal[pick], owner[pick]
    return centre, normal, owner


def _faces(part: MeshPart, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Face centres (F, 3), outward unit normals (F, 3) and areas (F,): a face whose
    winding points into the part is turned (meshes from strangers wind either way)."""
    triangles = vertices[part.faces]
    centre = triangles.mean(axis=1)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    area = np.linalg.norm(cross, axis=1) / 2
    normal = cross / np.maximum(2 * area, 1e-300)[:, None]
    inward = np.einsum("fi,fi->f", normal, centre - vertices.mean(axis=0)) < 0
    normal[inward] *= -1
    return centre, normal, area


def up_directions(count: int = ATTITUDES) -> np.ndarray:
    """(count, 3) unit directions spread evenly over the sphere (a Fibonacci lattice)."""
    index = np.arange(count) + 0.5
    z = 1 - 2 * index / count
    angle = np.pi * (1 + 5**0.5) * index
    radius = np.sqrt(1 - z**2)
    return np.stack([radius * np.cos(angle), radius * np.sin(angle), z], axis=1)


def seen_from_room(normals: np.ndarray, ups: np.ndarray) -> np.ndarray:
    """(N, D) whether a marker whose surface faces ``normals`` (N, 3) is seen by two of a
    ring of cameras above the mock-up (``CAMERA_ELEVATION_RAD``) when the room's up is
    ``ups`` (D, 3) in the body frame."""
    helper = np.where(np.abs(ups[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    east = np.cross(ups, helper)
    east /= np.linalg.norm(east, axis=1, keepdims=True)
    north = np.cross(ups, east)
    azimuth = 2 * np.pi * np.arange(RING_CAMERAS) / RING_CAMERAS
    cameras = (np.cos(CAMERA_ELEVATION_RAD) * (np.cos(azimuth)[None, :, None] * east[:, None]
                                                + np.sin(azimuth)[None, :, None] * north[:, None])
               + np.sin(CAMERA_ELEVATION_RAD) * ups[:, None])  # (D, J, 3)
    facing = np.einsum("ni,dji->ndj", normals, cameras) > np.cos(SEEN_WITHIN_RAD)
    return facing.sum(axis=-1) >= 2


def chosen(target: Target, sight: Sight | None = None) -> Markers:
    """``CHOSEN_MARKERS`` of the ``candidates`` that give the best fit over the whole
    target (module docstring), where they are seen: by ``sight`` (the room's cameras at the
    planned poses), else by a ring of cameras over every attitude (``seen_from_room``).
    Three spread far apart to start, each next the one that most lowers the mean position
    variance at the centre, then each exchanged for a better one."""
    centre, normal, owner = candidates(target)
    point = target.centre_m * target.mockup_scale
    seen = seen_from_room(normal, up_directions()) if sight is None else sight(centre, normal)  # (C, D)
    start = farthest_points(centre, point, 3)
    picked = [int(np.argmin(np.linalg.norm(centre - p, axis=1))) for p in start]

    def score(sets: list[list[int]]) -> np.ndarray:
        index = np.array(sets)
        return mean_point_variance(centre[index], np.swapaxes(seen[index], 1, 2), point, unseen_m2=1e6)

    def free(others: list[int]) -> list[int]:
        """The candidates at least MIN_SEPARATION_M from every one of ``others``."""
        near = np.linalg.norm(centre[:, None] - centre[others][None], axis=2).min(axis=1) < MIN_SEPARATION_M
        return [int(c) for c in np.flatnonzero(~near)]

    while len(picked) < CHOSEN_MARKERS and (options := free(picked)):
        scores = score([[*picked, c] for c in options])
        picked.append(options[int(np.argmin(scores))])
    for slot in range(len(picked)):
        options = free(picked[:slot] + picked[slot + 1:])
        if not options:
            continue
        trials = [picked[:slot] + [c] + picked[slot + 1:] for c in options]
        scores = score(trials)
        if scores.min() < score([picked])[0]:
            picked = trials[int(np.argmin(scores))]
    names = list(target.parts)
    return Markers(centre[picked], normal[picked], True, tuple(names[owner[i]] for i in picked))
