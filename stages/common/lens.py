"""Rendering through a real lens: draw an ideal pinhole image wider than the camera's, then
remap it through OpenCV's 5-coefficient distortion model.

``LensCamera`` is the camera an image is taken with (K, distortion, size: OpenCV
conventions, pixel centres at integer coordinates). ``RenderGeometry`` is the pinhole image
a renderer draws for it: square pixels, the camera's focal length, the principal point in
its centre, large enough that every output pixel, traced back through the inverse of the
distortion model, lands inside it. Both the virtual testbed and the synthetic twins use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stages.common.kept import Kept

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


@dataclass(frozen=True)
class LensCamera:
    """camera_matrix (3, 3) px, dist (5,) OpenCV (k1, k2, p1, p2, k3), image width x height px."""

    camera_matrix: np.ndarray
    dist: np.ndarray
    width: int
    height: int


@dataclass(frozen=True)
class RenderGeometry:
    """Pinhole render: ``width x height`` pixels, focal ``focal_px``, principal point at
    the centre (OpenCV convention: ``((width - 1) / 2, (height - 1) / 2)``)."""

    width: int
    height: int
    focal_px: float

    @property
    def fov_x_rad(self) -> float:
        return 2.0 * float(np.arctan(self.width / 2.0 / self.focal_px))

    def camera_matrix(self) -> np.ndarray:
        return np.array([[self.focal_px, 0, (self.width - 1) / 2], [0, self.focal_px, (self.height - 1) / 2],
                         [0, 0, 1.0]])


def undistort_pixels(pixels: np.ndarray, camera: LensCamera) -> np.ndarray:
    """Normalised pinhole coordinates (N, 2) of distorted pixels (N, 2)."""
    points = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    out = cv2.undistortPointsIter(points, np.asarray(camera.camera_matrix, float),
                                  np.asarray(camera.dist, float), None, None, _UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def render_geometry(camera: LensCamera, margin_px: int = 4) -> RenderGeometry:
    """Smallest centred pinhole render covering every output pixel (plus a margin)."""
    w, h = camera.width, camera.height
    border = np.concatenate([
        np.stack([np.arange(w), np.zeros(w)], 1), np.stack([np.arange(w), np.full(w, h - 1)], 1),
        np.stack([np.zeros(h), np.arange(h)], 1), np.stack([np.full(h, w - 1), np.arange(h)], 1)])
    normalised = undistort_pixels(border, camera)
    focal = float(max(camera.camera_matrix[0][0], camera.camera_matrix[1][1]))
    half_x = np.abs(normalised[:, 0]).max() * focal + margin_px
    half_y = np.abs(normalised[:, 1]).max() * focal + margin_px
    return RenderGeometry(int(2 * np.ceil(half_x) + 1), int(2 * np.ceil(half_y) + 1), focal)


def distortion_maps(camera: LensCamera, geometry: RenderGeometry) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps (H, W) float32: the pinhole-render pixel each output pixel samples."""
    w, h = camera.width, camera.height
    us, vs = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    normalised = undistort_pixels(np.stack([us.ravel(), vs.ravel()], 1), camera)
    k = geometry.camera_matrix()
    map_x = (normalised[:, 0] * k[0, 0] + k[0, 2]).reshape(h, w).astype(np.float32)
    map_y = (normalised[:, 1] * k[1, 1] + k[1, 2]).reshape(h, w).astype(np.float32)
    return map_x, map_y


#: the last few cameras' pixel rays: a session keeps one camera, and tracing 576k pixels
#: back through the distortion costs 0.6 s a call (every truth map and twin asked anew)
_PIXEL_RAYS: Kept[np.ndarray] = Kept(4)
#: their float32 axes (3, H * W), one contiguous row each, for the Earth's single-precision
#: arithmetic (``stages.common.earth``), kept beside them
_PIXEL_DIRECTIONS: Kept[np.ndarray] = Kept(4)


def _camera_key(camera: LensCamera) -> tuple:
    return (camera.width, camera.height, np.asarray(camera.camera_matrix, float).tobytes(),
            np.asarray(camera.dist, float).tobytes())


def pixel_rays(camera: LensCamera) -> np.ndarray:
    """Unit directions (H * W, 3), camera frame, of the rays through every pixel centre
    (row-major), traced back through the distortion model. Cached per camera (K, dist and
    size, bit for bit) and read-only: the same bytes as computing them again."""
    def compute() -> np.ndarray:
        us, vs = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
        normalised = undistort_pixels(np.stack([us.ravel(), vs.ravel()], 1), camera)
        rays = np.concatenate([normalised, np.ones((len(normalised), 1))], 1)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        rays.setflags(write=False)
        return rays

    return _PIXEL_RAYS.get(_camera_key(camera), compute)


def pixel_directions(camera: LensCamera) -> np.ndarray:
    """``pixel_rays`` as float32 axes (3, H * W), one contiguous row each; cached per
    camera and read-only as they are."""
    def compute() -> np.ndarray:
        directions = np.ascontiguousarray(pixel_rays(camera).T, np.float32)
        directions.setflags(write=False)
        return directions

    return _PIXEL_DIRECTIONS.get(_camera_key(camera), compute)


class Lens:
    """Remaps pinhole renders (H_render, W_render[, C]) to the camera's distorted image (H, W[, C])."""

    def __init__(self, camera: LensCamera, margin_px: int = 4, geometry: RenderGeometry | None = None) -> None:
        """``geometry``: the pinhole render to sample (default: ``render_geometry(camera)``); any
        render with the same optical centre that covers the camera's field of view works."""
        self.camera = camera
        self.geometry = geometry or render_geometry(camera, margin_px)
        self.map_x, self.map_y = distortion_maps(camera, self.geometry)
        #: whether a pixel's bilinear sample reaches the film's border row or column, or past it,
        #: where the remap replicates the border (never for ``render_geometry``'s margin)
        self.reaches_border = bool(self.map_x.min() < 1 or self.map_y.min() < 1
                                   or self.map_x.max() > self.geometry.width - 2
                                   or self.map_y.max() > self.geometry.height - 2)

    def distort(self, pinhole: np.ndarray) -> np.ndarray:
        """Bilinear sampling of the pinhole render at every output pixel (float32)."""
        return cv2.remap(np.ascontiguousarray(pinhole, dtype=np.float32), self.map_x, self.map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
