"""Replay of Tabb & Ahmad Yousef's robot-world/hand-eye datasets (camera on the hand).

Layout: ``images/imageN.png`` (robot stop N), ``robot_cali.txt`` (the number of stops,
then one 4 x 4 ``hand_from_base`` matrix per stop, millimetres) and
``calibration_object.txt`` (``chess_width``, ``chess_height`` inner corners,
``chess_mm_width``/``chess_mm_height`` square size). Mapped onto DESIGN section 4: the
target T is the chessboard's OpenCV frame, the target flange T_K is the robot base (= the
robot world K) and the camera flange C_K is the hand. The only source is the robot.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from manifests import Workspace
from manifests.io import copy_atomic
from stages import geometry as g
from stages.acquire.backend import CaptureRecord
from stages.acquire.ingest import IngestError, check_rotation, check_translation_mm, read_text
from stages.geometry import pose_columns
from stages.patterns import PatternSpec


def read_calibration_object(path: Path) -> PatternSpec:
    values: dict[str, float] = {}
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 2:
            raise IngestError(path, f"line {number}: expected 'key value', got {line!r}")
        try:
            values[parts[0]] = float(parts[1])
        except ValueError:
            raise IngestError(path, f"line {number}: {parts[0]} must be a number, got {parts[1]!r}") from None
    for key in ("chess_width", "chess_height", "chess_mm_width", "chess_mm_height"):
        if key not in values:
            raise IngestError(path, f"missing {key}")
    if values["chess_mm_width"] != values["chess_mm_height"]:
        raise IngestError(path, "chess_mm_width and chess_mm_height differ; only square squares are supported")
    if values["chess_mm_width"] <= 0 or values["chess_width"] < 2 or values["chess_height"] < 2:
        raise IngestError(path, "the chessboard needs at least 2 x 2 inner corners and a positive square size")
    return PatternSpec("chessboard", (int(values["chess_width"]), int(values["chess_height"])),
                       values["chess_mm_width"] / 1000.0)


def read_robot_cali(path: Path) -> np.ndarray:
    """(N, 4, 4) ``hand_from_base`` in millimetres, validated."""
    tokens = read_text(path).split()
    try:
        numbers = [float(token) for token in tokens]
    except ValueError as error:
        raise IngestError(path, f"not a number: {error}") from None
    if not numbers or numbers[0] != int(numbers[0]) or numbers[0] < 1:
        raise IngestError(path, "must start with the number of robot stops")
    count = int(numbers[0])
    if len(numbers) - 1 != 16 * count:
        raise IngestError(path, f"announces {count} matrices but holds {(len(numbers) - 1) / 16:g}")
    matrices = np.array(numbers[1:]).reshape(count, 4, 4)
    for index, matrix in enumerate(matrices):
        where = f"matrix {index} (robot stop {index})"
        if not np.all(np.isfinite(matrix)):
            raise IngestError(path, f"{where}: non-finite value")
        if not np.allclose(matrix[3], [0, 0, 0, 1]):
            raise IngestError(path, f"{where}: last row must be 0 0 0 1, got {matrix[3].tolist()}")
        check_rotation(path, where, matrix[:3, :3])
    check_translation_mm(path, "matrix", matrices[:, :3, 3])
    return matrices


class TabbReplay:
    """Implements ``stages.acquire.backend.Testbed`` for a Tabb dataset directory."""

    def __init__(self, source: Path, workspace: Workspace) -> None:
        self.source, self.workspace = source, workspace
        if not source.is_dir():
            raise IngestError(source, "not a directory")
        self.pattern = read_calibration_object(source / "calibration_object.txt")
        self.hand_from_base_mm = read_robot_cali(source / "robot_cali.txt")
        missing = [f"images/image{i}.png" for i in range(len(self.hand_from_base_mm))
                   if not (source / "images" / f"image{i}.png").is_file()]
        if missing:
            raise IngestError(source, f"{len(missing)} image(s) missing, first {missing[0]}")

    def samples(self) -> list[dict[str, Any]]:
        return [{"sample_id": f"cal{i:06d}", "session": "calibration", "index": i}
                for i in range(len(self.hand_from_base_mm))]

    def session(self) -> dict[str, Any]:
        import cv2

        image = cv2.imread(str(self.source / "images" / "image0.png"), cv2.IMREAD_GRAYSCALE)
        return {"backend": "replay", "format": "tabb", "source": str(self.source), "sources": ["kuka"],
                "pattern": self.pattern.to_json(),
                "camera": {"K": None, "dist": None, "width": int(image.shape[1]), "height": int(image.shape[0])},
                "frames": {"camee": "hand", "targetee": "robot base", "world": "robot base",
                           "target": "chessboard (OpenCV)"}}

    def capture(self, sample: dict[str, Any]) -> CaptureRecord:
        index = sample["index"]
        hand_from_base = self.hand_from_base_mm[index].copy()
        hand_from_base[:3, 3] /= 1000.0  # millimetres, converted once, here
        image_path = self.workspace.image_relpath("calibration", sample["sample_id"])
        copy_atomic(self.source / "images" / f"image{index}.png", self.workspace.resolve(image_path))
        captures = {
            "sample_id": sample["sample_id"], "session": "calibration", "fixture": "fixed", "image_path": image_path,
            **pose_columns("kuka_world_from_camee", g.invert(hand_from_base)),
            **pose_columns("kuka_world_from_targetee", np.eye(4)),
            "kuka_camera_joints_rad": None, "kuka_target_joints_rad": None, "kuka_rail_m": None,
            **pose_columns("vicon_world_from_camrb", None), **pose_columns("vicon_world_from_targetrb", None),
            "vicon_camrb_markers": 0, "vicon_targetrb_markers": 0, "status": "ok",
        }
        return CaptureRecord(captures, None)
