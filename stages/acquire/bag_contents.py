"""The messages of a ROS 2 bag that its mapping names, read in one pass
(``stages/acquire/rosbag.py`` makes its captures of them): each arm's joints, the rail,
the motion-capture bodies as time series (``bag_streams.py``), /tf and /tf_static as a
frame tree, the camera's images (stamp, recording time, size), the triggers and the camera
info. Units and frames are the messages' own (``stages/common/rosbag/messages.py``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from speedplus.errors import FileError
from stages.acquire.bag_streams import NS, FrameTree, Series, seconds
from stages.common.rosbag import messages as msg
from stages.common.rosbag.mapping import BagMapping


class BagContents:
    """A bag's mapped messages, read and checked (``FileError`` naming the topic, the stamp
    or the mapping's key)."""

    def __init__(self, source: Path, mapping: BagMapping) -> None:
        self.source, self.mapping = source, mapping
        self._read()

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
