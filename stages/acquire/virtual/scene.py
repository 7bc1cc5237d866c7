"""The testbed's room in Mitsuba 3 (``room.room_of``: TRON's, or a facility folder's): black
curtains, the Earth-albedo light boxes, the sun lamp, ceiling panels for calibration, the
mock-up (with its own look) and the ChArUco board.

The scene is built once per worker process; each capture moves the camera, the model and
the board, and switches lights, through the scene's parameters
(``mitsuba_adapter.LoadedScene``). Coordinates: robot world K.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from core.config import Config
from stages.acquire.virtual.room import room_of
from stages.common import geometry as g
from stages.common import layout
from stages.common.lens import RenderGeometry
from stages.common.looks import mockup_look
from stages.common.mitsuba_adapter import (
    LoadedScene,
    bsdf,
    first_hit_on,
    load_mitsuba,
    mesh,
    sensor,
    sensor_pixel_rays,
    set_one_thread,
    transform,
)
from stages.common.patterns import board_image, board_pattern
from stages.common.surface import shape_id
from stages.common.target import Target
from stages.common.tone import luminance

BOARD_MARGIN_M = 0.01  # white border of the printed plate around the 11 x 11 squares
_HIDDEN_OFFSET = np.array([0.0, 0.0, -100.0])  # where absent objects are parked (below the floor)
#: a facility room's surfaces glow with this share of ``virtual.ambient_radiance`` under its
#: ambient light, as a lab's lights fill it: a board is lit whichever way the robots hold it
#: (TRON's two ceiling panels light a board held up to a camera hung from the ceiling; a
#: room of its own may hold it sideways or down)
ROOM_GLOW = 0.1
def _facing(centre: np.ndarray, normal: np.ndarray, half_size: tuple[float, float]) -> np.ndarray:
    """to_world (4, 4) of Mitsuba's rectangle ([-1, 1]^2, normal +z) centred at ``centre``
    and facing ``normal``."""
    z = normal / np.linalg.norm(normal)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return g.make_transform(np.stack([x, y, z], axis=1) @ np.diag([half_size[0], half_size[1], 1.0]), centre)


#: the blur of the testbed's film: a separable kernel (a, 1 - 2a, a) over box-filtered pixels,
#: whose footprint has the variance (1/12 + 2a px^2 per axis) of the Gaussian reconstruction
#: filter of 0.4 px the captures were made with before (Mitsuba's, splatted per sample)
SENSOR_BLUR_TAP = (0.4**2 - 1.0 / 12.0) / 2.0


def sensor_blur(film: np.ndarray) -> np.ndarray:
    """The film (H, W) blurred as a sensor's optics and pixels blur: (H, W) float32.

    Applied once to the box-filtered film instead of splatting every sample onto its
    neighbours (Mitsuba's Gaussian filter): the same footprint at a third less of a capture's
    cost (docs/architecture.md section 5)."""
    kernel = np.array([SENSOR_BLUR_TAP, 1.0 - 2.0 * SENSOR_BLUR_TAP, SENSOR_BLUR_TAP], np.float32)
    return cv2.sepFilter2D(np.asarray(film, np.float32), -1, kernel, kernel, borderType=cv2.BORDER_REFLECT)


class TestbedScene:
    """A loaded room; ``render`` returns linear luminance (H, W) of the pinhole geometry."""

    __test__ = False

    def __init__(self, config: Config, geometry: RenderGeometry, target: Target) -> None:
        self.mi = mi = load_mitsuba()
        set_one_thread()  # the same bytes whatever the workers (mitsuba_adapter.set_one_thread)
        self.config, self.geometry = config, geometry
        virtual = config.virtual
        rng = np.random.default_rng([virtual.seed, 0x7E57])
        self.scale = target.mockup_scale
        self.room = room_of(config)
        self.light_box_count = len(self.room.light_boxes)
        self.glowing = self.room.glowing

        objects: dict[str, Any] = {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": self.config.virtual.max_depth,
                           "rr_depth": self.config.virtual.rr_depth},
            "sensor": sensor(mi, geometry, far_clip_m=30.0, pixel_format="rgb", sampler="multijitter"),
        }
        objects.update(self._room(mi))
        objects.update(self._lights(mi))
        self._parts = {}
        for index, (name, part) in enumerate(target.parts.items()):  # textures drawn in the mesh's order
            objects[shape_id(index)] = mesh(mi, shape_id(index), part.vertices * self.scale, part.faces, part.uv,
                                            bsdf(mi, mockup_look(target.looks.get(name), rng)))
            self._parts[shape_id(index)] = part.vertices * self.scale
        self._board_vertices = self._board(mi, objects, target)
        self.loaded = LoadedScene(mi, objects)
        self.scene = self.loaded.scene
        names = self.loaded.keys()
        self._opaque_keys = [key for key in names if key == "sensor.to_world"
                             or key.endswith(("emitter.radiance.value", "emitter.sampling_weight"))]

    # ----------------------------------------------------------------------- construction
    def _room(self, mi: Any) -> dict[str, Any]:
        length, width, height = self.room.size_m
        curtain = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.008, 0.008, 0.008]}}
        floor = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.05, 0.05, 0.05]}}
        walls = {
            "floor": ([length / 2, width / 2, 0.0], [0, 0, 1], (length / 2, width / 2), floor),
            "ceiling": ([length / 2, width / 2, height], [0, 0, -1], (length / 2, width / 2), curtain),
            "wall_y0": ([length / 2, 0.0, height / 2], [0, 1, 0], (length / 2, height / 2), curtain),
            "wall_y1": ([length / 2, width, height / 2], [0, -1, 0], (length / 2, height / 2), curtain),
            "wall_x0": ([0.0, width / 2, height / 2], [1, 0, 0], (width / 2, height / 2), curtain),
            "wall_x1": ([length, width / 2, height / 2], [-1, 0, 0], (width / 2, height / 2), curtain),
        }
        surfaces = {name: {"type": "rectangle", "to_world": transform(mi, _facing(np.array(c, float),
                                                                                  np.array(n, float), half)),
                           "bsdf": bsdf} for name, (c, n, half, bsdf) in walls.items()}
        if self.glowing:
            for surface in surfaces.values():
                surface["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
        return surfaces

    def _lights(self, mi: Any) -> dict[str, Any]:
        room = self.room
        lights: dict[str, Any] = {}
        # switched-off boxes are covered with the black curtain (as in TRON)
        covered = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.008, 0.008, 0.008]}}
        for index, box in enumerate(room.light_boxes):
            half = (box.size_m[0] / 2, box.size_m[1] / 2)
            lights[f"light_box_{index}"] = {
                "type": "rectangle", "to_world": transform(mi, _facing(box.centre_m, box.aim_m - box.centre_m, half)),
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
                "bsdf": covered,
            }
        if room.sun_lamp_m is not None:
            lights["sun_lamp"] = {
                "type": "sphere", "center": list(map(float, room.sun_lamp_m)), "radius": room.sun_lamp_radius_m,
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
            }
        length, width, height = room.size_m
        for index, x in enumerate(() if self.glowing else (0.25 * length, 0.5 * length)):
            lights[f"ambient_{index}"] = {
                "type": "rectangle",
                "to_world": transform(mi, _facing(np.array([x, width / 2, height - 0.02]), np.array([0, 0, -1.0]),
                                                   (0.6, 0.6))),
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
                "bsdf": covered,
            }
        return lights

    def _board(self, mi: Any, objects: dict[str, Any], target: Target) -> np.ndarray:
        """The printed ChArUco plate as a textured quad; returns its corners in T."""
        spec = board_pattern(self.config.testbed, target)
        image = board_image(spec, px_per_m=4000.0, margin_m=BOARD_MARGIN_M)
        reflectance = (0.03 + 0.82 * (image.astype(np.float32) / 255.0))[..., None].repeat(3, axis=-1)
        m = BOARD_MARGIN_M
        w, h = spec.size[0] * spec.square_m, spec.size[1] * spec.square_m
        corners_board = np.array([[-m, -m, 0.0], [w + m, -m, 0.0], [w + m, h + m, 0.0], [-m, h + m, 0.0]])
        uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        faces = np.array([[0, 2, 1], [0, 3, 2]])  # front faces -z of the board frame, towards the camera
        corners_target = g.apply(layout.target_from_board(self.config.testbed, target), corners_board)
        plate = bsdf(mi, {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": reflectance}})
        objects["board"] = mesh(mi, "board", corners_target + _HIDDEN_OFFSET, faces, uv, plate)
        return corners_target

    # --------------------------------------------------------------------------- per capture
    def _set_emitter(self, name: str, radiance: float, key: str = "emitter.radiance.value") -> None:
        self.loaded.set_grey(f"{name}.{key}", radiance)
        self.loaded.set_scalar(f"{name}.emitter.sampling_weight", 1.0 if radiance > 0 else 0.0)

    def set_lights(self, light: str, boxes: list[int]) -> None:
        virtual = self.config.virtual
        for index in range(self.light_box_count):
            on = light == "lightbox" and index in boxes
            self._set_emitter(f"light_box_{index}", virtual.light_box_radiance if on else 0.0)
        if self.room.sun_lamp_m is not None:
            self._set_emitter("sun_lamp", virtual.sun_lamp_radiance if light == "sunlamp" else 0.0)
        ambient = virtual.ambient_radiance if light == "ambient" else 0.0
        if self.glowing:
            for name in ("floor", "ceiling", "wall_y0", "wall_y1", "wall_x0", "wall_x1"):
                self._set_emitter(name, ROOM_GLOW * ambient)
        else:
            for index in range(2):
                self._set_emitter(f"ambient_{index}", ambient)

    def render(self, world_from_cam: np.ndarray, world_from_target: np.ndarray, light: str, boxes: list[int],
               show_board: bool, seed: int) -> np.ndarray:
        """Linear luminance (H_render, W_render) of the pinhole render at these true poses."""
        self._pose(world_from_cam, world_from_target)
        board = (g.apply(world_from_target, self._board_vertices) if show_board
                 else self._board_vertices + _HIDDEN_OFFSET)
        self.loaded.set_vertices("board.vertex_positions", board)
        self.set_lights(light, boxes)
        # Opaque parameters: literal values would be folded into the compiled kernel, whose
        # random-number use (and so the image's noise) would then depend on the light set-up
        # of whichever capture compiled it; opaque ones give one kernel for every capture.
        image = self.loaded.render(self.config.virtual.spp, seed, opaque=self._opaque_keys)
        return sensor_blur(luminance(image))

    def _pose(self, world_from_cam: np.ndarray, world_from_target: np.ndarray) -> None:
        """The camera and the mock-up at these true poses (the mesh moves: the room is static)."""
        self.loaded.set_camera(world_from_cam)
        for name, vertices in self._parts.items():
            self.loaded.set_vertices(f"{name}.vertex_positions", g.apply(world_from_target, vertices))

    def silhouette(self, world_from_cam: np.ndarray, world_from_target: np.ndarray) -> np.ndarray:
        """Where the mock-up is the first surface seen (H_render, W_render) float32 (0 or 1),
        one ray per pixel centre through this scene's own camera: the model's silhouette in
        a capture at these poses (tests and benchmarks compare twins with it)."""
        self._pose(world_from_cam, world_from_target)
        self.loaded.update()
        hit = first_hit_on(self.mi, self.scene, sensor_pixel_rays(self.mi, self.scene, self.geometry),
                           set(self._parts))
        return hit.astype(np.float32).reshape(self.geometry.height, self.geometry.width)
