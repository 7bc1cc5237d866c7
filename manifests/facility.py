"""A facility folder: the room, its robots (URDF), rails, static mounts, camera, lights and
motion capture, as ``DIR/facility.toml`` beside the URDFs and obstacle meshes it names
(docs/architecture.md section 11). Format version 1; every error names the file and the
key (or the line and column of a TOML syntax error); the URDFs are checked where they are
read (``stages.common.robots.chain``).

    DIR/facility.toml
    format_version = 1
    name = "tron"                     # [a-z0-9_-]+
    length_unit = "m"                 # or "mm": every length in this file; angles in rad
    [room]
    size = [8.0, 3.0, 3.0]            # a box from the origin of frame K (x along the room, z up)
    obstacles = []                    # optional: meshes (trimesh formats) in K, relative to DIR
    [[robot]]
    name = "camera_robot"             # [a-z0-9_-]+, unique
    carries = "camera"                # or "target"
    urdf = "kr16_2.urdf"              # relative to DIR: one serial chain between the two links
    base_link = "base_link"
    flange_link = "tool0"
    world_from_base_t = [1.7, 1.5, 3.0]          # where the base stands in K (rail at 0)
    world_from_base_q = [0.0, 1.0, 0.0, 0.0]     # Hamilton, w first
    flange_from_tool_t = [0.0, 0.0, 0.12]        # optional: what it carries, in the flange frame
    flange_from_tool_q = [1.0, 0.0, 0.0, 0.0]    # (the camera's optical frame; the target's origin)
    payload_kg = 2.5                  # optional: what it carries, with its fixture
    controller = "kuka"               # optional: kuka (KRL, degrees, rail as E1 in mm), ur
                                      # (URScript, radians) or none; what export --format robot writes
    [robot.rail]                      # optional: a prismatic axis carrying the base
    axis = [1.0, 0.0, 0.0]            # in K
    travel = [0.0, 5.9]               # along axis, from the base's place above
    [[static]]                        # optional: a mount that stands still, instead of a robot
    name = "tripod"
    carries = "target"
    world_from_mount_t = [...]
    world_from_mount_q = [...]
    [camera]                          # optional: the sensor (absent: the configuration's [camera])
    sensor = "mono"                   # or "colour"
    size_px = [1920, 1200]
    pixel_pitch = 5.86e-6             # length_unit
    [motion_capture]                  # optional: absent, robots only
    cameras = [{ position = [x, y, z], aim = [x, y, z] }, ...]   # K
    marker_sigma = 0.0003             # length_unit, seen by two cameras
    [[light_box]]                     # optional
    centre = [x, y, z]
    size = [0.6, 0.6]
    aim = [x, y, z]
    [sun_lamp]                        # optional
    position = [x, y, z]
    radius = 0.04
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Literal

from manifests.schema import NAME_PATTERN
from manifests.sidecars.base import Fields, Pose, SidecarError, read_toml

FACILITY_FILE = "facility.toml"
FACILITY_FORMAT_VERSION = 1
#: metres per unit
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
OBSTACLE_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl")
#: a room's side in metres: below, the file is not in metres; above, not a room (a unit off by 1000)
ROOM_SIDE_M = (0.5, 100.0)
IDENTITY = Pose((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
Carried = Literal["camera", "target"]
#: the robot programs ``export --format robot`` writes (stages/export/robot.py)
CONTROLLERS = ("kuka", "ur", "none")


class FacilityError(SidecarError):
    """A facility folder that cannot be used as it is."""


@dataclass(frozen=True)
class RailSpec:
    axis: tuple[float, float, float]  # unit vector in K
    travel_m: tuple[float, float]  # along the axis, from the base's place


@dataclass(frozen=True)
class RobotSpec:
    name: str
    carries: Carried
    urdf: str  # relative to the folder
    base_link: str
    flange_link: str
    world_from_base: Pose  # metres
    flange_from_tool: Pose  # metres: the carried camera's frame, or the target's origin
    payload_kg: float
    rail: RailSpec | None
    controller: str = "none"  # CONTROLLERS


@dataclass(frozen=True)
class StaticSpec:
    name: str
    carries: Carried
    world_from_mount: Pose  # metres


@dataclass(frozen=True)
class CameraSpec:
    sensor: Literal["mono", "colour"]
    size_px: tuple[int, int]
    pixel_pitch_m: float


@dataclass(frozen=True)
class MotionCaptureSpec:
    cameras: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...]  # (position, aim) m
    marker_sigma_m: float


@dataclass(frozen=True)
class LightBoxSpec:
    centre_m: tuple[float, float, float]
    size_m: tuple[float, float]
    aim_m: tuple[float, float, float]


@dataclass(frozen=True)
class SunLampSpec:
    position_m: tuple[float, float, float]
    radius_m: float


@dataclass(frozen=True)
class FacilitySpec:
    """``facility.toml``, every length in metres."""

    name: str
    room_m: tuple[float, float, float]
    obstacles: tuple[str, ...]
    robots: tuple[RobotSpec, ...]
    statics: tuple[StaticSpec, ...]
    camera: CameraSpec | None
    motion_capture: MotionCaptureSpec | None
    light_boxes: tuple[LightBoxSpec, ...]
    sun_lamp: SunLampSpec | None

    def carrier(self, carried: Carried) -> RobotSpec | StaticSpec:
        """The robot or static mount that holds the camera (or the target)."""
        return next(item for item in (*self.robots, *self.statics) if item.carries == carried)


def read_facility_spec(directory: Path) -> FacilitySpec:
    """``DIR/facility.toml``, validated (the URDFs: ``stages.common.robots``)."""
    path = Path(directory) / FACILITY_FILE
    data = read_toml(path, FacilityError, "a facility folder holds facility.toml beside its URDFs")
    try:
        return _parse(Fields(data, str(path), ""), Path(directory))
    except FacilityError:
        raise
    except SidecarError as error:
        raise FacilityError(str(error)) from None


def facility_files(directory: Path, spec: FacilitySpec) -> list[str]:
    """The folder's files the facility is made of: facility.toml, URDFs, obstacle meshes."""
    return [FACILITY_FILE, *sorted({robot.urdf for robot in spec.robots}), *spec.obstacles]


def facility_digest(directory: Path) -> str:
    """Digest of what the facility is made of (its files' names and bytes)."""
    directory = Path(directory)
    digest = hashlib.sha256()
    for name in facility_files(directory, read_facility_spec(directory)):
        digest.update(name.encode() + b"\0" + (directory / name).read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def inside(directory: Path, f: Fields, key: str, reference: str, suffixes: tuple[str, ...]) -> str:
    """A file the facility names: relative, inside the folder, present, of a known type."""
    relative = PurePosixPath(reference.replace("\\", "/"))
    if relative.is_absolute() or ".." in relative.parts or not (directory / relative).resolve().is_relative_to(
            directory.resolve()):
        raise FacilityError(f"{f.where}: key {f.key(key)}: {reference!r} is outside the facility folder {directory}")
    if relative.suffix.lower() not in suffixes:
        raise f.fail(key, f"a file ending in {', '.join(suffixes)}")
    if not (directory / relative).is_file():
        raise FacilityError(f"{f.where}: key {f.key(key)}: {directory / relative} does not exist")
    return relative.as_posix()


def _parse(f: Fields, directory: Path) -> FacilitySpec:
    f.only("format_version", "name", "length_unit", "room", "robot", "static", "camera", "motion_capture",
           "light_box", "sun_lamp")
    if f.data.get("format_version") != FACILITY_FORMAT_VERSION:
        raise f.fail("format_version", f"{FACILITY_FORMAT_VERSION} (this program reads version "
                                       f"{FACILITY_FORMAT_VERSION})")
    name = f.text("name")
    if not NAME_PATTERN.fullmatch(name):
        raise f.fail("name", "a name of a-z, 0-9, _ and -")
    unit = LENGTH_UNITS[f.text("length_unit", tuple(LENGTH_UNITS))]
    room_m, obstacles = _room(f.child("room"), unit, directory)
    robots = tuple(_robot(item, unit, directory, room_m) for item in _tables(f, "robot"))
    statics = tuple(_static(item, unit, room_m) for item in _tables(f, "static"))
    names = [item.name for item in (*robots, *statics)]
    if len(set(names)) != len(names):
        raise f.fail("robot", "robots and static mounts of distinct names")
    for carried in ("camera", "target"):
        holders = [item.name for item in (*robots, *statics) if item.carries == carried]
        if len(holders) != 1:
            raise FacilityError(f"{f.where}: exactly one robot or static mount carries the {carried}, found "
                                f"{len(holders)} ({', '.join(holders) or 'none'})")
    if not robots:
        raise f.fail("robot", "at least one [[robot]]: a facility of static mounts presents one pose")
    return FacilitySpec(
        name, room_m, obstacles, robots, statics,
        _camera(f.child("camera"), unit) if f.optional("camera") else None,
        _motion_capture(f.child("motion_capture"), unit, room_m) if f.optional("motion_capture") else None,
        tuple(_light_box(item, unit, room_m) for item in _tables(f, "light_box")),
        _sun_lamp(f.child("sun_lamp"), unit, room_m) if f.optional("sun_lamp") else None)


def _tables(f: Fields, key: str) -> list[Fields]:
    """An array of tables (``[[robot]]``), each as Fields named ``key[i]``."""
    if not f.optional(key):
        return []
    value = f.raw(key)
    if not isinstance(value, list) or not all(isinstance(item, dict) for item in value):
        raise f.fail(key, f"[[{key}]] tables")
    return [Fields(item, f.where, f"{f.key(key)}[{index}].") for index, item in enumerate(value)]


def _room(f: Fields, unit: float, directory: Path) -> tuple[tuple[float, float, float], tuple[str, ...]]:
    f.only("size", "obstacles")
    size = tuple(v * unit for v in f.vector("size", 3))
    low, high = ROOM_SIDE_M
    if not all(low <= side <= high for side in size):
        hint = ("; is length_unit \"mm\"?" if max(size) > high else "; is length_unit \"m\"?" if min(size) < low
                else "")
        raise FacilityError(f"{f.where}: key {f.key('size')}: a room of {' x '.join(f'{s:g}' for s in size)} m; "
                            f"expected each side within {low:g}-{high:g} m{hint}")
    obstacles: list[str] = []
    if f.optional("obstacles"):
        value = f.raw("obstacles")
        if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
            raise f.fail("obstacles", "a list of mesh files")
        listed = Fields({str(i): item for i, item in enumerate(value)}, f.where, f"{f.key('obstacles')}.")
        obstacles = [inside(directory, listed, str(i), item, OBSTACLE_SUFFIXES) for i, item in enumerate(value)]
    return (size[0], size[1], size[2]), tuple(obstacles)


def _point(f: Fields, key: str, unit: float, room_m: tuple[float, float, float] | None = None,
           ) -> tuple[float, float, float]:
    """A position in K (length_unit -> m), inside the room when ``room_m`` is given."""
    point = tuple(v * unit for v in f.vector(key, 3))
    if room_m is not None and not all(-1e-9 <= p <= side + 1e-9 for p, side in zip(point, room_m, strict=True)):
        raise FacilityError(f"{f.where}: key {f.key(key)}: ({', '.join(f'{p:g}' for p in point)}) m is outside the "
                            f"room (0..{room_m[0]:g}, 0..{room_m[1]:g}, 0..{room_m[2]:g} m)")
    return point[0], point[1], point[2]


def _pose(f: Fields, prefix: str, unit: float, room_m: tuple[float, float, float] | None = None,
          default: Pose | None = None) -> Pose:
    """``prefix_t`` (length_unit) and ``prefix_q`` (w, x, y, z, unit norm) as a Pose in m."""
    if default is not None and not f.optional(f"{prefix}_t") and not f.optional(f"{prefix}_q"):
        return default
    q = f.vector(f"{prefix}_q", 4)
    if abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-6:
        raise f.fail(f"{prefix}_q", "a unit quaternion (w, x, y, z)")
    return Pose((q[0], q[1], q[2], q[3]), _point(f, f"{prefix}_t", unit, room_m))


def _carries(f: Fields) -> Carried:
    return "camera" if f.text("carries", ("camera", "target")) == "camera" else "target"


def _name(f: Fields) -> str:
    name = f.text("name")
    if not NAME_PATTERN.fullmatch(name):
        raise f.fail("name", "a name of a-z, 0-9, _ and -")
    return name


def _robot(f: Fields, unit: float, directory: Path, room_m: tuple[float, float, float]) -> RobotSpec:
    f.only("name", "carries", "urdf", "base_link", "flange_link", "world_from_base_t", "world_from_base_q",
           "flange_from_tool_t", "flange_from_tool_q", "payload_kg", "rail", "controller")
    base = _pose(f, "world_from_base", unit, room_m)
    rail = _rail(f.child("rail"), unit, base, room_m) if f.optional("rail") else None
    payload = f.number("payload_kg") if f.optional("payload_kg") else 0.0
    if payload < 0:
        raise f.fail("payload_kg", "a mass of at least 0 kg")
    return RobotSpec(_name(f), _carries(f), inside(directory, f, "urdf", f.text("urdf"), (".urdf",)),
                     f.text("base_link"), f.text("flange_link"), base,
                     _pose(f, "flange_from_tool", unit, default=IDENTITY), payload, rail,
                     f.text("controller", CONTROLLERS) if f.optional("controller") else "none")


def _rail(f: Fields, unit: float, base: Pose, room_m: tuple[float, float, float]) -> RailSpec:
    f.only("axis", "travel")
    axis = f.vector("axis", 3)
    norm = math.sqrt(sum(v * v for v in axis))
    if norm < 1e-9:
        raise f.fail("axis", "a direction (not zero)")
    low, high = (v * unit for v in f.vector("travel", 2))
    if not high > low:
        raise FacilityError(f"{f.where}: key {f.key('travel')}: a rail of zero or negative length "
                            f"({low:g} to {high:g} m); expected [start, end] with end > start")
    direction = (axis[0] / norm, axis[1] / norm, axis[2] / norm)
    for end in (low, high):
        point = [b + end * d for b, d in zip(base.t, direction, strict=True)]
        if not all(-1e-9 <= p <= side + 1e-9 for p, side in zip(point, room_m, strict=True)):
            raise FacilityError(f"{f.where}: key {f.key('travel')}: at {end:g} m the base is at "
                                f"({', '.join(f'{p:g}' for p in point)}) m, outside the room")
    return RailSpec(direction, (low, high))


def _static(f: Fields, unit: float, room_m: tuple[float, float, float]) -> StaticSpec:
    f.only("name", "carries", "world_from_mount_t", "world_from_mount_q")
    return StaticSpec(_name(f), _carries(f), _pose(f, "world_from_mount", unit, room_m))


def _camera(f: Fields, unit: float) -> CameraSpec:
    f.only("sensor", "size_px", "pixel_pitch")
    size = f.vector("size_px", 2)
    if not all(float(v).is_integer() and v >= 1 for v in size):
        raise f.fail("size_px", "two whole numbers of pixels")
    sensor: Literal["mono", "colour"] = "mono" if f.text("sensor", ("mono", "colour")) == "mono" else "colour"
    return CameraSpec(sensor, (int(size[0]), int(size[1])), f.number("pixel_pitch", positive=True) * unit)


def _motion_capture(f: Fields, unit: float, room_m: tuple[float, float, float]) -> MotionCaptureSpec:
    f.only("cameras", "marker_sigma")
    cameras = []
    for item in _tables(f, "cameras"):
        item.only("position", "aim")
        cameras.append((_point(item, "position", unit, room_m), _point(item, "aim", unit, room_m)))
    if len(cameras) < 2:
        raise f.fail("cameras", "at least two cameras (a marker is triangulated)")
    return MotionCaptureSpec(tuple(cameras), f.number("marker_sigma", positive=True) * unit)


def _light_box(f: Fields, unit: float, room_m: tuple[float, float, float]) -> LightBoxSpec:
    f.only("centre", "size", "aim")
    size = f.vector("size", 2)
    if not all(v > 0 for v in size):
        raise f.fail("size", "a positive width and height")
    return LightBoxSpec(_point(f, "centre", unit, room_m), (size[0] * unit, size[1] * unit),
                        _point(f, "aim", unit, room_m))


def _sun_lamp(f: Fields, unit: float, room_m: tuple[float, float, float]) -> SunLampSpec:
    f.only("position", "radius")
    return SunLampSpec(_point(f, "position", unit, room_m), f.number("radius", positive=True) * unit)


def describe(spec: FacilitySpec) -> dict[str, Any]:
    """What the folder says, in metres (``speedplus facility`` prints it beside the robots' reach)."""
    return {"name": spec.name, "room_m": list(spec.room_m), "robots": [robot.name for robot in spec.robots],
            "statics": [static.name for static in spec.statics], "light_boxes": len(spec.light_boxes),
            "sun_lamp": spec.sun_lamp is not None,
            "motion_capture_cameras": 0 if spec.motion_capture is None else len(spec.motion_capture.cameras)}
