"""Replay of a ROS 2 bag (``acquire --backend replay --format rosbag --source BAG``): a
lab's own recording, read without ROS and without a converter. BAG is the bag's folder
(``metadata.yaml`` and its MCAP or sqlite3 files, ROS 2 Humble and later; ROS 1 bags are
not read), and ``BAG/rosbag.toml`` says which topics and frames are what
(``stages/common/rosbag/mapping.py``, whose docstring is the format).

Each capture (an image message, or a trigger's ``time_ref``) takes the arms' joints, the
rail, the flanges' poses in /tf and the motion-capture bodies at its stamp, all in the
one clock of the messages' headers. The robots' values are interpolated only where they
stood still (``stages/acquire/bag_streams.py``); a capture where they moved beyond the
tolerance is refused, naming it. Everything but the images is read and checked before
the first capture is written: a missing topic, a clock that jumps, a capture without
joints, a frame that is not in /tf each refuse the replay with nothing written.

The captures are those ``--format session`` gives of the same recording
(``stages/export/rosbag.py`` writes a workspace's captures as such a bag). Not in the
messages, and so null: motion capture's marker counts, the markers its fits used and
their residuals, and each move's duration.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from manifests import Workspace, sample_ids
from manifests.files import write_bytes_atomic
from manifests.sidecars import Session, SessionCamera
from speedplus.errors import FileError
from stages.acquire.backend import CaptureRecord
from stages.acquire.bag_streams import NS, FrameTree, Series, Window, nearest_value, seconds, still_value
from stages.common.geometry import pose_columns
from stages.common.image_io import encode_png, ingest_image
from stages.common.patterns import pattern_from_table
from stages.common.rosbag import messages as msg
from stages.common.rosbag.mapping import MAPPING_FILE, read_mapping

SAMPLE_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class Capture:
    """What one capture measured, read and checked before anything is written."""

    sample_id: str
    session: str
    stamp: int  # ns
    image_logged: int  # the image message's recording time (ns), to fetch it
    image_stamp: int
    row: dict[str, Any]  # the captures row, less the image's columns


class BagReplay:
    """Implements ``stages.acquire.backend.Testbed`` for a ROS 2 bag and its mapping."""

    def __init__(self, source: Path, workspace: Workspace) -> None:
        self.source, self.workspace = source, workspace
        if not source.is_dir():
            raise FileError(source, "not a directory: give the bag's folder (metadata.yaml and its files)")
        self.mapping = read_mapping(source / MAPPING_FILE)
        self.pattern = (pattern_from_table(self.mapping.pattern, str(self.mapping.path))
                        if self.mapping.pattern is not None else None)
        self._read()
        self.captures = self._captures()

    # -- the one pass over the bag ---------------------------------------------------------
    def _reader(self) -> Any:
        from rosbags.highlevel import AnyReader

        return AnyReader([self.source], default_typestore=msg.typestore())

    def _unreadable(self, error: Exception) -> FileError:
        """rosbags' own errors say what is wrong with the bag's files."""
        return FileError(self.source, f"not a readable bag ({type(error).__name__}: {error})")

    def _topics(self, reader: Any) -> list[Any]:
        """The mapped topics' connections (and /tf's), each checked for its message type."""
        m = self.mapping
        wanted: list[tuple[str, str, tuple[str, ...]]] = [(m.camera_topic, "camera.topic", msg.IMAGE_TYPES)]
        if m.info_topic:
            wanted.append((m.info_topic, "camera.info_topic", (msg.CAMERA_INFO,)))
        if m.trigger_topic:
            wanted.append((m.trigger_topic, "captures.trigger_topic", (msg.TIME_REFERENCE,)))
        for name, robot in m.robots.items():
            if robot.joints:
                wanted.append((robot.joints_topic, f"robots.{name}.joints_topic", (msg.JOINT_STATE,)))
        if m.rail:
            wanted.append((m.rail[0], "rail.topic", (msg.JOINT_STATE,)))
        for body, source in m.bodies.items():
            if source.topic:
                key = "camera_body" if body == "camrb" else "target_body"
                wanted.append((source.topic, f"motion_capture.{key}.topic", (msg.POSE_STAMPED,)))
        present: dict[str, list[Any]] = {}
        for connection in reader.connections:  # every publisher's connection of a topic
            present.setdefault(connection.topic, []).append(connection)
        for topic, key, types in wanted:
            if topic not in present:
                raise FileError(m.path, f"key {key}: topic {topic} is not in the bag {self.source} (it has: "
                                        f"{', '.join(sorted(present)) or 'no topics'})")
            wrong = sorted({c.msgtype for c in present[topic]} - set(types))
            if wrong:
                raise FileError(m.path, f"key {key}: topic {topic} carries {', '.join(wrong)}, expected "
                                        f"{' or '.join(types)}")
        topics = {topic for topic, _, _ in wanted} | {"/tf", "/tf_static"}
        return [c for c in reader.connections if c.topic in topics and (c.topic not in ("/tf", "/tf_static")
                                                                       or c.msgtype == msg.TF)]

    def _read(self) -> None:
        m = self.mapping
        self.joints = {name: Series(f"{r.joints_topic} joints of the {name} robot", False)
                       for name, r in m.robots.items() if r.joints}
        self.rail = Series(f"{m.rail[0]} joint {m.rail[1]}", False) if m.rail else None
        self.bodies = {body: Series(f"{s.topic}", True) for body, s in m.bodies.items() if s.topic}
        self.tree, self.images, self.triggers = FrameTree(), [], []
        self.info: Any = None
        try:
            with self._reader() as reader:
                connections = self._topics(reader)
                self.start = int(reader.start_time)
                for connection, logged, raw in reader.messages(connections=connections):
                    message = reader.deserialize(raw, connection.msgtype)
                    self._take(connection.topic, connection.msgtype, message, int(logged))
        except FileError:
            raise
        except Exception as error:  # noqa: BLE001 - any of rosbags' readers' errors: the bag is damaged
            raise self._unreadable(error) from None
        # /tf's edges are checked where a mapped chain uses them (FrameTree.chain)
        for series in [*self.joints.values(), *([self.rail] if self.rail else []), *self.bodies.values()]:
            problem = series.clock_problem(m.clock_jump_s)
            if problem:
                raise FileError(self.source, problem)
        if not self.images:
            raise FileError(self.source, f"no image on {m.camera_topic}")

    def _take(self, topic: str, msgtype: str, message: Any, logged: int) -> None:
        """One message into its series."""
        m = self.mapping
        if msgtype in msg.IMAGE_TYPES and topic == m.camera_topic:
            self._image(message, logged, msgtype)
        elif topic == m.info_topic and self.info is None:
            self.info = message
        elif topic == m.trigger_topic:
            self.triggers.append((int(message.time_ref.sec) * NS + int(message.time_ref.nanosec), str(message.source)))
        elif msgtype == msg.TF:
            for transform in message.transforms:
                stamp = msg.stamp_ns(transform.header)
                problem = self._pose_problem(topic, stamp, transform.transform.translation,
                                             transform.transform.rotation)
                pose = problem or msg.pose_matrix(transform.transform.translation, transform.transform.rotation)
                self.tree.add(transform.header.frame_id, transform.child_frame_id, pose, stamp, logged,
                              topic == "/tf_static", topic)
        elif msgtype == msg.POSE_STAMPED:
            for body, source in m.bodies.items():
                if source.topic == topic:
                    self._body_frame(topic, message.header.frame_id)
                    self.bodies[body].add(msg.stamp_ns(message.header), self._checked_pose(
                        topic, msg.stamp_ns(message.header), message.pose.position, message.pose.orientation), logged)
        if msgtype == msg.JOINT_STATE:
            self._joint_state(topic, message, logged)

    def _body_frame(self, topic: str, frame_id: str) -> None:
        world = self.mapping.mocap_world_frame
        if world and frame_id and frame_id != world:
            raise FileError(self.source, f"{topic}: poses in frame {frame_id!r}, but the mapping's "
                                         f"motion_capture.world_frame is {world!r}")

    @staticmethod
    def _pose_problem(topic: str, stamp: int, position: Any, orientation: Any) -> str | None:
        norm = msg.quaternion_norm(orientation)
        if not abs(norm - 1.0) <= 1e-3:
            return f"{topic}, stamp {seconds(stamp)} s: quaternion norm {norm:.6f} is not 1"
        values = [position.x, position.y, position.z]
        if not np.all(np.isfinite(values)) or max(abs(v) for v in values) > 1000.0:
            return (f"{topic}, stamp {seconds(stamp)} s: position {values} is not a plausible position in metres "
                    "(ROS poses are in m)")
        return None

    def _checked_pose(self, topic: str, stamp: int, position: Any, orientation: Any) -> np.ndarray:
        problem = self._pose_problem(topic, stamp, position, orientation)
        if problem:
            raise FileError(self.source, problem)
        return msg.pose_matrix(position, orientation)

    def _joint_state(self, topic: str, message: Any, logged: int) -> None:
        names = list(message.name)
        mapped = {j for r in self.mapping.robots.values() if r.joints_topic == topic for j in r.joints}
        if self.mapping.rail and self.mapping.rail[0] == topic:
            mapped.add(self.mapping.rail[1])
        if not mapped & set(names) or not len(message.position):  # another publisher's, or efforts only
            return
        if len(message.position) != len(names):
            raise FileError(self.source, f"{topic}, stamp {seconds(msg.stamp_ns(message.header))} s: "
                                         f"{len(names)} names but {len(message.position)} positions")
        at = {name: i for i, name in enumerate(names)}
        stamp = msg.stamp_ns(message.header)
        for name, robot in self.mapping.robots.items():
            if robot.joints_topic == topic and robot.joints and all(j in at for j in robot.joints):
                self.joints[name].add(stamp, np.array([message.position[at[j]] for j in robot.joints]), logged)
        if self.rail and self.mapping.rail[0] == topic and self.mapping.rail[1] in at:
            self.rail.add(stamp, np.array([message.position[at[self.mapping.rail[1]]]]), logged)

    def _image(self, message: Any, logged: int, msgtype: str) -> None:
        stamp = msg.stamp_ns(message.header)
        if msgtype == msg.IMAGE:
            if message.encoding not in msg.ENCODINGS:
                raise FileError(self.source, f"{self.mapping.camera_topic}, stamp {seconds(stamp)} s: encoding "
                                             f"{message.encoding!r} is not read (read: {', '.join(msg.ENCODINGS)})")
            size = (int(message.width), int(message.height))
        else:  # a compressed image's size from its header (another format's once decoded)
            size = msg.compressed_size(bytes(message.data[:65536]))
        self.images.append((stamp, logged, size))

    # -- the captures -------------------------------------------------------------------------
    def _capture_stamps(self) -> list[tuple[int, str, int, int]]:
        """(stamp, sample id or "", the image's recording time, the image's stamp) per capture."""
        images = sorted(self.images)
        stamps = [s for s, _, _ in images]
        if not self.mapping.trigger_topic:
            return [(s, "", logged, s) for s, logged, _ in images]
        out, taken = [], {}
        reach = int(self.mapping.trigger_window_s * NS)
        for stamp, name in sorted(self.triggers):
            i = int(np.argmin(np.abs(np.asarray(stamps) - stamp)))
            said = f"{self.mapping.trigger_topic}: trigger at {seconds(stamp)} s{f' ({name})' if name else ''}"
            if abs(stamps[i] - stamp) > reach:
                raise FileError(self.source, f"{said} has no image on {self.mapping.camera_topic} within "
                                             f"{reach / NS:g} s (captures.trigger_window_s)")
            if i in taken:
                raise FileError(self.source, f"{said} has the image at {seconds(stamps[i])} s, which the trigger at "
                                             f"{seconds(taken[i])} s has already: a frame was dropped")
            taken[i] = stamp
            out.append((stamp, name if self.mapping.trigger_names_samples else "", images[i][1], stamps[i]))
        if not out:
            raise FileError(self.source, f"no trigger on {self.mapping.trigger_topic}")
        return out

    def _captures(self) -> list[Capture]:
        m = self.mapping
        counts: dict[str, int] = {}
        first: dict[str, int] = {}
        out, seen = [], set()
        for stamp, name, logged, image_stamp in self._capture_stamps():
            session = m.session_at((stamp - self.start) / NS)
            if session is None:
                raise FileError(m.path, f"key captures.sessions: the capture at {seconds(stamp)} s "
                                        f"({(stamp - self.start) / NS:.3f} s after the bag's start) is in no window")
            sample_id = name or sample_ids.make(session, counts.get(session, 0))
            counts[session] = counts.get(session, 0) + 1
            if not SAMPLE_ID.fullmatch(sample_id) or sample_id in seen:
                raise FileError(self.source, f"{m.trigger_topic}: trigger at {seconds(stamp)} s names sample "
                                             f"{sample_id!r}: {'a duplicate' if sample_id in seen else 'not an id'}")
            seen.add(sample_id)
            first.setdefault(session, stamp)
            row = self._measured(sample_id, session, stamp, (stamp - first[session]) / NS)
            row["fixture"] = m.fixture_at((stamp - self.start) / NS)
            out.append(Capture(sample_id, session, stamp, logged, image_stamp, row))
        return out

    def _still(self, sample_id: str, stamp: int, series: Series, tolerance: float) -> np.ndarray:
        m = self.mapping
        window = Window(stamp, stamp - int(m.still_s * NS), stamp + int(m.exposure_s * NS))
        value = still_value(series, window, tolerance, m.tolerance_rad, int(m.max_message_gap_s * NS))
        if isinstance(value, str):
            raise FileError(self.source, f"capture {sample_id} at {seconds(stamp)} s: {value}")
        return value

    def _flange(self, sample_id: str, stamp: int, robot: str) -> np.ndarray:
        m = self.mapping
        chain = self.tree.chain(m.world_frame, m.robots[robot].flange_frame, m.clock_jump_s)
        if isinstance(chain, str):
            raise FileError(m.path, f"key robots.{robot}.flange_frame: {chain}")
        window = Window(stamp, stamp - int(m.still_s * NS), stamp + int(m.exposure_s * NS))
        pose = self.tree.pose(chain, window, m.tolerance_m, m.tolerance_rad, int(m.max_message_gap_s * NS))
        if isinstance(pose, str):
            raise FileError(self.source, f"capture {sample_id} at {seconds(stamp)} s: {pose}")
        return pose

    def _body(self, body: str, stamp: int) -> np.ndarray | None:
        m = self.mapping
        gap = int(m.max_gap_s * NS)
        if body in self.bodies:
            return nearest_value(self.bodies[body], stamp, gap)
        chain = self.tree.chain(m.mocap_world_frame or "", m.bodies[body].frame or "", m.clock_jump_s)
        if isinstance(chain, str):
            key = "camera_body" if body == "camrb" else "target_body"
            raise FileError(m.path, f"key motion_capture.{key}.frame: {chain}")
        return self.tree.pose_near(chain, stamp, gap)

    def _measured(self, sample_id: str, session: str, stamp: int, time_s: float) -> dict[str, Any]:
        """The captures row of one capture, less its image."""
        m = self.mapping
        poses = {"camee": np.eye(4), "targetee": np.eye(4)}
        for robot, body in (("camera", "camee"), ("target", "targetee")):
            if robot in m.robots:
                poses[body] = self._flange(sample_id, stamp, robot)
        joints = {name: self._still(sample_id, stamp, series, m.tolerance_rad)
                  for name, series in self.joints.items()}
        rail = None if self.rail is None else float(self._still(sample_id, stamp, self.rail, m.tolerance_m)[0])
        bodies = {body: self._body(body, stamp) if body in m.bodies else None for body in ("camrb", "targetrb")}
        return {
            "sample_id": sample_id, "session": session, "fixture": "fixed",
            **pose_columns("kuka_world_from_camee", poses["camee"]),
            **pose_columns("kuka_world_from_targetee", poses["targetee"]),
            "kuka_camera_joints_rad": joints.get("camera"), "kuka_target_joints_rad": joints.get("target"),
            "kuka_rail_m": rail, "capture_time_s": time_s, "move_s": None,
            **pose_columns("vicon_world_from_camrb", bodies["camrb"]),
            **pose_columns("vicon_world_from_targetrb", bodies["targetrb"]),
            "vicon_camrb_markers": None, "vicon_targetrb_markers": None,
            "vicon_targetrb_used": None, "vicon_targetrb_residual_m": None, "status": "ok",
        }

    # -- the Testbed interface ------------------------------------------------------------
    def samples(self) -> list[dict[str, Any]]:
        return [{"sample_id": c.sample_id, "session": c.session} for c in self.captures]

    def session(self) -> Session:
        m = self.mapping
        width, height = self._size()
        matrix = dist = None
        if self.info is not None:
            k = np.asarray(self.info.k, dtype=float).reshape(3, 3)
            matrix = k.tolist() if k[0, 0] > 0 else None
            dist = [float(v) for v in self.info.d] if len(self.info.d) else None
            if self.info.distortion_model not in ("", "plumb_bob", "rational_polynomial") and dist:
                raise FileError(self.source, f"{m.info_topic}: distortion model {self.info.distortion_model!r} "
                                             "(read: plumb_bob, rational_polynomial)")
        return Session("replay", "rosbag", m.sources, SessionCamera(width, height, matrix, dist),
                       self.pattern.to_json() if self.pattern else None, str(self.source),
                       {"camee": "camera flange" if "camera" in m.robots else "robot world K",
                        "targetee": "target flange" if "target" in m.robots else "robot world K"})

    def _size(self) -> tuple[int, int]:
        sizes = {size for _, _, size in self.images if size is not None}
        if self.info is not None and self.info.width > 0:
            sizes.add((int(self.info.width), int(self.info.height)))
        if len(sizes) > 1:
            raise FileError(self.source, f"{self.mapping.camera_topic}: images of several sizes {sorted(sizes)}")
        if sizes:
            return sizes.pop()
        from stages.common.image_io import decode_image

        data, suffix, _ = self._image_bytes(self.captures[0])
        height, width = decode_image(data, f"first{suffix}").shape[:2]
        return width, height

    def _image_bytes(self, capture: Capture) -> tuple[bytes, str, str | None]:
        """The capture's image as a file's bytes (PNG, or the compressed format it came in),
        its suffix, and what was converted (a raw image's pixels to PNG; None: as recorded)."""
        try:
            found = self._fetch(capture)
        except FileError:
            raise
        except Exception as error:  # noqa: BLE001 - as in _read
            raise self._unreadable(error) from None
        if found is None:
            raise FileError(self.source, f"capture {capture.sample_id}: its image at "
                                         f"{seconds(capture.image_stamp)} s could not be read again")
        return found

    def _fetch(self, capture: Capture) -> tuple[bytes, str, str | None] | None:
        with self._reader() as reader:
            connection = next(c for c in reader.connections if c.topic == self.mapping.camera_topic)
            for _, _, raw in reader.messages(connections=[connection], start=capture.image_logged,
                                             stop=capture.image_logged + 1):
                message = reader.deserialize(raw, connection.msgtype)
                if msg.stamp_ns(message.header) != capture.image_stamp:
                    continue
                if connection.msgtype == msg.IMAGE:
                    return (encode_png(msg.raw_image_pixels(message)), ".png",
                            f"sensor_msgs/Image {message.encoding} -> png (lossless)")
                data = bytes(message.data)
                if data.startswith(PNG_SIGNATURE):
                    return data, ".png", None
                return data, ".jpg" if data[:3] == b"\xff\xd8\xff" else f".{message.format.split(';')[0].strip()}", None
        return None

    def capture(self, sample: dict[str, Any]) -> CaptureRecord:
        capture = next(c for c in self.captures if c.sample_id == sample["sample_id"])
        relpath = self.workspace.image_relpath(capture.session, capture.sample_id)
        data, suffix, raw = self._image_bytes(capture)
        staged = self.workspace.resolve(relpath).with_suffix(f".bag{suffix}")
        write_bytes_atomic(staged, data)
        try:
            stored, converted = ingest_image(staged, self.workspace.resolve(relpath))
        finally:
            staged.unlink(missing_ok=True)
        image_path = Path(relpath).with_suffix(stored.suffix).as_posix()
        source_image = f"{self.mapping.camera_topic}@{capture.image_stamp}"
        return CaptureRecord({**capture.row, "image_path": image_path, "source_image": source_image,
                              "image_conversion": raw or converted}, None)

