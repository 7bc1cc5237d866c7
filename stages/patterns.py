"""Calibration patterns (ChArUco for the testbed, chessboards for third-party data).

A ``PatternSpec`` travels with a capture session (``W/session.json``) so that
``calibrate`` knows what to detect without extra flags. The pattern frame is OpenCV's:
origin at the board's outer corner (ChArUco) or first inner corner (chessboard), x along
the first dimension, y along the second, z into the board.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from pipeline.config import TestbedConfig


@dataclass(frozen=True)
class PatternSpec:
    kind: str  # "charuco" | "chessboard"
    size: tuple[int, int]  # charuco: squares (x, y); chessboard: inner corners (x, y)
    square_m: float
    marker_m: float = 0.0  # charuco only
    dictionary: str = ""  # charuco only, a cv2.aruco predefined dictionary name
    target_from_pattern_q: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    target_from_pattern_t: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> PatternSpec:
        tuples = {key: tuple(data[key]) for key in ("size", "target_from_pattern_q", "target_from_pattern_t")}
        return cls(**{**data, **tuples})

    def object_points(self) -> np.ndarray:
        """(M, 3) corners in the pattern frame, metres, in OpenCV's id order."""
        if self.kind == "charuco":
            return np.asarray(charuco_board(self).getChessboardCorners(), dtype=float)
        xs, ys = np.meshgrid(np.arange(self.size[0]), np.arange(self.size[1]))
        return np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1) * self.square_m


def charuco_board(spec: PatternSpec) -> cv2.aruco.CharucoBoard:
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    return cv2.aruco.CharucoBoard(spec.size, spec.square_m, spec.marker_m, dictionary)


def board_pattern(testbed: TestbedConfig) -> PatternSpec:
    """The ChArUco board fixed on the model's solar panel."""
    return PatternSpec("charuco", tuple(testbed.board_squares), testbed.board_square_m, testbed.board_marker_m,
                       testbed.board_dictionary, tuple(testbed.target_from_board_q),
                       tuple(testbed.target_from_board_t_m))


def board_image(spec: PatternSpec, px_per_m: float, margin_m: float) -> np.ndarray:
    """Printed board (H, W) uint8 with a white margin: the plate the board is printed on."""
    squares_x, squares_y = spec.size
    width_px = int(round((squares_x * spec.square_m + 2 * margin_m) * px_per_m))
    height_px = int(round((squares_y * spec.square_m + 2 * margin_m) * px_per_m))
    margin_px = int(round(margin_m * px_per_m))
    return charuco_board(spec).generateImage((width_px, height_px), marginSize=margin_px, borderBits=1)





def detect(image: np.ndarray, spec: PatternSpec) -> tuple[np.ndarray, np.ndarray]:
    """Pattern corners in a grey image: pixels (N, 2) and their ids (N,) into
    ``spec.object_points()``; empty arrays when nothing is found."""
    if spec.kind == "charuco":
        detector = cv2.aruco.CharucoDetector(charuco_board(spec))
        corners, ids, _, _ = detector.detectBoard(image)
        if ids is None or len(ids) == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=int)
        return corners.reshape(-1, 2).astype(float), ids.ravel().astype(int)
    found, corners = cv2.findChessboardCornersSB(image, spec.size, flags=cv2.CALIB_CB_EXHAUSTIVE)
    if not found:
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    return corners.reshape(-1, 2).astype(float), np.arange(spec.size[0] * spec.size[1])
