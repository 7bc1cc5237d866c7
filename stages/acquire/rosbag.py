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
from stages.acquire.bag_contents import BagContents
from stages.acquire.bag_streams import NS, Series, Window, nearest_value, seconds, still_value
from stages.common.geometry import pose_columns
from stages.common.image_io import IMAGE_SUFFIXES, encode_png, ingest_image
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


class BagReplay(BagContents):
    """Implements ``stages.acquire.backend.Testbed`` for a ROS 2 bag and its mapping: the
    bag's contents (``BagContents``) made captures."""

    def __init__(self, source: Path, workspace: Workspace) -> None:
        if not source.is_dir():
            raise FileError(source, "not a directory: give the bag's folder (metadata.yaml and its files)")
        mapping = read_mapping(source / MAPPING_FILE)
        self.workspace = workspace
        self.pattern = pattern_from_table(mapping.pattern, str(mapping.path)) if mapping.pattern is not None else None
        super().__init__(source, mapping)
        self.captures = self._captures()

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
                if data[:3] == b"\xff\xd8\xff":
                    return data, ".jpg", None
                suffix = f".{message.format.split(';')[0].strip().lower()}"  # the bag's own word: checked
                if suffix not in IMAGE_SUFFIXES:
                    raise FileError(self.source, f"{self.mapping.camera_topic}, stamp {seconds(capture.image_stamp)} "
                                                 f"s: compressed format {message.format!r} is not read (read: PNG, "
                                                 f"JPEG, {', '.join(IMAGE_SUFFIXES)})")
                return data, suffix, None
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

