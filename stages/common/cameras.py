"""Cameras the stages derive from the configuration."""

from __future__ import annotations

from pipeline.config import Config
from stages.common.lens import LensCamera


def train_camera(config: Config) -> LensCamera:
    """The SPEED+ camera of the profile, resized by ``render.train_resolution_scale``."""
    camera, factor = config.camera, config.render.train_resolution_scale
    k = camera.camera_matrix().copy()
    width, height = round(camera.width_px * factor), round(camera.height_px * factor)
    k[0, :] *= width / camera.width_px
    k[1, :] *= height / camera.height_px
    # pixel centres at integer coordinates: rescale about the image corner (-0.5, -0.5)
    k[0, 2] = (camera.camera_matrix()[0, 2] + 0.5) * width / camera.width_px - 0.5
    k[1, 2] = (camera.camera_matrix()[1, 2] + 0.5) * height / camera.height_px - 0.5
    return LensCamera(k, camera.dist_coeffs(), width, height)
