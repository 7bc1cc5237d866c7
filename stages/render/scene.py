"""The synthetic target in Mitsuba 3: its mesh at full scale with the flight model's looks
(``stages.common.looks``: for Tango smooth gold MLI, solar cells, white radiator, metal
antennas), black space, one directional light.

The model stays in its body frame T; each image moves the camera (``target_from_cam``)
and turns the light through the scene's parameters (``mitsuba_adapter.LoadedScene``), so
the acceleration structure is built once.
The render is an RGBA pinhole image wider than the camera's; ``stages.common.lens`` remaps it
through the label camera's distortion.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stages.common import geometry as g
from stages.common.lens import Lens, LensCamera, pixel_rays
from stages.common.looks import synthetic_look
from stages.common.mitsuba_adapter import (
    LoadedScene,
    bsdf,
    first_hit_on,
    load_mitsuba,
    mesh,
    rays,
    sensor,
    set_threads,
)
from stages.common.surface import shape_id
from stages.common.target import Target
from stages.common.windows import Window, distorted, film_window, image_window, replicates_border


class TargetRenderer:
    """A loaded scene of the synthetic target for one camera; ``render`` returns (H, W, 4)
    linear RGBA float32 in the camera's (distorted) image, alpha = coverage of the model."""

    def __init__(self, camera: LensCamera, target: Target, *, spp: int, max_depth: int, threads: int) -> None:
        self.mi = mi = load_mitsuba()
        # the same thread count in every engine: part of what makes the pixels reproducible
        set_threads(threads)
        self.lens = Lens(camera)
        self.spp = spp
        geometry = self.lens.geometry
        # box filter: alpha is exact coverage
        self.sensor_spec = sensor(mi, geometry, far_clip_m=1000.0, pixel_format="rgba")
        #: every vertex (N, 3, body frame, m): where the target can be in an image
        self.points_m = target.vertices_m
        objects: dict[str, Any] = {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": max_depth, "hide_emitters": True},
            "sensor": self.sensor_spec,
            "sun": {"type": "directional", "direction": [0.0, 0.0, -1.0],
                    "irradiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        }
        for index, (name, part) in enumerate(target.parts.items()):  # the part ids' order (stages.common.surface)
            objects[shape_id(index)] = mesh(mi, shape_id(index), part.vertices, part.faces, part.uv,
                                            bsdf(mi, synthetic_look(target.looks.get(name), part.colour)))
        self.loaded = LoadedScene(mi, objects)
        self.scene = self.loaded.scene
        self._image_window: tuple[Window | None, Window | None] | None = None

    def film_window(self, cam_from_target: np.ndarray) -> Window | None:
        """The pinhole film's window that holds the target at this pose
        (``windows.film_window``); None: all of the film (a vertex at or behind the camera)."""
        return film_window(self.lens.geometry, cam_from_target, self.points_m)

    def image_window(self, cam_from_target: np.ndarray) -> Window | None:
        """The window of the camera's image whose pixels sample ``film_window`` (where the
        target can be in the image), kept for the last film window asked; None: all of the
        image, also where the remap's replicated border carries the film window beyond it
        (``windows.replicates_border``)."""
        film = self.film_window(cam_from_target)
        if self._image_window is None or self._image_window[0] != film:
            whole = film is None or replicates_border(self.lens, film)
            self._image_window = (film, None if whole else image_window(self.lens, film))
        return self._image_window[1]

    def render(self, cam_from_target: np.ndarray, light_dir_cam: np.ndarray, irradiance: float,
               seed: int) -> np.ndarray:
        """cam_from_target (4, 4) full scale; light_dir_cam (3,) unit, from the target towards
        the light; irradiance W/m^2; returns (H, W, 4) float32 through the lens. Only the film
        window that holds the target is rendered (``film_window``, one compiled kernel for
        every window: ``LoadedScene.render_window``); the rest of the film is black space, as
        a full render's. Where no window can be drawn, Mitsuba renders the whole film."""
        target_from_cam = g.invert(cam_from_target)
        travel = -(target_from_cam[:3, :3] @ np.asarray(light_dir_cam, float))
        # the directional emitter sends its light along its local +z axis
        sun_rotation = g.look_at_rotation(travel, np.array([0.0, 0.0, 1.0]) if abs(travel[2]) < 0.9
                                          else np.array([1.0, 0.0, 0.0]))
        self.loaded.set_camera(target_from_cam)
        self.loaded.set_transform("sun.to_world", g.make_transform(sun_rotation, np.zeros(3)))
        self.loaded.set_grey("sun.irradiance.value", irradiance)
        # opaque: one compiled kernel for every pose and light, whatever rendered before
        opaque = ("sensor.to_world", "sun.to_world", "sun.irradiance.value")
        window = self.film_window(cam_from_target)
        if window is None:
            return self.lens.distort(np.asarray(self.loaded.render(self.spp, seed, opaque=opaque), dtype=np.float32))
        geometry = self.lens.geometry
        pinhole = np.zeros((geometry.height, geometry.width, 4), np.float32)
        if not window.empty:
            pinhole[window.slices()] = self.loaded.render_window(window.x, window.y, window.width, window.height,
                                                                 self.spp, seed, opaque=opaque)
        image = self.image_window(cam_from_target)
        return self.lens.distort(pinhole) if image is None else distorted(self.lens, pinhole, window, image)


def ray_traced_mask(renderer: TargetRenderer, cam_from_target: np.ndarray) -> np.ndarray:
    """Where the model covers each output pixel centre (H, W) bool, by casting one ray per
    pixel through the lens model; independent of the film, the filter and the remap."""
    camera = renderer.lens.camera
    target_from_cam = g.invert(cam_from_target)
    directions = pixel_rays(camera) @ target_from_cam[:3, :3].T
    hit = first_hit_on(renderer.mi, renderer.scene, rays(renderer.mi, target_from_cam[:3, 3], directions))
    return hit.reshape(camera.height, camera.width)

