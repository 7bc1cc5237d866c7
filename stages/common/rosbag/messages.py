"""ROS 2 messages as this pipeline reads and writes them, through ``rosbags`` (no ROS
installed): the message definitions of ROS 2 Humble (those used here are the same in
Iron and Jazzy), stamps, poses and images. Units and frames are the message types':
``JointState`` positions in rad (revolute) or m (prismatic), poses and transforms in m
with quaternions (x, y, z, w), images by their ``encoding`` or their compressed bytes.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

from stages.common import geometry as g

JOINT_STATE = "sensor_msgs/msg/JointState"
TF = "tf2_msgs/msg/TFMessage"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TIME_REFERENCE = "sensor_msgs/msg/TimeReference"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
#: raw ``sensor_msgs/Image`` encodings read: channels, numpy type, whether the channels are RGB order
ENCODINGS = {"mono8": (1, np.uint8, False), "8UC1": (1, np.uint8, False), "mono16": (1, np.uint16, False),
             "16UC1": (1, np.uint16, False), "bgr8": (3, np.uint8, False), "8UC3": (3, np.uint8, False),
             "rgb8": (3, np.uint8, True), "bgr16": (3, np.uint16, False), "rgb16": (3, np.uint16, True),
             "bgra8": (4, np.uint8, False), "rgba8": (4, np.uint8, True)}


@cache
def typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header``'s stamp in nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def time_msg(ns: int) -> Any:
    return typestore().types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def header(ns: int, frame_id: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=time_msg(ns), frame_id=frame_id)


def pose_matrix(position: Any, orientation: Any) -> np.ndarray:
    """(4, 4) from a ``Point``/``Vector3`` (m) and a ``Quaternion`` (x, y, z, w)."""
    q = [orientation.w, orientation.x, orientation.y, orientation.z]
    return g.transform_from_qt(np.asarray(q) / np.linalg.norm(q), [position.x, position.y, position.z])


def quaternion_norm(orientation: Any) -> float:
    return float(np.linalg.norm([orientation.w, orientation.x, orientation.y, orientation.z]))


def _quaternion(matrix: np.ndarray) -> Any:
    w, x, y, z = g.matrix_to_quat(matrix[:3, :3])
    return typestore().types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w))


def pose_stamped(ns: int, frame_id: str, matrix: np.ndarray) -> Any:
    types = typestore().types
    position = types["geometry_msgs/msg/Point"](x=float(matrix[0, 3]), y=float(matrix[1, 3]), z=float(matrix[2, 3]))
    return types[POSE_STAMPED](header=header(ns, frame_id),
                               pose=types["geometry_msgs/msg/Pose"](position=position, orientation=_quaternion(matrix)))


def transform_stamped(ns: int, parent: str, child: str, matrix: np.ndarray) -> Any:
    types = typestore().types
    translation = types["geometry_msgs/msg/Vector3"](x=float(matrix[0, 3]), y=float(matrix[1, 3]),
                                                     z=float(matrix[2, 3]))
    return types["geometry_msgs/msg/TransformStamped"](
        header=header(ns, parent), child_frame_id=child,
        transform=types["geometry_msgs/msg/Transform"](translation=translation, rotation=_quaternion(matrix)))


def tf_message(transforms: list[Any]) -> Any:
    return typestore().types[TF](transforms=transforms)


def joint_state(ns: int, names: list[str], positions: list[float]) -> Any:
    return typestore().types[JOINT_STATE](header=header(ns, ""), name=list(names),
                                          position=np.asarray(positions, dtype=np.float64),
                                          velocity=np.zeros(0), effort=np.zeros(0))


def compressed_image(ns: int, frame_id: str, data: bytes, fmt: str) -> Any:
    return typestore().types[COMPRESSED_IMAGE](header=header(ns, frame_id), format=fmt,
                                               data=np.frombuffer(data, dtype=np.uint8))


def time_reference(ns: int, source: str) -> Any:
    """A trigger: the exposure's instant in ``time_ref`` (and the header), the sample id in ``source``."""
    return typestore().types[TIME_REFERENCE](header=header(ns, ""), time_ref=time_msg(ns), source=source)


def camera_info(ns: int, frame_id: str, width: int, height: int, matrix: list[list[float]] | None,
                dist: list[float] | None) -> Any:
    types = typestore().types
    k = np.zeros(9) if matrix is None else np.asarray(matrix, dtype=np.float64).reshape(9)
    projection = np.zeros(12)
    projection[[0, 1, 2, 4, 5, 6, 8, 9, 10]] = k
    roi = types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return types[CAMERA_INFO](
        header=header(ns, frame_id), height=height, width=width, distortion_model="plumb_bob" if dist else "",
        d=np.asarray(dist or [], dtype=np.float64), k=k, r=np.eye(3).reshape(9), p=projection,
        binning_x=0, binning_y=0, roi=roi)


def raw_image_pixels(message: Any) -> np.ndarray:
    """(H, W) or (H, W, 3) BGR pixels of a ``sensor_msgs/Image`` (alpha dropped); ValueError
    naming an encoding this reader does not take."""
    if message.encoding not in ENCODINGS:
        raise ValueError(f"encoding {message.encoding!r} (read: {', '.join(ENCODINGS)})")
    channels, dtype, rgb = ENCODINGS[message.encoding]
    item = np.dtype(dtype).newbyteorder(">" if message.is_bigendian else "<")
    row_items = message.step // item.itemsize
    if message.step % item.itemsize or row_items < message.width * channels or \
            len(message.data) < message.step * message.height:
        raise ValueError(f"step {message.step} and {len(message.data)} bytes do not hold {message.height} rows of "
                         f"{message.width} x {channels} {np.dtype(dtype).name}")
    flat = np.frombuffer(bytes(message.data[:message.step * message.height]), dtype=item)
    pixels = flat.reshape(message.height, row_items)[:, :message.width * channels].astype(dtype)
    pixels = pixels.reshape(message.height, message.width, channels)
    if channels == 1:
        return pixels[:, :, 0]
    pixels = pixels[:, :, :3]
    return np.ascontiguousarray(pixels[:, :, ::-1] if rgb else pixels)


def compressed_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG's or a baseline/progressive JPEG's header; None for
    another format (its size is checked once decoded)."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data[:2] != b"\xff\xd8":
        return None
    at = 2
    while at + 9 < len(data):
        if data[at] != 0xFF:
            return None
        marker, length = data[at + 1], int.from_bytes(data[at + 2:at + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # a start of frame
            return int.from_bytes(data[at + 7:at + 9], "big"), int.from_bytes(data[at + 5:at + 7], "big")
        at += 2 + length
    return None
