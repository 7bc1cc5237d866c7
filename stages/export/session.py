"""``export --format session``: a workspace's captures in the layout a lab's logger writes
and ``acquire --backend replay --format session`` reads (stages/acquire/replay.py, whose
docstring is the format): ``session.toml``, ``robot.csv`` (the controllers' flange poses as
KUKA X Y Z A B C in mm and degrees, the rail in mm, the encoder readings in degrees),
``mocap.csv`` (rigid bodies in mm; an untracked body as zeros) and ``images/``.

Replaying the export gives the captures back: the same images (byte for byte), the same
poses, readings, rail and times to the precision the text keeps (measured on the smoke
run: 5e-16 m and rad, through KUKA's Euler angles). Not carried: which markers each
motion-capture fit used and its residual, and each move's duration, which a logger does
not record (replay leaves them null). It is the recording a lab would hand over, and the
layout and units its own logger must write.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from manifests.files import write_bytes_atomic
from manifests.sidecars import Session
from stages.common import geometry as g
from stages.export.robot import csv_text

JOINT_COLUMNS = [*(f"camera_j{k}" for k in range(1, 7)), *(f"target_j{k}" for k in range(1, 7))]
MOCAP_COLUMNS = ["sample_id", "body", "x", "y", "z", "qw", "qx", "qy", "qz", "markers"]


def still(session: Session) -> list[str]:
    """The bodies (camee, targetee) that stand still in the robot world in this session."""
    return [body for body, frame in (session.frames or {}).items() if frame == "robot world K"]


def session_toml(session: Session) -> str:
    """``session.toml`` of the recording: mm and degrees, KUKA's ZYX Euler angles."""
    camera: dict[str, Any] = {"width": session.camera.width, "height": session.camera.height}
    if session.camera.camera_matrix is not None:
        camera["K"] = [list(row) for row in session.camera.camera_matrix]
    if session.camera.dist is not None:
        camera["dist"] = list(session.camera.dist)
    document: dict[str, Any] = {"format_version": 1, "length_unit": "mm", "angle_unit": "deg", "euler": "ZYX",
                                "sources": list(session.sources), "camera": camera}
    if still(session):
        document["setup"] = {"camera_on": "world" if "camee" in still(session) else "flange",
                             "target_on": "world" if "targetee" in still(session) else "flange"}
    if session.pattern is not None:
        document["pattern"] = {key: list(value) if isinstance(value, tuple | list) else value
                               for key, value in session.pattern.items()}
    return tomli_w.dumps(document)


def _kuka(q: Any, t: Any) -> list[float]:
    return [float(v) for v in g.transform_to_kuka(g.transform_from_qt(q, t))]


def robot_rows(captures: list[dict[str, Any]], standing: list[str]) -> tuple[list[str], list[list[Any]]]:
    """``robot.csv``: one row per capture (no columns for a body ``standing`` still), with the
    time, the rail and the encoder readings where every capture has them."""
    joints = all(row["kuka_camera_joints_rad"] is not None and row["kuka_target_joints_rad"] is not None
                 for row in captures)
    timed = all(row["capture_time_s"] is not None for row in captures)
    rail = all(row["kuka_rail_m"] is not None for row in captures)
    bodies = [body for body in ("camee", "targetee") if body not in standing]
    header = ["sample_id", "session", "fixture", *(["time_s"] if timed else []), *(["rail"] if rail else []),
              *(f"{body}_{a}" for body in bodies for a in "xyzabc"), *(JOINT_COLUMNS if joints else [])]
    rows = []
    for row in captures:
        values = [row["sample_id"], row["session"], row["fixture"]]
        values += [repr(float(row["capture_time_s"]))] if timed else []
        values += [repr(float(row["kuka_rail_m"]) * 1000.0)] if rail else []
        for body in bodies:
            values += [repr(v) for v in _kuka(row[f"kuka_world_from_{body}_q"], row[f"kuka_world_from_{body}_t"])]
        if joints:
            values += [repr(float(v)) for v in np.degrees(row["kuka_camera_joints_rad"])]
            values += [repr(float(v)) for v in np.degrees(row["kuka_target_joints_rad"])]
        rows.append(values)
    return header, rows


def mocap_rows(captures: list[dict[str, Any]]) -> list[list[Any]]:
    """``mocap.csv``: both rigid bodies of every capture (zeros: not tracked)."""
    rows = []
    for row in captures:
        for body, column in (("camrb", "vicon_world_from_camrb"), ("targetrb", "vicon_world_from_targetrb")):
            q, t = row[f"{column}_q"], row[f"{column}_t"]
            pose = [0.0] * 7 if q is None else [*(float(v) * 1000.0 for v in t), *(float(v) for v in q)]
            markers = row[f"vicon_{body}_markers"]
            rows.append([row["sample_id"], body, *(repr(v) for v in pose), "nan" if markers is None else markers])
    return rows


def write_tables(out: Path, session: Session, captures: list[dict[str, Any]]) -> None:
    """``session.toml``, ``robot.csv`` and (with motion capture) ``mocap.csv`` in ``out``."""
    write_bytes_atomic(out / "session.toml", session_toml(session).encode())
    write_bytes_atomic(out / "robot.csv", csv_text(*robot_rows(captures, still(session))).encode())
    if "vicon" in session.sources:
        write_bytes_atomic(out / "mocap.csv", csv_text(MOCAP_COLUMNS, mocap_rows(captures)).encode())


def image_file(row: dict[str, Any]) -> str:
    """Where a capture's image goes in the export: ``images/<sample_id><suffix>``."""
    return f"images/{row['sample_id']}{Path(row['image_path']).suffix}"
