"""A Vicon-like motion-capture system: wall cameras (TRON: 12; a facility: its own), markers, occlusion, noise, ghosts.

A marker counts when at least two cameras see it: inside the camera's field of view and
range, and with the line of sight clear of the robot links (capsules) and of the model
(each of its parts' convex hulls). Each counted marker is triangulated with noise growing as fewer cameras
see it. With a configured probability a rigid body's observation includes one ghost or
mislabelled marker. The pose of a rigid body is the least-squares fit (Kabsch) of its
marker model to the observed markers; with fewer than 3 markers it is not tracked. Like a
real system it reports which markers the fit used and their RMS residual.
All positions here are in the robot world K; reported poses are in the motion-capture
world V.

The system's own calibration errs (``SystemErrors``, unmodelled by calibrate): each
camera's rays are turned by a small residual rotation, so a marker is triangulated where
the turned rays of the cameras that see it meet; a marker on the mock-up's reflective
skin appears shifted towards the surface in oblique views (its mirror image merges with
it); and the wand calibration's scale error scales every position in V.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from core.config import Config
from stages.acquire.virtual.room import room_of
from stages.common import geometry as g
from stages.common import layout
from stages.common.markers import MIN_CAMERAS, Occluders, Sight, Sightlines
from stages.common.target import Target

MIN_MARKERS = 3
#: the planned poses the markers' choice weighs at most (evenly over the plan)
PLANNED_VIEWS = 48


def planned_sight(config: Config, target: Target, plan: list[dict[str, Any]], body: Occluders) -> Sight | None:
    """Which of a mock-up's candidate markers this room's motion capture will see at the
    plan's poses (``stages.common.markers.Sightlines``; the arms' links, which move between
    captures, are left out), for choosing them; None without motion capture or a plan."""
    room = room_of(config)
    if room.mocap_positions_m is None or not plan:
        return None
    rows = [plan[i] for i in sorted(set(np.linspace(0, len(plan) - 1, PLANNED_VIEWS).round().astype(int)))]
    world_from_target = np.stack([
        g.transform_from_qt(row["world_from_targetee_q"], row["world_from_targetee_t"])
        @ g.invert(layout.target_from_targetee(target, row["mount"])) for row in rows])
    v = config.virtual
    lines = Sightlines(room.mocap_positions_m, room.mocap_aims_m, v.vicon_fov_rad, v.vicon_max_range_m,
                       world_from_target)
    return lambda centres, normals: lines.seen(centres, body)


@dataclass(frozen=True)
class SystemErrors:
    """The wand calibration's scale (reported / true), each camera's ray rotation (12, 3)
    rotation vectors (rad), and the centroid shift of markers on reflective skin (m)."""

    scale: float
    camera_rotvecs: np.ndarray
    reflection_bias_m: float

    @property
    def none(self) -> bool:
        return self.scale == 1.0 and not np.any(self.camera_rotvecs) and self.reflection_bias_m == 0.0


@dataclass(frozen=True)
class RigidBodyObservation:
    """``vicon_world_from_rb`` (4, 4) or None when untracked; markers used (their indices in
    the body's marker model) and the fit's RMS residual (m; None when untracked); ghost
    injected."""

    vicon_world_from_rb: np.ndarray | None
    markers: int
    ghost: bool
    used: tuple[int, ...] = ()
    residual_m: float | None = None


def camera_positions(config: Config) -> np.ndarray:
    """(C, 3) the motion-capture cameras in K (``room.room_of``: TRON's 12 on the walls near
    the ceiling, or the facility folder's)."""
    positions = room_of(config).mocap_positions_m
    if positions is None:
        raise ValueError("the configured facility has no motion capture")
    return positions


def camera_aims(config: Config) -> np.ndarray:
    """(C, 3) the point each camera looks at (TRON: the middle of the working volume)."""
    return room_of(config).mocap_aims_m


def _segments_hit_capsules(start: np.ndarray, end: np.ndarray, a: np.ndarray, b: np.ndarray,
                           radius: float) -> np.ndarray:
    """Whether segments start->end (N, 3) come within ``radius`` of capsule axes a->b (L, 3).

    Returns (N,). Closest points between segments by clamped parameters (sampled finely
    enough for these lengths: 64 samples along the sight line)."""
    samples = np.linspace(0.0, 0.97, 64)  # stop short of the marker: its own mount is not an obstacle
    points = start[:, None, :] + samples[None, :, None] * (end - start)[:, None, :]  # (N, S, 3)
    axis = b - a  # (L, 3)
    length_sq = np.maximum(np.einsum("li,li->l", axis, axis), 1e-12)
    t = np.einsum("nsli,li->nsl", points[:, :, None, :] - a[None, None], axis) / length_sq
    t = np.clip(t, 0.0, 1.0)
    closest = a[None, None] + t[..., None] * axis[None, None]
    distance = np.linalg.norm(points[:, :, None, :] - closest, axis=-1)
    return np.any(distance < radius, axis=(1, 2))


def triangulate(cameras: np.ndarray, seen: np.ndarray, markers_world: np.ndarray, errors: SystemErrors,
                normals_world: np.ndarray | None) -> np.ndarray:
    """(M, 3) where the system puts markers (M, 3) seen by ``seen`` (cameras, M): the
    least-squares meeting point of each seeing camera's ray, turned by that camera's
    error, through the marker's apparent centroid. Markers seen by fewer than two cameras
    keep their true position (they are not used)."""
    rotations = g.rotvec_to_matrix(errors.camera_rotvecs)  # (C, 3, 3)
    out = markers_world.copy()
    for m in np.flatnonzero(seen.sum(axis=0) >= MIN_CAMERAS):
        system, rhs = np.zeros((3, 3)), np.zeros(3)
        for c in np.flatnonzero(seen[:, m]):
            apparent = markers_world[m]
            ray = apparent - cameras[c]
            if normals_world is not None and errors.reflection_bias_m:
                view = ray / np.linalg.norm(ray)
                normal = normals_world[m]
                apparent = apparent - errors.reflection_bias_m * (normal - (normal @ view) * view)
            direction = rotations[c] @ (apparent - cameras[c])
            direction /= np.linalg.norm(direction)
            projector = np.eye(3) - np.outer(direction, direction)
            system += projector
            rhs += projector @ cameras[c]
        out[m] = np.linalg.solve(system, rhs)
    return out


def visibility(config: Config, markers_world: np.ndarray, link_segments: np.ndarray,
               world_from_target: np.ndarray, body: Occluders) -> np.ndarray:
    """(cameras, markers) boolean: which camera sees which marker, past the arms' links and
    the mock-up's parts (``stages.common.markers.occluders``)."""
    v = config.virtual
    cams = camera_positions(config)
    aims = camera_aims(config)
    boresight = (aims - cams) / np.linalg.norm(aims - cams, axis=1, keepdims=True)
    to_marker = markers_world[None, :, :] - cams[:, None, :]
    distance = np.linalg.norm(to_marker, axis=-1)
    cos_angle = np.einsum("cmi,ci->cm", to_marker, boresight) / distance
    seen = (cos_angle > np.cos(v.vicon_fov_rad / 2)) & (distance < v.vicon_max_range_m)
    starts = np.repeat(cams, len(markers_world), axis=0)
    ends = np.tile(markers_world, (len(cams), 1))
    blocked = _segments_hit_capsules(starts, ends, link_segments[:, 0], link_segments[:, 1], v.vicon_link_radius_m)
    target_from_world = g.invert(world_from_target)
    ends_body = g.apply(target_from_world, ends)
    starts_body = g.apply(target_from_world, starts)
    # shrink the sight line slightly so a marker on the surface is not hidden by its own face
    ends_body = starts_body + 0.995 * (ends_body - starts_body)
    blocked |= body.hides(starts_body, ends_body)
    return seen & ~blocked.reshape(len(cams), len(markers_world))


def kabsch(model: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """``observed_from_model`` (4, 4) minimising sum |observed - T model|^2 (points (N, 3))."""
    model_centre, observed_centre = model.mean(axis=0), observed.mean(axis=0)
    covariance = (observed - observed_centre).T @ (model - model_centre)
    rotation = g.project_to_so3(covariance)
    return g.make_transform(rotation, observed_centre - rotation @ model_centre)


def observe(config: Config, rng: np.random.Generator, markers_rb: np.ndarray, world_from_rb: np.ndarray,
            vicon_world_from_world: np.ndarray, link_segments: np.ndarray,
            world_from_target: np.ndarray, body: Occluders, noise_factor: float = 1.0,
            errors: SystemErrors | None = None, normals_world: np.ndarray | None = None) -> RigidBodyObservation:
    """Track one rigid body: markers_rb (M, 3) in its frame, true ``world_from_rb``; the
    mock-up's parts (``body``) at ``world_from_target`` hide markers;
    ``noise_factor`` scales the marker noise (markers on reflective surfaces); ``errors``
    of the system's calibration, and the markers' surface normals (M, 3) in K when they sit
    on reflective skin."""
    v = config.virtual
    markers_world = g.apply(world_from_rb, markers_rb)
    seen = visibility(config, markers_world, link_segments, world_from_target, body)
    cameras_seeing = seen.sum(axis=0)
    counted = cameras_seeing >= MIN_CAMERAS
    sigma = noise_factor * room_of(config).marker_sigma_m * np.sqrt(MIN_CAMERAS / np.maximum(cameras_seeing, 1))
    if errors is not None and not errors.none:
        markers_world = triangulate(camera_positions(config), seen, markers_world, errors, normals_world)
    noisy = markers_world + rng.normal(size=markers_world.shape) * sigma[:, None]
    ghost = bool(rng.uniform() < v.vicon_ghost_rate)
    visible = np.flatnonzero(counted)
    if len(visible) < MIN_MARKERS:
        return RigidBodyObservation(None, int(len(visible)), False)
    if ghost:
        victim = rng.choice(visible)
        direction = rng.normal(size=3)
        noisy[victim] += rng.uniform(*v.vicon_ghost_offset_m) * direction / np.linalg.norm(direction)
    reported = g.apply(vicon_world_from_world, noisy[visible])
    if errors is not None:
        reported = errors.scale * reported  # scaled about V's origin
    vicon_world_from_rb = kabsch(markers_rb[visible], reported)
    residual = reported - g.apply(vicon_world_from_rb, markers_rb[visible])
    return RigidBodyObservation(vicon_world_from_rb, int(len(visible)), ghost, tuple(int(i) for i in visible),
                                float(np.sqrt(np.mean(np.sum(residual**2, axis=1)))))
