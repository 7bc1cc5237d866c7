"""Per-pixel geometry of the target's mesh by ray casting: which part each pixel centre
sees, at what depth, with which surface normal and at which point of the body.

One ray per output pixel centre, cast through the camera's own model (a pinhole ``K`` for
undistorted images, or the lens's distortion for the 8-bit renders and captures), so the
maps are exact at every pixel: no film, filter, sampling noise or resampling is involved,
and ids and coordinates are never interpolated across an edge. Used by render (the EXR
ground truth of every synthetic image), acquire (depth and masks at the true pose) and
export (BOP masks at the label's pose).

Conventions (docs/architecture.md section 3): ``cam_from_target`` (4, 4) maps body
coordinates (T, full scale, metres) into the OpenCV camera frame (x right, y down, z along
the boresight); depth is z in that frame, not the distance along the ray.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from stages.common import geometry as g
from stages.common.lens import LensCamera, pixel_rays
from stages.common.mitsuba_adapter import bsdf, load_mitsuba, load_scene, mesh, surface_hits
from stages.common.target import MeshPart
from stages.common.windows import Window

BACKGROUND = "background"


def part_ids(parts: dict[str, MeshPart]) -> dict[str, int]:
    """Each pixel's part index (uint8): 0 the background, then 1, 2, ... the target's parts
    in the mesh's order (``speedplus target DIR`` lists them); the EXR header records it."""
    return {BACKGROUND: 0, **{name: index + 1 for index, name in enumerate(parts)}}


def shape_id(index: int) -> str:
    """The Mitsuba shape id of the target's ``index``-th part, in every scene that holds it."""
    return f"target_part_{index + 1}"


@dataclass(frozen=True)
class SurfaceMaps:
    """What each pixel centre sees; every array (H, W[, 3]) float32, NaN where ``part`` is 0.

    depth_m: z of the hit in the camera frame (m). normal_cam: unit geometric normal in the
    camera frame, turned towards the camera. body_m: the hit in body coordinates (m).
    part: ``PART_IDS`` index (uint8).
    """

    depth_m: np.ndarray
    normal_cam: np.ndarray
    body_m: np.ndarray
    part: np.ndarray
    ids: dict[str, int]

    @property
    def mask(self) -> np.ndarray:
        return self.part > 0


@dataclass(frozen=True)
class WindowedMaps:
    """The maps of an image of ``height`` x ``width`` cast in ``window`` only: ``inside``
    (the window's ``SurfaceMaps``; None for an empty window); outside it the target covers
    nothing (NaN, part 0). What the writers of ground truth take (``stages.common.exr``'s
    ``Windowed`` planes), so that no frame-sized array of NaN is made or scanned."""

    inside: SurfaceMaps | None
    window: Window
    height: int
    width: int
    ids: dict[str, int]

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: where the target covers a pixel centre."""
        out = np.zeros((self.height, self.width), bool)
        if self.inside is not None:
            out[self.window.slices()] = self.inside.mask
        return out

    def whole(self) -> SurfaceMaps:
        """The maps of the whole image (H, W[, 3])."""
        shape = (self.height, self.width)
        full = SurfaceMaps(np.full(shape, np.nan, np.float32), np.full((*shape, 3), np.nan, np.float32),
                           np.full((*shape, 3), np.nan, np.float32), np.zeros(shape, np.uint8), self.ids)
        if self.inside is not None:
            rows, columns = self.window.slices()
            for name in ("depth_m", "normal_cam", "body_m", "part"):
                getattr(full, name)[rows, columns] = getattr(self.inside, name)
        return full


def pinhole_rays(camera_matrix: np.ndarray, width: int, height: int) -> np.ndarray:
    """Unit directions (H * W, 3), camera frame, through every pixel centre of an
    undistorted image with intrinsics ``camera_matrix`` (3, 3), row-major."""
    us, vs = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    pixels = np.stack([us.ravel(), vs.ravel(), np.ones(us.size)], 1)
    directions = pixels @ np.linalg.inv(np.asarray(camera_matrix, float)).T
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


class TargetSurfaces:
    """Ray casts against the target's triangles (``parts``, full scale, body frame): those of
    a scene that already holds them as shapes ``shape_id(index)`` (a renderer's), else of
    a geometry-only scene of their own."""

    def __init__(self, parts: dict[str, MeshPart], scene: Any = None) -> None:
        self.mi = mi = load_mitsuba()
        if scene is None:
            grey = bsdf(mi, {"type": "diffuse"})
            objects: dict[str, Any] = {"type": "scene"}
            for index, part in enumerate(parts.values()):
                objects[shape_id(index)] = mesh(mi, shape_id(index), part.vertices, part.faces, part.uv, grey)
            scene = load_scene(mi, objects)
        self.scene = scene
        self.ids = part_ids(parts)
        self._index = {shape_id(index): index + 1 for index in range(len(parts))}

    def cast(self, cam_from_target: np.ndarray, directions_cam: np.ndarray, shape: tuple[int, int]) -> SurfaceMaps:
        """Maps of ``shape`` (H, W) from unit ray directions (H * W, 3) in the camera frame."""
        target_from_cam = g.invert(np.asarray(cam_from_target, float))
        directions = directions_cam @ target_from_cam[:3, :3].T
        part, body, normal = surface_hits(self.mi, self.scene, target_from_cam[:3, 3], directions, self._index)
        valid = part > 0  # another shape of the scene (none in the renderers') is not the model
        # the frames' arithmetic on the rays that hit only (a window is mostly black space)
        hit_body, hit_normal = body[valid], normal[valid]
        camera_points = g.apply(cam_from_target, hit_body)
        normal_cam = hit_normal @ np.asarray(cam_from_target, float)[:3, :3].T
        normal_cam *= np.where(np.sum(normal_cam * directions_cam[valid], axis=1, keepdims=True) > 0, -1.0, 1.0)
        height, width = shape
        depth = np.full(height * width, np.nan, np.float32)
        normals, points = np.full((height * width, 3), np.nan, np.float32), np.full((height * width, 3), np.nan,
                                                                                    np.float32)
        depth[valid], normals[valid], points[valid] = camera_points[:, 2], normal_cam, hit_body
        return SurfaceMaps(depth.reshape(height, width), normals.reshape(height, width, 3),
                           points.reshape(height, width, 3), part.reshape(height, width), self.ids)

    def pinhole(self, cam_from_target: np.ndarray, camera_matrix: np.ndarray, width: int, height: int) -> SurfaceMaps:
        """Maps of an undistorted ``width x height`` image with intrinsics ``camera_matrix``."""
        return self.cast(cam_from_target, pinhole_rays(camera_matrix, width, height), (height, width))

    def through_lens(self, cam_from_target: np.ndarray, camera: LensCamera,
                     window: Window | None = None) -> SurfaceMaps:
        """Maps of the camera's distorted image (the pixels of its renders and captures), cast
        in ``window`` only (``stages.common.windows``: where the target can be; the rest sees
        nothing), or at every pixel."""
        if window is None:
            return self.cast(cam_from_target, pixel_rays(camera), (camera.height, camera.width))
        return self.in_window(cam_from_target, camera, window).whole()

    def in_window(self, cam_from_target: np.ndarray, camera: LensCamera, window: Window) -> WindowedMaps:
        """``through_lens`` cast in ``window`` and kept as that window's maps."""
        inside = None
        if not window.empty:
            rows, columns = window.slices()
            rays = pixel_rays(camera).reshape(camera.height, camera.width, 3)[rows, columns].reshape(-1, 3)
            inside = self.cast(cam_from_target, rays, (window.height, window.width))
        return WindowedMaps(inside, window, camera.height, camera.width, self.ids)
