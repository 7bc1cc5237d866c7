"""``rosbag.toml``, the small file beside a ROS 2 bag that says which of its topics and
frames are what (``acquire --backend replay --format rosbag``; ``export --format rosbag``
writes one beside its bag). Defined here once, versioned, validated on read; every error
names the file and the key. docs/user-guide.md walks a lab through it.

```
format_version = 1
sources = ["kuka", "vicon"]       # the robots ("kuka", always), and motion capture ("vicon") if mapped
world_frame = "world"             # the robots' world in /tf (frame K of the session format)

[setup]                           # optional, as session.toml: a body on "world" stands still
camera_on = "flange"              # "flange" | "world"
target_on = "flange"

[camera]
topic = "/camera/image"           # sensor_msgs/Image or sensor_msgs/CompressedImage
info_topic = "/camera/info"       # optional: sensor_msgs/CameraInfo (K, and plumb_bob distortion)

[pattern]                         # optional: the calibration pattern, as session.toml's (its
                                  # target_from_pattern_q is (w, x, y, z), not ROS's (x, y, z, w))

[robots.camera]                   # the arm that carries the camera (absent when camera_on = "world")
joints_topic = "/joint_states"    # sensor_msgs/JointState: positions in rad (revolute joints)
joints = ["cam_a1", "cam_a2", "cam_a3", "cam_a4", "cam_a5", "cam_a6"]   # optional; all six or none
flange_frame = "cam_flange"       # the flange in /tf (or /tf_static), below world_frame
[robots.target]                   # the arm that carries the target (absent when target_on = "world")
[rail]                            # optional: the railed robot's rail, a prismatic joint (m)
topic = "/joint_states"
joint = "rail"

[motion_capture]                  # with sources = [.., "vicon"]
world_frame = "mocap"             # motion capture's world, for bodies given as /tf frames
camera_body = { topic = "/mocap/camera/pose" }   # geometry_msgs/PoseStamped, or { frame = "..." } in /tf
target_body = { topic = "/mocap/target/pose" }
max_gap_s = 0.05                  # a body's pose within this of the stamp, or it was not tracked

[captures]
trigger_topic = "/camera/trigger" # optional: sensor_msgs/TimeReference (time_ref: the exposure's
                                  # instant); default: each image is a capture
trigger_window_s = 0.1            # a trigger's image: the nearest one stamped within this of it
trigger_names_samples = false     # true: each trigger's source is its sample id (export writes it so)
still_s = 0.5                     # the robots stood still this long before the exposure...
exposure_s = 0.01                 # ...and through it
tolerance_rad = 1e-5              # "still": no joint or /tf rotation moved more than this
tolerance_m = 1e-5                # nor a joint or /tf translation
clock_jump_s = 0.5                # a topic whose stamp steps against its recording time by more is refused
max_message_gap_s = 0.1           # the robots' messages over the stand-still at most this far apart
sessions = [["calibration", 0.0, 60.0], ["dataset", 60.0, 1e9]]   # seconds after the bag's first
                                  # message: which captures belong to which session
fixtures = [["minus_x", 0.0, 30.0]]   # optional, the same way: which model fixture (mount) held the
                                  # target; a capture in no window: "fixed"
```
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from manifests.files import write_bytes_atomic
from manifests.schema import SESSIONS
from speedplus.errors import FileError, unknown_keys

MAPPING_FILE = "rosbag.toml"
MAPPING_VERSION = 1
TOP_KEYS = {"format_version", "sources", "world_frame", "setup", "camera", "pattern", "robots", "rail",
            "motion_capture", "captures"}
SETUP_KEYS = ("camera_on", "target_on")
ROBOTS = ("camera", "target")
#: the defaults of [captures]; each is a number
CAPTURE_DEFAULTS = {"still_s": 0.5, "exposure_s": 0.01, "tolerance_rad": 1e-5, "tolerance_m": 1e-5,
                    "clock_jump_s": 0.5, "max_message_gap_s": 0.1, "trigger_window_s": 0.1}


@dataclass(frozen=True)
class RobotTopics:
    """One arm: its joints (``joints`` in the arm's order, A1-A6; empty: not mapped) and flange."""

    joints_topic: str
    joints: tuple[str, ...]
    flange_frame: str


@dataclass(frozen=True)
class BodySource:
    """A motion-capture rigid body: a ``PoseStamped`` topic, or a frame in /tf."""

    topic: str | None
    frame: str | None


@dataclass(frozen=True)
class SessionWindow:
    """Captures stamped in [from_s, to_s) seconds after the bag's first message belong to
    ``session`` (a session's name, or a fixture's in ``captures.fixtures``)."""

    session: str
    from_s: float
    to_s: float


@dataclass(frozen=True)
class BagMapping:
    """A validated ``rosbag.toml`` (the module's docstring says each key)."""

    path: Path
    sources: tuple[str, ...]
    world_frame: str
    setup: dict[str, str]
    camera_topic: str
    info_topic: str | None
    pattern: dict[str, Any] | None
    robots: dict[str, RobotTopics]
    rail: tuple[str, str] | None
    mocap_world_frame: str | None
    bodies: dict[str, BodySource]  # "camrb" / "targetrb"
    max_gap_s: float
    trigger_topic: str | None
    still_s: float
    exposure_s: float
    tolerance_rad: float
    tolerance_m: float
    clock_jump_s: float
    max_message_gap_s: float
    trigger_window_s: float
    sessions: tuple[SessionWindow, ...]
    fixtures: tuple[SessionWindow, ...] = ()
    trigger_names_samples: bool = False

    def session_at(self, seconds: float) -> str | None:
        """The session of a capture stamped ``seconds`` after the bag's start (None: in no window)."""
        return next((w.session for w in self.sessions if w.from_s <= seconds < w.to_s), None)

    def fixture_at(self, seconds: float) -> str:
        """The model fixture of a capture stamped ``seconds`` after the bag's start."""
        return next((w.session for w in self.fixtures if w.from_s <= seconds < w.to_s), "fixed")

    def to_toml(self) -> str:
        document: dict[str, Any] = {"format_version": MAPPING_VERSION, "sources": list(self.sources),
                                    "world_frame": self.world_frame, "setup": dict(self.setup)}
        document["camera"] = {"topic": self.camera_topic, **({"info_topic": self.info_topic} if self.info_topic
                                                              else {})}
        if self.pattern is not None:
            document["pattern"] = self.pattern
        document["robots"] = {name: {"joints_topic": r.joints_topic, "joints": list(r.joints),
                                     "flange_frame": r.flange_frame} for name, r in self.robots.items()}
        if self.rail is not None:
            document["rail"] = {"topic": self.rail[0], "joint": self.rail[1]}
        if "vicon" in self.sources:
            bodies = {f"{'camera' if key == 'camrb' else 'target'}_body":
                      ({"topic": b.topic} if b.topic else {"frame": b.frame}) for key, b in self.bodies.items()}
            document["motion_capture"] = {**({"world_frame": self.mocap_world_frame} if self.mocap_world_frame
                                             else {}), **bodies, "max_gap_s": self.max_gap_s}
        captures: dict[str, Any] = {"trigger_topic": self.trigger_topic} if self.trigger_topic else {}
        captures.update({"still_s": self.still_s, "exposure_s": self.exposure_s, "tolerance_rad": self.tolerance_rad,
                         "tolerance_m": self.tolerance_m, "clock_jump_s": self.clock_jump_s,
                         "max_message_gap_s": self.max_message_gap_s, "trigger_window_s": self.trigger_window_s,
                         "trigger_names_samples": self.trigger_names_samples,
                         "sessions": [[w.session, w.from_s, w.to_s] for w in self.sessions]})
        if self.fixtures:
            captures["fixtures"] = [[w.session, w.from_s, w.to_s] for w in self.fixtures]
        document["captures"] = captures
        return tomli_w.dumps(document)


def write_mapping(directory: Path, mapping: BagMapping) -> None:
    write_bytes_atomic(directory / MAPPING_FILE, mapping.to_toml().encode())


class _Table:
    """A TOML table being validated: errors name the file and the dotted key."""

    def __init__(self, data: Any, path: Path, prefix: str, known: set[str]) -> None:
        self.path, self.prefix = path, prefix
        if not isinstance(data, dict):
            raise FileError(path, f"[{prefix.rstrip('.')}] must be a table")
        unknown = sorted(set(data) - known)
        if unknown:
            where = f" in [{prefix.rstrip('.')}]" if prefix else ""
            raise FileError(path, f"unknown key(s){where} {unknown_keys(unknown, known)}")
        self.data = data

    def fail(self, key: str, expected: str) -> FileError:
        return FileError(self.path, f"key {self.prefix}{key}: expected {expected}, got {self.data.get(key)!r}")

    def text(self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
        value = self.data.get(key, default)
        if not isinstance(value, str) or not value or (choices and value not in choices):
            raise self.fail(key, " or ".join(choices) if choices else "a non-empty string")
        return value

    def optional_text(self, key: str) -> str | None:
        return self.text(key) if key in self.data else None

    def number(self, key: str, default: float, minimum: float = 0.0) -> float:
        value = self.data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) \
                or value < minimum:
            raise self.fail(key, f"a finite number >= {minimum:g}")
        return float(value)

    def table(self, key: str, known: set[str]) -> _Table:
        return _Table(self.data.get(key, {}), self.path, f"{self.prefix}{key}.", known)


def _robots(top: _Table, setup: dict[str, str]) -> dict[str, RobotTopics]:
    robots = top.table("robots", set(ROBOTS))
    out = {}
    for name, key in zip(ROBOTS, SETUP_KEYS, strict=True):
        moving = setup[key] == "flange"
        if not moving:
            if name in robots.data:
                raise FileError(top.path, f"[robots.{name}] given, but [setup] {key} = \"world\"")
            continue
        if name not in robots.data:
            raise FileError(top.path, f"[robots.{name}] missing: [setup] {key} = \"flange\" needs its arm")
        arm = robots.table(name, {"joints_topic", "joints", "flange_frame"})
        joints = arm.data.get("joints", [])
        if not isinstance(joints, list) or len(joints) not in (0, 6) or not all(
                isinstance(j, str) and j for j in joints) or len(set(joints)) != len(joints):
            raise arm.fail("joints", "six distinct joint names (A1-A6 in order), or none")
        topic = arm.text("joints_topic") if joints else arm.data.get("joints_topic", "")
        out[name] = RobotTopics(topic, tuple(joints), arm.text("flange_frame"))
    if len(out) == 2 and bool(out["camera"].joints) != bool(out["target"].joints):
        raise FileError(top.path, "[robots] joints: both arms' or neither's (the arms are calibrated together)")
    return out


def _bodies(top: _Table) -> tuple[str | None, dict[str, BodySource], float]:
    mocap = top.table("motion_capture", {"world_frame", "camera_body", "target_body", "max_gap_s"})
    bodies = {}
    for key, body in (("camera_body", "camrb"), ("target_body", "targetrb")):
        if key not in mocap.data:
            continue
        entry = mocap.table(key, {"topic", "frame"})
        if ("topic" in entry.data) == ("frame" in entry.data):
            raise FileError(top.path, f"[motion_capture] {key}: give topic (a PoseStamped) or frame (in /tf), one")
        bodies[body] = BodySource(entry.optional_text("topic"), entry.optional_text("frame"))
    if not bodies:
        raise FileError(top.path, "[motion_capture] maps no rigid body (camera_body, target_body), but sources "
                                  "lists vicon")
    frames = any(b.frame for b in bodies.values())
    world = mocap.text("world_frame") if frames else mocap.optional_text("world_frame")
    return world, bodies, mocap.number("max_gap_s", 0.05)


def _windows(captures: _Table, key: str, names: tuple[str, ...] | None) -> tuple[SessionWindow, ...]:
    """``[[name, from_s, to_s], ...]`` under ``key``: ``names`` the allowed names (None: any
    name of a fixture), windows that do not overlap."""
    value = captures.data.get(key, [] if names is None else None)
    if not isinstance(value, list) or (names is not None and not value):
        raise captures.fail(key, "a list of [name, from_s, to_s]")
    windows = []
    for index, entry in enumerate(value):
        if (not isinstance(entry, list) or len(entry) != 3 or not isinstance(entry[0], str) or not entry[0]
                or (names is not None and entry[0] not in names)
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in entry[1:])
                or not entry[1] < entry[2]):
            allowed = f"one of {', '.join(names)}" if names else "a fixture's name"
            raise FileError(captures.path, f"key captures.{key}[{index}]: expected [name, from_s, to_s] with the "
                                           f"name {allowed} and from_s < to_s, got {entry!r}")
        windows.append(SessionWindow(entry[0], float(entry[1]), float(entry[2])))
    ordered = sorted(windows, key=lambda w: w.from_s)
    for a, b in zip(ordered, ordered[1:], strict=False):
        if b.from_s < a.to_s:
            raise FileError(captures.path, f"key captures.{key}: windows {a.session} [{a.from_s:g}, {a.to_s:g}) "
                                           f"and {b.session} [{b.from_s:g}, {b.to_s:g}) overlap")
    return tuple(windows)


def read_mapping(path: Path) -> BagMapping:
    """``rosbag.toml`` at ``path``, validated (``FileError`` naming the key)."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise FileError(path, f"file not found: a bag needs its mapping ({MAPPING_FILE}, docs/user-guide.md)") \
            from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise FileError(path, f"not valid TOML ({error})") from None
    except OSError as error:
        raise FileError(path, f"unreadable ({error.strerror})") from None
    top = _Table(data, path, "", TOP_KEYS)
    if data.get("format_version") != MAPPING_VERSION:
        raise top.fail("format_version", str(MAPPING_VERSION))
    sources = data.get("sources", ["kuka"])
    if not isinstance(sources, list) or "kuka" not in sources or not set(sources) <= {"kuka", "vicon"}:
        raise top.fail("sources", "a list of kuka and optionally vicon")
    setup_table = top.table("setup", set(SETUP_KEYS))
    setup = {key: setup_table.text(key, "flange", ("flange", "world")) for key in SETUP_KEYS}
    if set(setup.values()) == {"world"}:
        raise FileError(path, "[setup] camera_on and target_on are both world: nothing moves")
    camera = top.table("camera", {"topic", "info_topic"})
    rail = None
    if "rail" in data:
        rail_table = top.table("rail", {"topic", "joint"})
        rail = (rail_table.text("topic"), rail_table.text("joint"))
    world, bodies, gap = _bodies(top) if "vicon" in sources else (None, {}, 0.05)
    if "vicon" not in sources and "motion_capture" in data:
        raise FileError(path, "[motion_capture] given, but sources does not list vicon")
    captures = top.table("captures", {"trigger_topic", "sessions", "fixtures", "trigger_names_samples",
                                      *CAPTURE_DEFAULTS})
    numbers = {key: captures.number(key, default) for key, default in CAPTURE_DEFAULTS.items()}
    names_samples = captures.data.get("trigger_names_samples", False)
    if not isinstance(names_samples, bool):
        raise captures.fail("trigger_names_samples", "true or false")
    if "pattern" in data and not isinstance(data["pattern"], dict):
        raise FileError(path, "[pattern] must be a table")
    return BagMapping(path, tuple(sorted(sources, key=("kuka", "vicon").index)), top.text("world_frame", "world"),
                      setup, camera.text("topic"), camera.optional_text("info_topic"), data.get("pattern"),
                      _robots(top, setup), rail, world, bodies, gap, captures.optional_text("trigger_topic"),
                      sessions=_windows(captures, "sessions", SESSIONS),
                      fixtures=_windows(captures, "fixtures", None), trigger_names_samples=names_samples,
                      **numbers)
