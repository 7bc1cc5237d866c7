"""``export --format rosbag``: a workspace's captures as a ROS 2 bag (MCAP, written with
``rosbags``; ROS 2 Humble's message definitions) and the ``rosbag.toml`` that maps it
(``stages/common/rosbag/mapping.py``), in the layout a ROS 2 lab records:

- ``/joint_states`` (``sensor_msgs/JointState``): each arm's six joints (``camera_a1`` ..
  ``target_a6``, rad) and the rail (``rail``, m), where every capture has them;
- ``/tf``: ``world`` -> ``camera_flange`` and ``world`` -> ``target_flange`` (the flanges in
  the robot world, m);
- ``/mocap/camera/pose`` and ``/mocap/target/pose`` (``geometry_msgs/PoseStamped`` in frame
  ``mocap``), where motion capture tracked the body;
- ``/camera/image`` (``sensor_msgs/CompressedImage``: the workspace's PNG, byte for byte),
  ``/camera/camera_info`` once, and ``/camera/trigger`` (``sensor_msgs/TimeReference``: the
  exposure's instant, the sample id in ``source``).

The robots stand still from ``STILL_S`` before each capture to ``EXPOSURE_S`` after it:
their messages are written at both ends and at the stamp. Captures keep their
``capture_time_s`` where every one has it and they lie at least ``SPACING_S`` apart; else
they are laid ``SPACING_S`` apart. The calibration session comes first, then the dataset,
``SESSION_GAP_S`` later. A capture's model fixture (mount), which no ROS message carries,
is a window of the mapping's ``captures.fixtures``. Stamps count from ``EPOCH_NS``, so the same captures give the same
bytes. Replaying the bag (``acquire --backend replay --format rosbag --source OUT/bag``)
gives the captures back: the images byte for byte, the poses, joints and rail to 1e-9.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from manifests.sidecars import Session
from stages.common import geometry as g
from stages.common.rosbag import messages as msg
from stages.common.rosbag.mapping import (
    CAPTURE_DEFAULTS,
    BagMapping,
    BodySource,
    RobotTopics,
    SessionWindow,
    write_mapping,
)

NS = 1_000_000_000
EPOCH_NS = 1_750_000_000 * NS
STILL_S = 0.5
EXPOSURE_S = 0.01
SPACING_S = 2.0
SESSION_GAP_S = 10.0
#: the robots' messages about each capture, before its stand-still, at it and after its exposure
AROUND_S = (-(STILL_S + 0.05), 0.0, EXPOSURE_S + 0.05)
BAG_DIR = "bag"
TOPICS = {"image": "/camera/image", "info": "/camera/camera_info", "trigger": "/camera/trigger",
          "joints": "/joint_states", "camrb": "/mocap/camera/pose", "targetrb": "/mocap/target/pose"}
JOINTS = {robot: tuple(f"{robot}_a{k}" for k in range(1, 7)) for robot in ("camera", "target")}
FLANGES = {"camera": "camera_flange", "target": "target_flange"}
RAIL_JOINT = "rail"


def stamps(captures: list[dict[str, Any]]) -> list[int]:
    """Each capture's stamp (ns), calibration first (the module's docstring says how)."""
    out, start = [], EPOCH_NS + int(1.0 * NS)
    for session in ("calibration", "dataset"):
        rows = [r for r in captures if r["session"] == session]
        if not rows:
            continue
        times = [r["capture_time_s"] for r in rows]
        if any(t is None for t in times) or any(b - a < SPACING_S for a, b in zip(times, times[1:], strict=False)) \
                or times[0] < 0:
            times = [k * SPACING_S for k in range(len(rows))]
        out += [start + round(t * NS) for t in times]
        start = out[-1] + int(SESSION_GAP_S * NS)
    return out


def mapping(session: Session, captures: list[dict[str, Any]], at: list[int], out: Path) -> BagMapping:
    """The ``rosbag.toml`` of the bag written from these captures."""
    moving = [robot for robot, body in (("camera", "camee"), ("target", "targetee"))
              if (session.frames or {}).get(body, "flange") != "robot world K"]
    joints = all(r[f"kuka_{robot}_joints_rad"] is not None for r in captures for robot in moving)
    robots = {robot: RobotTopics(TOPICS["joints"] if joints else "", JOINTS[robot] if joints else (), FLANGES[robot])
              for robot in moving}
    rail = all(r["kuka_rail_m"] is not None for r in captures)
    start = min(at) + int(AROUND_S[0] * NS)
    calibration = [stamp for stamp, r in zip(at, captures, strict=True) if r["session"] == "calibration"]
    if calibration:
        split = (max(calibration) - start) / NS + SESSION_GAP_S / 2
        windows = (SessionWindow("calibration", 0.0, split), SessionWindow("dataset", split, 1e9))
    else:
        windows = (SessionWindow("dataset", 0.0, 1e9),)
    bodies = {body: BodySource(TOPICS[body], None) for body in ("camrb", "targetrb")} \
        if "vicon" in session.sources else {}
    # the export writes the robots at three instants about each capture, not at a controller's rate
    numbers = {**CAPTURE_DEFAULTS, "still_s": STILL_S, "exposure_s": EXPOSURE_S, "max_message_gap_s": STILL_S + 0.1,
               "trigger_window_s": 0.001}
    return BagMapping(out, tuple(session.sources), "world",
                      {"camera_on": "flange" if "camera" in moving else "world",
                       "target_on": "flange" if "target" in moving else "world"},
                      TOPICS["image"], TOPICS["info"], session.pattern, robots,
                      (TOPICS["joints"], RAIL_JOINT) if rail else None, "mocap" if bodies else None, bodies, 0.05,
                      TOPICS["trigger"], sessions=windows, fixtures=fixture_windows(captures, at, start),
                      trigger_names_samples=True, **numbers)


def fixture_windows(captures: list[dict[str, Any]], at: list[int], start: int) -> tuple[SessionWindow, ...]:
    """``captures.fixtures``: one window per run of consecutive captures on the same model
    fixture (none for "fixed"), from a fifth of ``SPACING_S`` before its first capture to a
    fifth after its last, so that windows of captures ``SPACING_S`` apart never touch."""
    runs: list[list[Any]] = []
    for stamp, row in sorted(zip(at, captures, strict=True), key=lambda item: item[0]):
        if runs and runs[-1][0] == row["fixture"]:
            runs[-1][2] = stamp
        else:
            runs.append([row["fixture"], stamp, stamp])
    margin = int(SPACING_S / 5 * NS)
    return tuple(SessionWindow(name, (first - margin - start) / NS, (last + margin - start) / NS)
                 for name, first, last in runs if name != "fixed")


def _robot_messages(row: dict[str, Any], stamp: int, plan: BagMapping) -> list[tuple[int, str, str, Any]]:
    """(stamp ns, topic, type, message) of the robots and motion capture about one capture."""
    out: list[tuple[int, str, str, Any]] = []
    for offset in AROUND_S:
        ns = stamp + round(offset * NS)
        names, positions = [], []
        for robot, arm in plan.robots.items():
            if arm.joints:
                names += list(arm.joints)
                positions += [float(v) for v in row[f"kuka_{robot}_joints_rad"]]
        if plan.rail:
            names.append(RAIL_JOINT)
            positions.append(float(row["kuka_rail_m"]))
        if names:
            out.append((ns, TOPICS["joints"], msg.JOINT_STATE, msg.joint_state(ns, names, positions)))
        transforms = [msg.transform_stamped(ns, plan.world_frame, FLANGES[robot], g.transform_from_qt(
            row[f"kuka_world_from_{body}_q"], row[f"kuka_world_from_{body}_t"]))
            for robot, body in (("camera", "camee"), ("target", "targetee")) if robot in plan.robots]
        out.append((ns, "/tf", msg.TF, msg.tf_message(transforms)))
        for body in plan.bodies:
            q, t = row[f"vicon_world_from_{body}_q"], row[f"vicon_world_from_{body}_t"]
            if q is not None:
                out.append((ns, TOPICS[body], msg.POSE_STAMPED,
                            msg.pose_stamped(ns, "mocap", g.transform_from_qt(q, t))))
    return out


def write_bag(out: Path, session: Session, captures: list[dict[str, Any]],
              image: Callable[[dict[str, Any]], tuple[bytes, str]]) -> list[int]:
    """Write ``out/bag`` (the MCAP bag and its ``rosbag.toml``) from ``captures`` (calibration
    first); ``image(row)`` gives a capture's file bytes and its format ("png", "exr").
    Written beside, then moved into place: a bag is one file, and an interrupted export
    leaves no half of one. Returns each capture's stamp (ns)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    at = stamps(captures)
    target, staging = out / BAG_DIR, out / ".partial"
    partial = staging / BAG_DIR
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    plan = mapping(session, captures, at, target)
    store = msg.typestore()
    with Writer(partial, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections: dict[str, Any] = {}
        for order, (row, stamp) in enumerate(zip(captures, at, strict=True)):
            data, fmt = image(row)
            batch = [*_robot_messages(row, stamp, plan),
                     (stamp, TOPICS["image"], msg.COMPRESSED_IMAGE, msg.compressed_image(stamp, "camera", data, fmt)),
                     (stamp, TOPICS["trigger"], msg.TIME_REFERENCE, msg.time_reference(stamp, row["sample_id"]))]
            if order == 0:
                camera = session.camera
                batch.append((stamp, TOPICS["info"], msg.CAMERA_INFO, msg.camera_info(
                    stamp, "camera", camera.width, camera.height, camera.camera_matrix, camera.dist)))
            # captures lie SPACING_S apart, so each one's messages follow the last one's in time
            for ns, topic, kind, message in sorted(batch, key=lambda m: m[0]):
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, kind, typestore=store)
                writer.write(connections[topic], ns, store.serialize_cdr(message, kind))
    write_mapping(partial, plan)
    shutil.rmtree(target, ignore_errors=True)
    partial.rename(target)
    staging.rmdir()
    return at

