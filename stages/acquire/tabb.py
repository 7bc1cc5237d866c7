"""Tabb & Ahmad Yousef's robot-world/hand-eye datasets (camera on the hand): a preset of
the hand-eye folder format (``stages.acquire.handeye``).

Layout: ``images/imageN.png`` (robot stop N), ``robot_cali.txt`` (the number of stops,
then one 4 x 4 ``hand_from_base`` matrix per stop, millimetres) and
``calibration_object.txt`` (``chess_width``, ``chess_height`` inner corners,
``chess_mm_width``/``chess_mm_height`` square size). Mapped onto docs/architecture.md section 4 as every
eye-in-hand folder: the target T is the chessboard's OpenCV frame, the target flange T_K is
the robot base (= the robot world K) and the camera flange C_K is the hand.
"""

from __future__ import annotations

from pathlib import Path

from speedplus.errors import FileError
from stages.acquire.handeye import HandEyeDataset
from stages.acquire.ingest import read_text
from stages.common.patterns import PatternSpec


def read_calibration_object(path: Path) -> PatternSpec:
    values: dict[str, float] = {}
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 2:
            raise FileError(path, f"line {number}: expected 'key value', got {line!r}")
        try:
            values[parts[0]] = float(parts[1])
        except ValueError:
            raise FileError(path, f"line {number}: {parts[0]} must be a number, got {parts[1]!r}") from None
    for key in ("chess_width", "chess_height", "chess_mm_width", "chess_mm_height"):
        if key not in values:
            raise FileError(path, f"missing {key}")
    if values["chess_mm_width"] != values["chess_mm_height"]:
        raise FileError(path, "chess_mm_width and chess_mm_height differ; only square squares are supported")
    if values["chess_mm_width"] <= 0 or values["chess_width"] < 2 or values["chess_height"] < 2:
        raise FileError(path, "the chessboard needs at least 2 x 2 inner corners and a positive square size")
    return PatternSpec("chessboard", (int(values["chess_width"]), int(values["chess_height"])),
                       values["chess_mm_width"] / 1000.0)


def tabb_dataset(source: Path) -> HandEyeDataset:
    """Tabb's layout as a preset of the hand-eye format: ``robot_cali.txt`` holds the count
    then ``hand_from_base`` matrices in mm (``counted4x4``, ``flange_from_base``), the camera
    rides the hand, image N (natural order) belongs to robot stop N."""
    if not source.is_dir():
        raise FileError(source, "not a directory")
    return HandEyeDataset(source, "robot_cali.txt", "counted4x4", "flange_from_base", "mm", "deg", "flange",
                          "images/image*.png", read_calibration_object(source / "calibration_object.txt"), None,
                          label="robot_cali.txt")
