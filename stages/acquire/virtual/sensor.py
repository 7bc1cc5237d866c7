"""From rendered radiance to an 8-bit photograph: lens distortion, glare, exposure, shot
and read noise, saturation, gamma.

The renderer draws an ideal pinhole image, wider than the camera's, with square pixels
and the principal point in its centre (``RenderGeometry``). Lens distortion is applied
by remapping: every output pixel is traced back through the inverse of OpenCV's
5-coefficient model to the pinhole image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.config import CameraConfig, VirtualConfig
from stages import geometry as g

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


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


def undistort_pixels(pixels: np.ndarray, camera: CameraConfig) -> np.ndarray:
    """Normalised pinhole coordinates (N, 2) of distorted pixels (N, 2)."""
    points = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    out = cv2.undistortPointsIter(points, camera.camera_matrix(), camera.dist_coeffs(), None, None,
                                  _UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def render_geometry(camera: CameraConfig, margin_px: int = 4) -> RenderGeometry:
    """Smallest centred pinhole render covering every output pixel (plus a margin)."""
    w, h = camera.width_px, camera.height_px
    border = np.concatenate([
        np.stack([np.arange(w), np.zeros(w)], 1), np.stack([np.arange(w), np.full(w, h - 1)], 1),
        np.stack([np.zeros(h), np.arange(h)], 1), np.stack([np.full(h, w - 1), np.arange(h)], 1)])
    normalised = undistort_pixels(border, camera)
    focal = float(camera.camera_matrix()[0, 0])
    half_x = np.abs(normalised[:, 0]).max() * focal + margin_px
    half_y = np.abs(normalised[:, 1]).max() * focal + margin_px
    return RenderGeometry(int(2 * np.ceil(half_x) + 1), int(2 * np.ceil(half_y) + 1), focal)


def distortion_maps(camera: CameraConfig, geometry: RenderGeometry) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps (H, W) float32: the pinhole-render pixel each output pixel samples."""
    w, h = camera.width_px, camera.height_px
    us, vs = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    normalised = undistort_pixels(np.stack([us.ravel(), vs.ravel()], 1), camera)
    k = geometry.camera_matrix()
    map_x = (normalised[:, 0] * k[0, 0] + k[0, 2]).reshape(h, w).astype(np.float32)
    map_y = (normalised[:, 1] * k[1, 1] + k[1, 2]).reshape(h, w).astype(np.float32)
    return map_x, map_y


class Sensor:
    """The camera after the lens: distortion, glare, exposure, noise, 8-bit output."""

    def __init__(self, camera: CameraConfig, virtual: VirtualConfig) -> None:
        self.camera, self.virtual = camera, virtual
        self.geometry = render_geometry(camera)
        self.map_x, self.map_y = distortion_maps(camera, self.geometry)

    def distort(self, pinhole: np.ndarray) -> np.ndarray:
        """(H_render, W_render) -> (H, W) through the lens model (bilinear sampling)."""
        return cv2.remap(pinhole.astype(np.float32), self.map_x, self.map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    def glare(self, lamp_cam: np.ndarray) -> np.ndarray:
        """Veiling glare and streaks (H, W), in full-well units, of a bright lamp at
        ``lamp_cam`` (3,) in the camera frame: a halo when it is in view, a haze that
        fades with its angle from the boresight when it is not."""
        h, w = self.camera.height_px, self.camera.width_px
        strength = self.virtual.glare_strength
        angle = float(np.arccos(np.clip(lamp_cam[2] / np.linalg.norm(lamp_cam), -1, 1)))
        half_fov = self.geometry.fov_x_rad / 2
        haze = strength * 0.02 * np.exp(-max(angle - half_fov, 0.0) / 0.1)
        image = np.full((h, w), haze, dtype=np.float64)
        if lamp_cam[2] <= 0:
            return image
        pixel = g.project_points(lamp_cam[None], self.camera.camera_matrix(), self.camera.dist_coeffs())[0]
        vs, us = np.mgrid[0:h, 0:w]
        du, dv = us - pixel[0], vs - pixel[1]
        radius = np.hypot(du, dv)
        scale = 0.02 * w
        halo = strength / (1.0 + (radius / scale) ** 2)
        theta = np.arctan2(dv, du)
        streaks = 0.5 * strength * np.exp(-radius / (0.25 * w)) * np.abs(np.cos(3 * theta)) ** 40
        return image + halo + streaks

    def expose(self, radiance: np.ndarray, exposure: float, rng: np.random.Generator,
               glare: np.ndarray | None = None) -> np.ndarray:
        """Radiance (H, W) after the lens -> uint8 image: electrons = radiance * exposure *
        full well, shot noise (Gaussian approximation of Poisson), Gaussian read noise,
        clipping at full well, gamma, 8-bit quantisation."""
        full_well = self.virtual.full_well_e
        signal = np.clip(radiance, 0, None) * exposure
        if glare is not None:
            signal = signal + glare
        expected = np.clip(signal, 0, 4.0) * full_well
        # Shot noise as sqrt(n) * z with one standard normal per pixel, so that the noise does
        # not reshuffle when the expected count changes in its last bits (a Poisson sampler
        # consumes a varying amount of randomness); read noise dominates where n is small.
        shot, read = rng.standard_normal((2, *expected.shape))
        electrons = expected + np.sqrt(expected) * shot + self.virtual.read_noise_e * read
        linear = np.clip(electrons / full_well, 0.0, 1.0)
        encoded = np.power(linear, 1.0 / self.virtual.gamma)
        return np.round(encoded * 255.0).astype(np.uint8)
