"""A render worker: turns a ``RenderJob`` into an 8-bit RGB PNG, a mask PNG and a
``renders`` row. One per process (local engine) or Ray actor; the scene loads once.

Tone mapping is fixed (linear radiance x ``EXPOSURE``, sRGB curve, 8 bits) so that an
image's brightness follows its light, as in SPEED+'s synthetic images.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from manifests import Workspace
from stages.common import geometry as g
from stages.common import tango
from stages.common.image_io import write_png_atomic
from stages.common.lens import LensCamera
from stages.render.earth import earth_background
from stages.render.jobs import RenderJob
from stages.render.scene import TangoRenderer

EXPOSURE = 1.0


def to_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear RGB (..., 3) in [0, 1] -> 8-bit sRGB."""
    x = np.clip(linear, 0.0, 1.0)
    encoded = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(encoded * 255.0).astype(np.uint8)


def mask_bbox(mask: np.ndarray) -> np.ndarray:
    """x_min, y_min, x_max, y_max (4,) of the mask's pixel centres; NaN when empty."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return np.full(4, np.nan)
    return np.array([xs.min(), ys.min(), xs.max(), ys.max()], float)


class RenderWorker:
    """Renders jobs of one camera into the workspace at ``root``."""

    def __init__(self, camera: LensCamera, root: str, spp: int, max_depth: int, threads: int) -> None:
        self.camera, self.workspace, self.spp = camera, Workspace(root), spp
        self.renderer = TangoRenderer(camera, spp=spp, max_depth=max_depth, threads=threads)

    def image(self, job: RenderJob) -> tuple[np.ndarray, np.ndarray]:
        """The 8-bit BGR image (H, W, 3) and mask (H, W) of a job, without writing them."""
        light = np.asarray(job.light_dir_cam, float)
        rgba = self.renderer.render(job.cam_from_target(), light, job.irradiance, job.seed)
        rgb, alpha = rgba[..., :3], np.clip(rgba[..., 3:], 0.0, 1.0)
        if job.earth:
            background = earth_background(self.camera, light, job.irradiance, np.random.default_rng(job.seed))
            rgb = rgb + (1.0 - alpha) * background  # the render's rgb is premultiplied by coverage
        image = to_srgb8(rgb * EXPOSURE)[..., ::-1]
        mask = alpha[..., 0] >= 0.5
        return np.ascontiguousarray(image), mask

    def render(self, job: RenderJob) -> dict[str, Any]:
        """Render, write both PNGs atomically, and return the job's ``renders`` row; or, when
        the target covers no pixel, ``{"sample_id", "rejected": reason}`` and no files."""
        started = time.perf_counter()
        image, mask = self.image(job)
        if not mask.any():
            return {"sample_id": job.sample_id, "rejected": "the target covers no pixel of the image"}
        write_png_atomic(self.workspace.resolve(job.image_path), image)
        write_png_atomic(self.workspace.resolve(job.mask_path), mask.astype(np.uint8) * 255)
        keypoints = g.project(job.cam_from_target(), tango.KEYPOINTS_M, self.camera.camera_matrix, self.camera.dist)
        return {
            "sample_id": job.sample_id, "set": job.set, "image_path": job.image_path, "mask_path": job.mask_path,
            "q_vbs2tango_true": list(job.q_vbs2tango_true), "r_Vo2To_vbs_true": list(job.r_Vo2To_vbs_true),
            "light_dir_cam": list(job.light_dir_cam), "irradiance": job.irradiance, "earth": job.earth,
            "keypoints_px": keypoints, "bbox_px": mask_bbox(mask),
            "width": self.camera.width, "height": self.camera.height,
            "seed": job.seed, "spp": self.spp, "seconds": time.perf_counter() - started,
        }


def open_worker(camera: LensCamera, root: str, spp: int, max_depth: int, threads: int) -> RenderWorker:
    """Picklable factory for the engines."""
    return RenderWorker(camera, root, spp, max_depth, threads)
