"""Cameras the stages derive from the configuration."""

from __future__ import annotations

from core.config import Config, resize_camera_matrix
from stages.common.lens import LensCamera


def train_camera(config: Config) -> LensCamera:
    """The SPEED+ camera of the profile, resized by ``render.train_resolution_scale``."""
    camera, factor = config.camera, config.render.train_resolution_scale
    width, height = round(camera.width_px * factor), round(camera.height_px * factor)
    k = resize_camera_matrix(camera.camera_matrix(), width / camera.width_px, height / camera.height_px)
    return LensCamera(k, camera.dist_coeffs(), width, height)
