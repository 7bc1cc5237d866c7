"""The room the virtual testbed photographs and tracks in: its size, light boxes, sun lamp
and motion-capture cameras, from ``[testbed]``/``[virtual]`` (TRON) or from the facility
folder (``facility.path``; docs/architecture.md section 11).

TRON's values come from the configuration exactly as before the folder existed, so its
captures keep their bytes; a facility's come from its ``facility.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from core.config import Config
from manifests.facility import read_facility_spec

#: TRON's motion capture: 12 wall cameras (4 on each long wall, 2 on each end wall)
TRON_MOCAP_CAMERAS = 12


@dataclass(frozen=True)
class LightBox:
    centre_m: np.ndarray  # (3,) in K
    size_m: tuple[float, float]
    aim_m: np.ndarray  # (3,) the point in K its face looks at


@dataclass(frozen=True)
class Room:
    """What the virtual testbed's room holds, in K (m)."""

    size_m: tuple[float, float, float]
    light_boxes: tuple[LightBox, ...]
    sun_lamp_m: np.ndarray | None  # (3,) centre; None: the room has none
    sun_lamp_radius_m: float
    mocap_positions_m: np.ndarray | None  # (C, 3); None: no motion capture
    mocap_aims_m: np.ndarray | None  # (C, 3) the point each camera looks at
    marker_sigma_m: float
    #: the ambient (calibration) light: TRON's two ceiling panels, or a facility room's
    #: surfaces glowing (``scene.ROOM_GLOW``), which light a board however the robots hold it
    glowing: bool = False

    @property
    def mocap_cameras(self) -> int:
        return 0 if self.mocap_positions_m is None else len(self.mocap_positions_m)


def room_of(config: Config) -> Room:
    """The configured room: the facility folder's, else TRON's from ``[testbed]``."""
    if config.facility.path:
        return _facility_room(Path(config.facility.path).resolve())
    testbed, virtual = config.testbed, config.virtual
    aim = np.asarray(testbed.light_box_aim_m, float)
    boxes = tuple(LightBox(np.asarray(c, float), tuple(testbed.light_box_size_m), aim)
                  for c in testbed.light_box_centres_m)
    positions = _tron_mocap(testbed.room_m, virtual.vicon_camera_height_m)
    length, width, _ = testbed.room_m
    aims = np.broadcast_to(np.array([0.45 * length, width / 2, 1.2]), positions.shape)
    return Room(tuple(testbed.room_m), boxes, np.asarray(testbed.sun_lamp_position_m, float),
                virtual.sun_lamp_radius_m, positions, aims, virtual.vicon_marker_sigma_m)


def _tron_mocap(room_m: tuple[float, float, float], height: float) -> np.ndarray:
    """(12, 3) TRON's cameras on the walls near the ceiling."""
    length, width, _ = room_m
    xs = np.linspace(0.15 * length, 0.85 * length, 4)
    cams = [(x, 0.05, height) for x in xs] + [(x, width - 0.05, height) for x in xs]
    cams += [(0.05, y, height) for y in (0.3 * width, 0.7 * width)]
    cams += [(length - 0.05, y, height) for y in (0.3 * width, 0.7 * width)]
    return np.array(cams)


@cache
def _facility_room(directory: Path) -> Room:
    spec = read_facility_spec(directory)
    boxes = tuple(LightBox(np.asarray(b.centre_m, float), tuple(b.size_m), np.asarray(b.aim_m, float))
                  for b in spec.light_boxes)
    lamp = spec.sun_lamp
    mocap = spec.motion_capture
    positions = None if mocap is None else np.array([c[0] for c in mocap.cameras], float)
    aims = None if mocap is None else np.array([c[1] for c in mocap.cameras], float)
    return Room(tuple(spec.room_m), boxes, None if lamp is None else np.asarray(lamp.position_m, float),
                0.0 if lamp is None else lamp.radius_m, positions, aims,
                0.0 if mocap is None else mocap.marker_sigma_m, glowing=True)
