"""The synthetic Tango in Mitsuba 3: the procedural mesh of ``stages.common.tango_mesh`` at full
scale with physically based materials of the flight model's look (smooth gold MLI, solar
cells, white radiator, metal antennas), black space, one directional light.

The model stays in its body frame T; each image moves the camera (``target_from_cam``)
and turns the light through ``mi.traverse``, so the acceleration structure is built once.
The render is an RGBA pinhole image wider than the camera's; ``stages.common.lens`` remaps it
through the label camera's distortion.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stages.common import geometry as g
from stages.common.lens import Lens, LensCamera, pixel_rays
from stages.common.mitsuba_adapter import (
    first_hit_on,
    load_mitsuba,
    load_scene,
    mesh,
    rays,
    sensor,
    sensor_to_world,
    set_threads,
    transform,
)
from stages.common.tango_mesh import tango_parts


def solar_cell_texture(cells: tuple[int, int] = (8, 12), px_per_cell: int = 24) -> np.ndarray:
    """Diffuse reflectance (H, W, 3) of a regular solar-cell array: dark blue cells, silver
    bus bars and a thin frame (the synthetic model's clean look; the mock-up's is noisy)."""
    rows, cols = cells
    h, w = rows * px_per_cell, cols * px_per_cell
    vs, us = np.mgrid[0:h, 0:w]
    image = np.empty((h, w, 3), np.float32)
    image[:] = (0.02, 0.03, 0.09)
    gap = ((us % px_per_cell) < 2) | ((vs % px_per_cell) < 2)
    fingers = (us % (px_per_cell // 3)) == 0
    image[fingers] = (0.12, 0.12, 0.14)
    image[gap] = (0.55, 0.55, 0.58)
    return image


class TangoRenderer:
    """A loaded synthetic-Tango scene for one camera; ``render`` returns (H, W, 4) linear
    RGBA float32 in the camera's (distorted) image, alpha = coverage of the model."""

    def __init__(self, camera: LensCamera, *, spp: int, max_depth: int, threads: int) -> None:
        self.mi = mi = load_mitsuba()
        # the same thread count in every engine: part of what makes the pixels reproducible
        set_threads(threads)
        self.lens = Lens(camera)
        self.spp = spp
        geometry = self.lens.geometry
        objects: dict[str, Any] = {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": max_depth, "hide_emitters": True},
            # box filter: alpha is exact coverage
            "sensor": sensor(mi, geometry, far_clip_m=1000.0, rfilter="box", pixel_format="rgba"),
            "sun": {"type": "directional", "direction": [0.0, 0.0, -1.0],
                    "irradiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        }
        for name, part in tango_parts().items():
            objects[f"tango_{name}"] = mesh(mi, f"tango_{name}", part.vertices, part.faces, part.uv,
                                            self._bsdf(mi, name))
        self.scene = load_scene(mi, objects)
        self.params = mi.traverse(self.scene)

    @staticmethod
    def _bsdf(mi: Any, part: str) -> Any:
        if part == "sides":  # multi-layer insulation: gold foil, a rough conductor, evenly stretched
            return mi.load_dict({"type": "blendbsdf", "weight": 0.25,
                                 "bsdf_0": {"type": "roughconductor", "material": "Au", "alpha": 0.35},
                                 "bsdf_1": {"type": "diffuse",
                                            "reflectance": {"type": "rgb", "value": [0.55, 0.4, 0.12]}}})
        if part == "solar_panel":
            return mi.load_dict({"type": "roughplastic", "alpha": 0.06, "int_ior": 1.5,
                                 "diffuse_reflectance": {"type": "bitmap",
                                                         "bitmap": mi.Bitmap(solar_cell_texture())}})
        if part == "rear_panel":  # white radiator paint
            return mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}})
        return mi.load_dict({"type": "roughconductor", "material": "Al", "alpha": 0.2})

    def render(self, cam_from_target: np.ndarray, light_dir_cam: np.ndarray, irradiance: float,
               seed: int) -> np.ndarray:
        """cam_from_target (4, 4) full scale; light_dir_cam (3,) unit, from the target towards
        the light; irradiance W/m^2; returns (H, W, 4) float32 through the lens."""
        mi = self.mi
        import drjit as dr

        target_from_cam = g.invert(cam_from_target)
        travel = -(target_from_cam[:3, :3] @ np.asarray(light_dir_cam, float))
        # the directional emitter sends its light along its local +z axis
        sun_rotation = g.look_at_rotation(travel, np.array([0.0, 0.0, 1.0]) if abs(travel[2]) < 0.9
                                          else np.array([1.0, 0.0, 0.0]))
        self.params["sensor.to_world"] = sensor_to_world(mi, target_from_cam)
        self.params["sun.to_world"] = transform(mi, g.make_transform(sun_rotation, np.zeros(3)))
        self.params["sun.irradiance.value"] = mi.Color3f(irradiance, irradiance, irradiance)
        # opaque: one compiled kernel for every pose and light, whatever rendered before
        for key in ("sensor.to_world", "sun.to_world", "sun.irradiance.value"):
            dr.make_opaque(self.params[key])
        self.params.update()
        pinhole = np.array(mi.render(self.scene, spp=self.spp, seed=seed), dtype=np.float32)
        return self.lens.distort(pinhole)


def ray_traced_mask(renderer: TangoRenderer, cam_from_target: np.ndarray) -> np.ndarray:
    """Where the model covers each output pixel centre (H, W) bool, by casting one ray per
    pixel through the lens model; independent of the film, the filter and the remap."""
    camera = renderer.lens.camera
    target_from_cam = g.invert(cam_from_target)
    directions = pixel_rays(camera) @ target_from_cam[:3, :3].T
    hit = first_hit_on(renderer.mi, renderer.scene, rays(renderer.mi, target_from_cam[:3, 3], directions))
    return hit.reshape(camera.height, camera.width)

