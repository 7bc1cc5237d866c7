"""From rendered radiance to an 8-bit photograph: lens distortion, glare, exposure, shot
and read noise, saturation, gamma.

The renderer draws an ideal pinhole image wider than the camera's (``stages.common.lens``);
lens distortion is applied by remapping it.
"""

from __future__ import annotations

import numpy as np

from core.config import CameraConfig, VirtualConfig
from stages.common import geometry as g
from stages.common.lens import Lens, LensCamera, RenderGeometry
from stages.common.tone import encode8

__all__ = ["RenderGeometry", "Sensor", "lens_camera"]


def lens_camera(camera: CameraConfig) -> LensCamera:
    """The configured (true) camera of the testbed."""
    return LensCamera(camera.camera_matrix(), camera.dist_coeffs(), camera.width_px, camera.height_px)


class Sensor:
    """The camera after the lens: distortion, glare, exposure, noise, 8-bit output."""

    def __init__(self, camera: CameraConfig, virtual: VirtualConfig, geometry: RenderGeometry | None = None) -> None:
        self.camera, self.virtual = camera, virtual
        self.lens = Lens(lens_camera(camera), geometry=geometry)
        self.geometry = self.lens.geometry
        self._pixels: tuple[np.ndarray, np.ndarray] | None = None  # (columns (1, W), rows (H, 1)) float32

    def distort(self, pinhole: np.ndarray) -> np.ndarray:
        """(H_render, W_render) -> (H, W) through the lens model (bilinear sampling)."""
        return self.lens.distort(pinhole)

    def glare(self, lamp_cam: np.ndarray) -> np.ndarray:
        """Veiling glare and streaks (H, W), in full-well units, of a bright lamp at
        ``lamp_cam`` (3,) in the camera frame: a halo when it is in view, a haze that
        fades with its angle from the boresight when it is not."""
        h, w = self.camera.height_px, self.camera.width_px
        strength = self.virtual.glare_strength
        angle = float(np.arccos(np.clip(lamp_cam[2] / np.linalg.norm(lamp_cam), -1, 1)))
        half_fov = self.geometry.fov_x_rad / 2
        haze = strength * 0.02 * np.exp(-max(angle - half_fov, 0.0) / 0.1)
        if lamp_cam[2] <= 0:
            return np.full((h, w), haze, dtype=np.float32)
        # a lamp nearly 90 deg off the axis projects far away: kept finite in float32
        pixel = np.clip(g.project_points(lamp_cam[None], self.camera.camera_matrix(), self.camera.dist_coeffs())[0],
                        -1e6, 1e6)
        if self._pixels is None:
            self._pixels = (np.arange(w, dtype=np.float32)[None], np.arange(h, dtype=np.float32)[:, None])
        du, dv = self._pixels[0] - np.float32(pixel[0]), self._pixels[1] - np.float32(pixel[1])
        radius = np.hypot(du, dv)
        scale = 0.02 * w
        halo = strength / (1.0 + (radius / np.float32(scale)) ** 2)
        # |cos(3 theta)| of the streaks' six spokes from the direction's cosine
        # (cos 3t = 4 cos^3 t - 3 cos t), without an arctan per pixel
        cosine = du / np.maximum(radius, np.float32(1e-6))
        spokes = np.abs(cosine * (4.0 * cosine * cosine - 3.0)) ** 40
        streaks = np.float32(0.5 * strength) * np.exp(-radius / np.float32(0.25 * w)) * spokes
        return (np.float32(haze) + halo + streaks).astype(np.float32)

    def expose(self, radiance: np.ndarray, exposure: float, rng: np.random.Generator,
               glare: np.ndarray | None = None) -> np.ndarray:
        """Radiance (H, W) after the lens -> uint8 image: electrons = radiance * exposure *
        full well, shot noise (Gaussian approximation of Poisson), Gaussian read noise,
        clipping at full well, gamma, 8-bit quantisation."""
        full_well = np.float32(self.virtual.full_well_e)
        signal = np.clip(np.asarray(radiance, np.float32), 0, None) * np.float32(exposure)
        if glare is not None:
            signal = signal + glare
        expected = np.clip(signal, 0, 4.0, dtype=np.float32) * full_well
        # Shot noise as sqrt(n) * z with one standard normal per pixel, so that the noise does
        # not reshuffle when the expected count changes in its last bits (a Poisson sampler
        # consumes a varying amount of randomness); read noise dominates where n is small.
        shot, read = rng.standard_normal((2, *expected.shape), dtype=np.float32)
        electrons = expected + np.sqrt(expected) * shot + np.float32(self.virtual.read_noise_e) * read
        return encode8(electrons / full_well, self.camera.gamma)
