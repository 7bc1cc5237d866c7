"""A render worker: turns a ``RenderJob`` into an 8-bit PNG, a mask PNG, the per-pixel
ground truth (``stages.common.ground_truth``) and a ``renders`` row. One per process
(local engine) or Ray actor; the scene loads once. It never touches the workspace: the
files go back to the driver with the row (``core.engines.Produced``).

The mask and the ground truth are ray-cast at the output pixel centres through the lens
(``stages.common.surface``) in the render's own scene: exact per pixel, where remapping a
rendered AOV image would blend ids and coordinates across edges; only in the window where
the target can be (``stages.common.windows``), where the render draws.

The image is what the camera would make of the radiance (``stages.common.tone``): grey for a
mono camera (SPEED+'s), colour for a colour one, through the camera's gamma; the exposure
is fixed (``EXPOSURE``) so that an image's brightness follows its light, as in SPEED+'s
synthetic images.
"""

from __future__ import annotations

import time

import numpy as np

from core.engines import Produced
from stages.common import geometry as g
from stages.common import ground_truth
from stages.common.earth import earth_background, earth_image
from stages.common.image_io import encode_png
from stages.common.lens import LensCamera
from stages.common.surface import TargetSurfaces
from stages.common.target import Target
from stages.common.tone import Response
from stages.common.windows import Window
from stages.render.jobs import RenderJob
from stages.render.scene import TargetRenderer

EXPOSURE = 1.0
#: SPEED+'s camera, the default
MONO_LINEAR = Response("mono", 1.0)


def mask_bbox(mask: np.ndarray) -> np.ndarray:
    """x_min, y_min, x_max, y_max (4,) of the mask's pixel centres; NaN when empty."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return np.full(4, np.nan)
    return np.array([xs.min(), ys.min(), xs.max(), ys.max()], float)


class RenderWorker:
    """Renders jobs of one camera, as that camera's ``response`` would see them."""

    def __init__(self, camera: LensCamera, target: Target, spp: int, max_depth: int, threads: int,
                 with_ground_truth: bool = True, response: Response = MONO_LINEAR) -> None:
        self.camera, self.spp, self.keypoints_m, self.response = camera, spp, target.keypoints_m, response
        self.renderer = TargetRenderer(camera, target, spp=spp, max_depth=max_depth, threads=threads)
        self.surfaces = TargetSurfaces(target.parts, self.renderer.scene)
        self.with_ground_truth = with_ground_truth

    def radiance(self, job: RenderJob) -> tuple[np.ndarray, bool]:
        """Linear radiance (H, W, 3) of a job: the render, over the Earth when it has one; and
        whether the Earth is in the image."""
        light = np.asarray(job.light_dir_cam, float)
        rgba = self.renderer.render(job.cam_from_target(), light, job.irradiance, job.seed)
        rgb, alpha = rgba[..., :3], np.clip(rgba[..., 3:], 0.0, 1.0)
        if not job.earth:
            return rgb, False
        if job.earth_centre_cam_m is not None:
            background, seen = earth_image(self.camera, np.asarray(job.earth_centre_cam_m),
                                           np.reshape(job.cam_from_planet, (3, 3)), np.asarray(job.sun_dir_cam),
                                           job.irradiance)
        else:
            background, seen = earth_background(self.camera, light, job.irradiance,
                                                np.random.default_rng(job.seed)), True
        # the render's rgb is premultiplied by coverage; outside the window it and the coverage
        # are zero, and the image is the Earth's (a fresh frame: composited in place)
        window = self.renderer.image_window(job.cam_from_target())
        if window is None:
            return rgb + (1.0 - alpha) * background, seen
        rows, columns = window.slices()
        background[rows, columns] = rgb[rows, columns] + (1.0 - alpha[rows, columns]) * background[rows, columns]
        return background, seen

    def tone(self, radiance: np.ndarray, window: Window | None) -> np.ndarray:
        """The 8-bit image of the radiance (H, W, 3), toned in ``window`` only where it is
        given: outside it the radiance is exactly zero (black space, no Earth), and so is
        its code: the same bytes as toning every pixel."""
        if window is None:
            return self.response.image(radiance, EXPOSURE)
        shape = radiance.shape[:2] if self.response.channels == 1 else radiance.shape
        pixels = np.zeros(shape, np.uint8)
        if not window.empty:
            pixels[window.slices()] = self.response.image(radiance[window.slices()], EXPOSURE)
        return pixels

    def render(self, job: RenderJob) -> Produced:
        """Render; the job's ``renders`` row with its PNGs and ground truth, or, when the
        target covers no pixel centre, ``{"sample_id", "rejected": reason}`` and no files."""
        started = time.perf_counter()
        radiance, earth = self.radiance(job)
        # the ray cast where the target can be, the window the render drew (stages.common.windows)
        window = self.renderer.image_window(job.cam_from_target())
        if window is None:
            maps = self.surfaces.through_lens(job.cam_from_target(), self.camera)
            mask, bbox = maps.mask, mask_bbox(maps.mask)
        else:  # kept as the window's maps: the ground truth is written from them
            maps = self.surfaces.in_window(job.cam_from_target(), self.camera, window)
            mask = maps.mask
            bbox = (np.full(4, np.nan) if maps.inside is None
                    else mask_bbox(maps.inside.mask) + np.array([maps.window.x, maps.window.y] * 2, float))
        if np.isnan(bbox[0]):
            return Produced({"sample_id": job.sample_id, "rejected": "the target covers no pixel of the image"})
        pixels = self.tone(radiance, None if earth else window)
        files = {job.image_path: encode_png(np.ascontiguousarray(pixels if pixels.ndim == 2 else pixels[..., ::-1])),
                 job.mask_path: encode_png(mask.astype(np.uint8) * 255)}
        ground_truth_path = None
        if self.with_ground_truth:
            ground_truth_path = job.ground_truth_path
            channels = ground_truth.channels_of(maps, radiance, ground_truth.RADIANCE + ground_truth.GEOMETRY,
                                                black_outside=not earth)
            files[ground_truth_path] = ground_truth.encode(channels, self.camera, job.cam_from_target(), maps.ids)
        keypoints = g.project(job.cam_from_target(), self.keypoints_m, self.camera.camera_matrix, self.camera.dist)
        return Produced({
            "sample_id": job.sample_id, "set": job.set, "image_path": job.image_path, "mask_path": job.mask_path,
            "ground_truth_path": ground_truth_path,
            "q_vbs2tango_true": list(job.q_vbs2tango_true), "r_Vo2To_vbs_true": list(job.r_Vo2To_vbs_true),
            "light_dir_cam": list(job.light_dir_cam), "irradiance": job.irradiance, "earth": earth,
            "keypoints_px": keypoints, "bbox_px": bbox,
            "width": self.camera.width, "height": self.camera.height,
            "seed": job.seed, "spp": self.spp, "seconds": time.perf_counter() - started,
        }, files)


def open_worker(camera: LensCamera, target: Target, spp: int, max_depth: int, threads: int,
                with_ground_truth: bool = True, response: Response = MONO_LINEAR) -> RenderWorker:
    """Picklable factory for the engines (the target travels whole: a cluster's workers
    may not see the workspace's files)."""
    return RenderWorker(camera, target, spp, max_depth, threads, with_ground_truth, response)
