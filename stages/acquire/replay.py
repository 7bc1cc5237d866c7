"""Replay of a recorded testbed session (the format a real lab writes; see docs/user-guide.md).

```
session.toml   format_version = 1, length_unit = "mm" | "m", angle_unit = "deg" | "rad",
               euler = "ZYX" (KUKA A B C), sources = ["kuka", "vicon"],
               [setup] camera_on = "flange" | "world", target_on = "flange" | "world" (optional;
                       "world": that body stands still in the robot world and robot.csv has no
                       columns for it; with one robot the rail column is optional too)
               [camera] width, height, K (optional), dist (optional),
               [pattern] kind, size, square_m, marker_m, dictionary, target_from_pattern_q/_t (optional)
robot.csv      sample_id, session, rail, camee_x, camee_y, camee_z, camee_a, camee_b, camee_c,
               targetee_x, ..., targetee_c       (flange poses in the robot world, KUKA X Y Z A B C)
               optional column fixture: which model fixture (mount) was used (default "fixed")
               optional column time_s: the exposure's time in seconds since the session's start
               optional columns camera_j1..camera_j6, target_j1..target_j6: the robots' encoder
               readings (axis angles A1-A6, in angle_unit; all twelve or none), which let calibrate
               calibrate the arms themselves
mocap.csv      sample_id, body (camrb | targetrb), x, y, z, qw, qx, qy, qz, markers
               (optional; all zeros or NaN: not tracked; markers nan: not recorded)
images/<sample_id>.<png|bmp|tif|tiff|jpg|jpeg|exr>
```
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from manifests import Workspace
from manifests.schema import SESSIONS
from manifests.sidecars import Session, SessionCamera
from speedplus.errors import unknown_keys
from stages.acquire.backend import CaptureRecord
from stages.acquire.handeye import check_images, inside
from stages.acquire.ingest import (
    FileError,
    check_angles,
    check_finite,
    check_translation,
    number,
    read_csv,
    read_text,
)
from stages.common import geometry as g
from stages.common.geometry import pose_columns
from stages.common.image_io import IMAGE_SUFFIXES, ingest_image
from stages.common.patterns import pattern_from_table

BODY_COLUMNS = {body: [f"{body}_{axis}" for axis in ("x", "y", "z", "a", "b", "c")] for body in ("camee", "targetee")}
SETUP_BODIES = {"camera_on": "camee", "target_on": "targetee"}
SESSION_KEYS = {"format_version", "length_unit", "angle_unit", "euler", "sources", "setup", "camera", "pattern"}
SAMPLE_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
MOCAP_COLUMNS = ["sample_id", "body", "x", "y", "z", "qw", "qx", "qy", "qz", "markers"]
BODIES = ("camrb", "targetrb")
JOINT_COLUMNS = {robot: [f"{robot}_j{k}" for k in range(1, 7)] for robot in ("camera", "target")}


def read_session_toml(path: Path) -> dict[str, Any]:
    try:
        meta = tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as error:
        raise FileError(path, f"not valid TOML ({error})") from None
    unknown = sorted(set(meta) - SESSION_KEYS)
    if unknown:
        raise FileError(path, f"unknown key(s) or table(s) {unknown_keys(unknown, SESSION_KEYS)}")
    setup = meta.setdefault("setup", {})
    if not isinstance(setup, dict) or set(setup) - set(SETUP_BODIES):
        raise FileError(path, f"[setup] may hold camera_on and target_on only, got {setup!r}")
    for key in SETUP_BODIES:
        if setup.setdefault(key, "flange") not in ("flange", "world"):
            raise FileError(path, f"[setup] {key} must be flange or world, got {setup[key]!r}")
    if setup["camera_on"] == setup["target_on"] == "world":
        raise FileError(path, "[setup] camera_on and target_on are both world: nothing moves")
    if "pattern" in meta:
        meta["pattern"] = pattern_from_table(meta["pattern"], str(path))
    expected = {"length_unit": ("mm", "m"), "angle_unit": ("deg", "rad"), "euler": ("ZYX",)}
    for key, allowed in expected.items():
        if meta.get(key) not in allowed:
            raise FileError(path, f"{key} must be one of {', '.join(allowed)}, got {meta.get(key)!r}")
    sources = meta.get("sources", ["kuka"])
    if not isinstance(sources, list) or "kuka" not in sources or not set(sources) <= {"kuka", "vicon"}:
        raise FileError(path, f"sources must list kuka and optionally vicon, got {sources!r}")
    camera = meta.get("camera", {})
    if not isinstance(camera.get("width"), int) or not isinstance(camera.get("height"), int):
        raise FileError(path, "[camera] needs integer width and height")
    return meta


def _to_metres(value: float, unit: str) -> float:
    return value / 1000.0 if unit == "mm" else value


class SessionReplay:
    """Implements ``stages.acquire.backend.Testbed`` for a recorded session directory."""

    def __init__(self, source: Path, workspace: Workspace) -> None:
        self.source, self.workspace = source, workspace
        if not source.is_dir():
            raise FileError(source, "not a directory")
        self.meta = read_session_toml(source / "session.toml")
        self.moving = [body for key, body in SETUP_BODIES.items() if self.meta["setup"][key] == "flange"]
        self.robot = self._read_robot(source / "robot.csv")
        self.mocap = self._read_mocap(source / "mocap.csv") if "vicon" in self.meta.get("sources", []) else {}
        self.images = {sample_id: self._image(sample_id) for sample_id in self.robot}
        camera = self.meta["camera"]
        check_images(list(self.images.values()), {"width": camera["width"], "height": camera["height"]},
                     source / "session.toml")

    def _image(self, sample_id: str) -> Path:
        """The recorded image of a sample: images/<sample_id> with one of the readable suffixes."""
        found = [self.source / "images" / f"{sample_id}{suffix}" for suffix in IMAGE_SUFFIXES
                 if (self.source / "images" / f"{sample_id}{suffix}").is_file()]
        if not found:
            raise FileError(self.source / "robot.csv", f"sample {sample_id}: image images/{sample_id}.png "
                                                         f"(or {', '.join(IMAGE_SUFFIXES[1:])}) is missing")
        if len(found) > 1:
            raise FileError(self.source / "robot.csv", f"sample {sample_id}: several images "
                                                         f"({', '.join(p.name for p in found)}); keep one")
        return inside(self.source, str(found[0].relative_to(self.source)), self.source / "robot.csv", "image")

    def _read_robot(self, path: Path) -> dict[str, dict[str, Any]]:
        length, angle = self.meta["length_unit"], self.meta["angle_unit"]
        robot: dict[str, dict[str, Any]] = {}
        required = ["sample_id", "session"] + [c for body in self.moving for c in BODY_COLUMNS[body]]
        rows = read_csv(path, required + (["rail"] if len(self.moving) == 2 else []))
        header = set(rows[0][1]) if rows else set()
        still = [c for body in BODY_COLUMNS if body not in self.moving for c in BODY_COLUMNS[body] if c in header]
        if still:
            raise FileError(path, f"column(s) {', '.join(still)} given, but session.toml [setup] says that body "
                                    "stands still in the robot world")
        positions: dict[str, list[np.ndarray]] = {body: [] for body in self.moving}
        labels: list[str] = []
        for line, row in rows:
            sample_id = (row["sample_id"] or "").strip()
            where = f"line {line} (sample_id {sample_id})"
            if not sample_id:
                raise FileError(path, f"line {line}: empty sample_id")
            if not SAMPLE_ID.fullmatch(sample_id):
                raise FileError(path, f"line {line}, column sample_id: {sample_id!r} must be letters, digits, "
                                        "'_', '-' or '.' (it names the image file; no paths)")
            if sample_id in robot:
                raise FileError(path, f"{where}: duplicate sample_id (first at line {robot[sample_id]['line']})")
            if row["session"] not in SESSIONS:
                raise FileError(path, f"{where}, column session: expected one of {', '.join(SESSIONS)}, "
                                        f"got {row['session']!r}")
            poses = {body: np.eye(4) for body in BODY_COLUMNS}
            for body in self.moving:
                values = np.array([number(path, line, row, f"{body}_{axis}") for axis in "xyzabc"])
                check_finite(path, f"{where}, {body}", values)
                check_angles(path, f"{where}, {body}", values[3:], angle)
                positions[body].append(values[:3])
                xyz_mm = values[:3] * (1.0 if length == "mm" else 1000.0)
                abc_deg = values[3:] if angle == "deg" else np.degrees(values[3:])
                poses[body] = g.kuka_to_transform(np.concatenate([xyz_mm, abc_deg]))
            labels.append(where)
            rail = None
            if "rail" in row:
                rail = number(path, line, row, "rail")
                check_finite(path, f"{where}, rail", np.array([rail]))
            fixture = (row.get("fixture") or "fixed").strip()
            time_s = None
            if "time_s" in row:
                time_s = number(path, line, row, "time_s")
                check_finite(path, f"{where}, time_s", np.array([time_s]))
            robot[sample_id] = {"line": line, "session": row["session"], "fixture": fixture, "time_s": time_s,
                                "rail_m": None if rail is None else _to_metres(rail, length), **poses,
                                **self._joints(path, line, where, row, angle)}
        if not robot:
            raise FileError(path, "no samples")
        for body, values in positions.items():
            check_translation(path, f"{body} position", np.array(values), length, labels)
        return robot

    def _joints(self, path: Path, line: int, where: str, row: dict[str, Any], angle: str) -> dict[str, Any]:
        """The encoder readings of a robot.csv row in radians, or None when not recorded."""
        columns = [c for names in JOINT_COLUMNS.values() for c in names]
        present = [c for c in columns if c in row]
        if not present:
            return {"camera_joints_rad": None, "target_joints_rad": None}
        if len(self.moving) < 2:
            raise FileError(path, f"encoder readings ({columns[0]}..{columns[-1]}) need both robots: the arm "
                                    "model is the testbed's pair of KUKA arms on their rail")
        missing = [c for c in columns if c not in row]
        if missing:
            raise FileError(path, f"encoder readings need all of {columns[0]}..{columns[-1]}; "
                                    f"missing column(s) {', '.join(missing)}")
        out = {}
        for robot, names in JOINT_COLUMNS.items():
            values = np.array([number(path, line, row, c) for c in names])
            check_finite(path, f"{where}, {robot} joints", values)
            out[f"{robot}_joints_rad"] = values if angle == "rad" else np.radians(values)
        return out

    def _read_mocap(self, path: Path) -> dict[tuple[str, str], dict[str, Any]]:
        length = self.meta["length_unit"]
        mocap: dict[tuple[str, str], dict[str, Any]] = {}
        positions, labels = [], []
        for line, row in read_csv(path, MOCAP_COLUMNS):
            sample_id, body = (row["sample_id"] or "").strip(), (row["body"] or "").strip()
            where = f"line {line} (sample_id {sample_id}, body {body})"
            if sample_id not in self.robot:
                raise FileError(path, f"{where}: sample_id not in robot.csv")
            if body not in BODIES:
                raise FileError(path, f"{where}, column body: expected camrb or targetrb")
            if (sample_id, body) in mocap:
                raise FileError(path, f"{where}: duplicate row")
            values = np.array([number(path, line, row, c) for c in ("x", "y", "z", "qw", "qx", "qy", "qz")])
            markers = number(path, line, row, "markers")
            # a motion-capture system reports an untracked body as zeros or NaN: missing, not an error
            untracked = (not np.all(np.isfinite(values))) or np.allclose(values, 0.0)
            pose = None
            if not untracked:
                norm = np.linalg.norm(values[3:])
                if abs(norm - 1.0) > 1e-3:
                    raise FileError(path, f"{where}: quaternion norm {norm:.6f} is not 1")
                positions.append(values[:3])
                labels.append(where)
                pose = g.transform_from_qt(values[3:], [_to_metres(v, length) for v in values[:3]])
            count = None if not math.isfinite(markers) else int(markers)  # nan: not recorded
            mocap[(sample_id, body)] = {"pose": pose, "markers": count}
        if positions:
            check_translation(path, "rigid-body position", np.array(positions), length, labels)
        return mocap

    def samples(self) -> list[dict[str, Any]]:
        return [{"sample_id": sample_id, "session": row["session"]} for sample_id, row in self.robot.items()]

    def session(self) -> Session:
        camera = self.meta["camera"]
        pattern = self.meta.get("pattern")
        setup = self.meta["setup"]
        sources = tuple(sorted(self.meta.get("sources", ["kuka"]), key=("kuka", "vicon").index))
        return Session("replay", "session", sources,
                       SessionCamera(camera["width"], camera["height"], camera.get("K"), camera.get("dist")),
                       pattern.to_json() if pattern else None, str(self.source),
                       {"camee": "camera flange" if setup["camera_on"] == "flange" else "robot world K",
                        "targetee": "target flange" if setup["target_on"] == "flange" else "robot world K"})

    def capture(self, sample: dict[str, Any]) -> CaptureRecord:
        sample_id = sample["sample_id"]
        robot = self.robot[sample_id]
        relpath = self.workspace.image_relpath(robot["session"], sample_id)
        stored, converted = ingest_image(self.images[sample_id], self.workspace.resolve(relpath))
        image_path = Path(relpath).with_suffix(stored.suffix).as_posix()
        empty = {"pose": None, "markers": None}
        camera_body = self.mocap.get((sample_id, "camrb"), empty)
        target_body = self.mocap.get((sample_id, "targetrb"), empty)
        captures = {
            "sample_id": sample_id, "session": robot["session"], "fixture": robot["fixture"],
            "image_path": image_path,
            "source_image": self.images[sample_id].relative_to(self.source).as_posix(), "image_conversion": converted,
            **pose_columns("kuka_world_from_camee", robot["camee"]),
            **pose_columns("kuka_world_from_targetee", robot["targetee"]),
            "kuka_camera_joints_rad": robot["camera_joints_rad"], "kuka_target_joints_rad": robot["target_joints_rad"],
            "kuka_rail_m": robot["rail_m"], "capture_time_s": robot["time_s"],
            "move_s": None,
            **pose_columns("vicon_world_from_camrb", camera_body["pose"]),
            **pose_columns("vicon_world_from_targetrb", target_body["pose"]),
            "vicon_camrb_markers": camera_body["markers"], "vicon_targetrb_markers": target_body["markers"],
            "vicon_targetrb_used": None, "vicon_targetrb_residual_m": None, "status": "ok",
        }
        return CaptureRecord(captures, None)
