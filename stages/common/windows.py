"""Where the target can be in an image, so that a render and a ray cast spend their work
there only (issue 60; docs/architecture.md section 7): the window of the pinhole film that
holds the target's projected vertices, and the window of the camera's (distorted) image
whose pixels sample that film window through the lens's remap.

Outside these windows the target covers nothing: a twin there is black space (or the Earth,
composited after), its mask false and its ground truth empty, exactly as a full render's
and a full ray cast's. Inside, the pixels are the full render's but for their Monte-Carlo
noise (another sample sequence), which ``tests/stages/common/test_windows.py`` measures.

Windows are (x, y, width, height) in pixels, x to the right, y down; a window of zero area
means the target is nowhere in the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stages.common import geometry as g
from stages.common.lens import Lens, RenderGeometry

#: pixels added round the projected vertices in the film: the box filter's half pixel, the
#: remap's bilinear neighbour, and one to spare
FILM_MARGIN_PX = 3
#: nearer than this (m) a vertex's projection is not trusted: the whole image is used
NEAR_M = 1e-3


@dataclass(frozen=True)
class Window:
    """A rectangle of pixels: columns ``x .. x + width``, rows ``y .. y + height``."""

    x: int
    y: int
    width: int
    height: int

    @property
    def empty(self) -> bool:
        return self.width <= 0 or self.height <= 0

    def slices(self) -> tuple[slice, slice]:
        """(rows, columns) to index an (H, W, ...) array with."""
        return slice(self.y, self.y + self.height), slice(self.x, self.x + self.width)


def film_window(geometry: RenderGeometry, cam_from_target: np.ndarray, points_m: np.ndarray,
                margin_px: int = FILM_MARGIN_PX) -> Window | None:
    """The window of the pinhole film (``geometry``) holding ``points_m`` (N, 3, target frame,
    m) seen through ``cam_from_target`` (4, 4), with ``margin_px`` round them; None when a
    point is at or behind the camera (the whole film is then rendered)."""
    camera_points = g.apply(np.asarray(cam_from_target, float), np.asarray(points_m, float))
    if np.any(camera_points[:, 2] <= NEAR_M):
        return None
    centre = (np.array([geometry.width, geometry.height]) - 1) / 2
    pixels = geometry.focal_px * camera_points[:, :2] / camera_points[:, 2:] + centre
    low = np.floor(pixels.min(axis=0)).astype(int) - margin_px
    high = np.ceil(pixels.max(axis=0)).astype(int) + margin_px + 1
    low = np.clip(low, 0, [geometry.width, geometry.height])
    high = np.clip(high, 0, [geometry.width, geometry.height])
    return Window(int(low[0]), int(low[1]), int(high[0] - low[0]), int(high[1] - low[1]))


def image_window(lens: Lens, film: Window | None) -> Window | None:
    """The window of the camera's image whose pixels sample ``film`` through the lens's remap
    (bilinear: a pixel reads the film pixels round its sample point); None: the whole image."""
    if film is None:
        return None
    if film.empty:
        return Window(0, 0, 0, 0)
    inside = ((lens.map_x >= film.x - 1) & (lens.map_x <= film.x + film.width)
              & (lens.map_y >= film.y - 1) & (lens.map_y <= film.y + film.height))
    rows, columns = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
    if len(rows) == 0:
        return Window(0, 0, 0, 0)
    return Window(int(columns[0]), int(rows[0]), int(columns[-1] - columns[0] + 1), int(rows[-1] - rows[0] + 1))


def replicates_border(lens: Lens, film: Window) -> bool:
    """Whether the lens's remap of a render drawn in ``film`` carries the film's border
    beyond ``image_window``: ``film`` reaches an edge of the film, and some pixel samples
    that edge or past it, where the remap replicates the border."""
    geometry = lens.geometry
    return lens.reaches_border and not film.empty and (
        film.x <= 0 or film.y <= 0 or film.x + film.width >= geometry.width
        or film.y + film.height >= geometry.height)


def distorted(lens: Lens, pinhole: np.ndarray, film: Window, image: Window) -> np.ndarray:
    """``lens.distort(pinhole)`` (H, W, C) float32 of a pinhole render (H_film, W_film, C)
    that is zero outside ``film``, whose image window is ``image`` (``image_window``): remapped
    in ``image`` only and zero elsewhere, the same values, since a pixel outside ``image``
    samples no pixel of ``film``. Where the remap's replicated border carries ``film``
    beyond that (``replicates_border``), the whole image is remapped."""
    if replicates_border(lens, film):
        return lens.distort(pinhole)
    camera = lens.camera
    image_pixels = np.zeros((camera.height, camera.width, *pinhole.shape[2:]), np.float32)
    if not image.empty:
        rows, columns = image.slices()
        image_pixels[rows, columns] = cv2.remap(
            np.ascontiguousarray(pinhole, dtype=np.float32), np.ascontiguousarray(lens.map_x[rows, columns]),
            np.ascontiguousarray(lens.map_y[rows, columns]), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return image_pixels
