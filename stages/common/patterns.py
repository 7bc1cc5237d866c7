"""Calibration patterns (ChArUco for the testbed, chessboards for third-party data).

A ``PatternSpec`` travels with a capture session (``W/session.json``) so that
``calibrate`` knows what to detect without extra flags. The pattern frame is OpenCV's:
origin at the board's outer corner (ChArUco) or first inner corner (chessboard), x along
the first dimension, y along the second, z into the board.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from core.config import TestbedConfig
from speedplus.errors import unknown_keys
from stages.common import layout
from stages.common.image_io import to_uint8
from stages.common.kept import Kept
from stages.common.target import Target


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
        """From ``session.json`` (validated by ``pattern_from_table`` on ingestion): the
        ``target_from_pattern_q/_t`` keys are optional (identity)."""
        tuples = {key: tuple(data[key]) for key in ("size", "target_from_pattern_q", "target_from_pattern_t")
                  if key in data}
        return cls(**{**data, **tuples})

    def reorderings(self) -> list[tuple[str, np.ndarray]]:
        """Corner relabellings a chessboard detection may need: (name, ids (M,) mapping each
        detected id to the relabelled one). OpenCV's chessboard detectors may start a board
        from either end (always possible when its squares repeat under a half turn, i.e.
        ``size`` x + y even), a square board also a quarter turn away; calibrate lets the
        robot's motion decide. ChArUco ids are absolute: no alternative."""
        if self.kind != "chessboard":
            return []
        w, h = self.size
        ids = np.arange(w * h)
        i, j = ids % w, ids // w
        out = [("half turn", (w - 1 - i) + w * (h - 1 - j))]
        if w == h:
            out += [("quarter turn", j + w * (w - 1 - i)), ("three-quarter turn", (w - 1 - j) + w * i)]
        return out

    def object_points(self) -> np.ndarray:
        """(M, 3) corners in the pattern frame, metres, in OpenCV's id order."""
        if self.kind == "charuco":
            return np.asarray(charuco_board(self).getChessboardCorners(), dtype=float)
        xs, ys = np.meshgrid(np.arange(self.size[0]), np.arange(self.size[1]))
        return np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1) * self.square_m


PATTERN_KEYS = {"kind", "size", "square_m", "marker_m", "dictionary", "target_from_pattern_q", "target_from_pattern_t"}


def pattern_from_table(table: Any, where: str) -> PatternSpec:
    """A ``[pattern]`` table of a recorded session (``session.toml``, ``dataset.toml``),
    validated; errors start with ``where`` and name the key."""
    from speedplus.errors import InputError

    def fail(message: str) -> InputError:
        return InputError(f"{where}: [pattern] {message}")

    if not isinstance(table, dict):
        raise fail("must be a table")
    unknown = sorted(set(table) - PATTERN_KEYS)
    if unknown:
        raise fail(f"unknown key(s) {unknown_keys(unknown, PATTERN_KEYS)}; expected some of "
                   f"{', '.join(sorted(PATTERN_KEYS))}")
    kind = table.get("kind")
    if kind not in ("chessboard", "charuco"):
        raise fail(f"kind must be chessboard or charuco, got {kind!r}")
    size = table.get("size")
    if (not isinstance(size, list) or len(size) != 2 or not all(isinstance(v, int) and v >= 2 for v in size)):
        what = "inner corners" if kind == "chessboard" else "squares"
        raise fail(f"size must be two integers >= 2 ({what} along x and y), got {size!r}")
    square = table.get("square_m")
    if not isinstance(square, int | float) or not 0 < square < 1:
        raise fail(f"square_m must be the square's side in metres (0 to 1), got {square!r}")
    marker, dictionary = table.get("marker_m", 0.0), table.get("dictionary", "")
    if kind == "charuco":
        if not isinstance(marker, int | float) or not 0 < marker < square:
            raise fail(f"marker_m must be in metres, positive and smaller than square_m, got {marker!r}")
        if not isinstance(dictionary, str) or not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
            raise fail(f"dictionary must name a cv2.aruco predefined dictionary (e.g. DICT_5X5_100), "
                       f"got {dictionary!r}")
    elif marker or dictionary:  # session.json writes the chessboard's 0.0 and "" explicitly
        raise fail("marker_m and dictionary belong to charuco patterns only")
    q = table.get("target_from_pattern_q", [1.0, 0.0, 0.0, 0.0])
    t = table.get("target_from_pattern_t", [0.0, 0.0, 0.0])
    for key, value, n in (("target_from_pattern_q", q, 4), ("target_from_pattern_t", t, 3)):
        if (not isinstance(value, list) or len(value) != n
                or not all(isinstance(v, int | float) and np.isfinite(v) for v in value)):
            raise fail(f"{key} must be {n} finite numbers, got {value!r}")
    if abs(np.linalg.norm(q) - 1.0) > 1e-6:
        raise fail(f"target_from_pattern_q must be a unit quaternion (w, x, y, z), norm {np.linalg.norm(q):.6f}")
    return PatternSpec(kind, (size[0], size[1]), float(square), float(marker), str(dictionary),
                       tuple(float(v) for v in q), tuple(float(v) for v in t))


def charuco_board(spec: PatternSpec) -> cv2.aruco.CharucoBoard:
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    return cv2.aruco.CharucoBoard(spec.size, spec.square_m, spec.marker_m, dictionary)


def board_pattern(testbed: TestbedConfig, target: Target) -> PatternSpec:
    """The testbed's ChArUco board where it lies on the mock-up (``layout.target_from_board``:
    Tango's solar panel), checked by the one pattern validator (a bad dictionary name is an
    error naming the configuration key)."""
    q, t = layout.board_pose(testbed, target)
    return pattern_from_table({"kind": "charuco", "size": list(testbed.board_squares),
                               "square_m": testbed.board_square_m, "marker_m": testbed.board_marker_m,
                               "dictionary": testbed.board_dictionary,
                               "target_from_pattern_q": [float(v) for v in q],
                               "target_from_pattern_t": [float(v) for v in t]},
                              "configuration [testbed] board_*")


def board_image(spec: PatternSpec, px_per_m: float, margin_m: float) -> np.ndarray:
    """Printed board (H, W) uint8 with a white margin: the plate the board is printed on."""
    squares_x, squares_y = spec.size
    width_px = int(round((squares_x * spec.square_m + 2 * margin_m) * px_per_m))
    height_px = int(round((squares_y * spec.square_m + 2 * margin_m) * px_per_m))
    margin_px = int(round(margin_m * px_per_m))
    return charuco_board(spec).generateImage((width_px, height_px), marginSize=margin_px, borderBits=1)





#: detections by (the 8-bit image's digest, its shape, the pattern): a process that detects
#: the same pixels again (a bench or a test calibrating one folder several ways, or in other
#: formats) finds them here; the detectors are deterministic, so this is their answer
_DETECTED: Kept[tuple[np.ndarray, np.ndarray]] = Kept(4096)


def detect(image: np.ndarray, spec: PatternSpec) -> tuple[np.ndarray, np.ndarray]:
    """Pattern corners in a grey image (H, W) of any pixel type: pixels (N, 2) and their ids
    (N,) into ``spec.object_points()``; empty arrays when nothing is found. Kept per process
    by the pixels' digest (``_DETECTED``): the same pixels are detected once.

    OpenCV's detectors need 8 bits: they run on ``to_uint8(image)``, which stretches data
    of more than 8 significant bits over its own range. Their sub-pixel fits are kept:
    refining them with ``cv2.cornerSubPix`` on the full-precision image was measured worse
    (12 dark 12-bit views of Ali et al.'s board: calibrateCamera RMS 0.120 px refined,
    0.067 px as detected)."""
    detection = np.ascontiguousarray(to_uint8(image))
    # the pattern by its fields' text: a spec made with lists (unhashable) is the same pattern
    key = (hashlib.blake2b(detection.data, digest_size=32).digest(), detection.shape, json.dumps(spec.to_json()))
    pixels, ids = _DETECTED.get(key, lambda: _detect(detection, spec))
    return pixels.copy(), ids.copy()


def _detect(detection: np.ndarray, spec: PatternSpec) -> tuple[np.ndarray, np.ndarray]:
    """``detect`` on the 8-bit image (H, W)."""
    if spec.kind == "charuco":
        detector = cv2.aruco.CharucoDetector(charuco_board(spec))
        corners, ids, _, _ = detector.detectBoard(detection)
        if ids is None or len(ids) == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=int)
        return corners.reshape(-1, 2).astype(float), ids.ravel().astype(int)
    found, corners = cv2.findChessboardCornersSB(detection, spec.size, flags=cv2.CALIB_CB_EXHAUSTIVE)
    if not found:
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    return corners.reshape(-1, 2).astype(float), np.arange(spec.size[0] * spec.size[1])
