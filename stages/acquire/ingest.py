"""Validation shared by the replay readers: every error names the file and the row."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from speedplus.errors import FileError

#: Plausible distances of a flange or rigid body from its world origin, per unit: an
#: industrial cell is metres across (at most 30 m), and a flange never stays within 50 mm of
#: its robot's base, so a file whose farthest position is nearer is in another unit.
PLAUSIBLE_RANGE = {"mm": (50.0, 30_000.0), "m": (0.05, 30.0)}
ORTHONORMAL_TOLERANCE = 1e-3


def read_text(path: Path) -> str:
    """UTF-8 text; a byte-order mark (spreadsheets write one) is dropped."""
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise FileError(path, "file not found") from None
    except UnicodeDecodeError as error:
        raise FileError(path, f"not UTF-8 text (byte {error.start})") from None
    except OSError as error:
        raise FileError(path, f"unreadable ({error.strerror})") from None


def read_csv(path: Path, required: list[str]) -> list[tuple[int, dict[str, str]]]:
    """(line number, row) pairs of a CSV with a header; the header must hold ``required``."""
    lines = read_text(path).splitlines()
    reader = csv.DictReader(lines)
    missing = [c for c in required if c not in (reader.fieldnames or [])]
    if missing:
        raise FileError(path, f"header lacks column(s) {', '.join(missing)}")
    return [(number, row) for number, row in enumerate(reader, start=2)]


def number(path: Path, line: int, row: dict[str, str], column: str) -> float:
    """A finite float from a CSV cell (``nan`` allowed only where the caller says so)."""
    text = (row.get(column) or "").strip()
    try:
        return float(text)
    except ValueError:
        raise FileError(path, f"line {line}, column {column}: expected a number, got {text!r}") from None


def check_finite(path: Path, where: str, values: np.ndarray) -> None:
    if not np.all(np.isfinite(values)):
        raise FileError(path, f"{where}: non-finite value")


def check_angles(path: Path, where: str, angles: np.ndarray, unit: str) -> None:
    """Euler angles (3,) of a robot controller lie within a turn: more in radians means degrees."""
    limit = 2 * np.pi + 1e-6 if unit == "rad" else 360.0 + 1e-6
    if np.abs(angles).max() > limit:
        hint = "; is the file in degrees (angle_unit = \"deg\")?" if unit == "rad" else ""
        raise FileError(path, f"{where}: angle {np.abs(angles).max():.6g} {unit} is more than a turn{hint}")


def check_rotation(path: Path, where: str, rotation: np.ndarray) -> None:
    """A proper rotation matrix (3, 3) within ``ORTHONORMAL_TOLERANCE``."""
    error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if error > ORTHONORMAL_TOLERANCE or np.linalg.det(rotation) <= 0:
        raise FileError(path, f"{where}: rotation is not orthonormal (|R^T R - I| = {error:.2g}, "
                                f"det = {np.linalg.det(rotation):.4f})")


def check_translation(path: Path, label: str, translations: np.ndarray, unit: str, rows: list[str]) -> None:
    """Positions (N, 3) must be plausible for ``unit``: none farther from the origin than a
    cell is across, and not all of them within a few millimetres of it (the mark of metres
    declared as millimetres). A single pose at the origin is plausible: a static target
    or a camera at the robot's base frame."""
    low, high = PLAUSIBLE_RANGE[unit]
    other = "m" if unit == "mm" else "mm"
    norms = np.linalg.norm(translations, axis=-1)
    for norm, row in zip(norms, rows, strict=True):
        if norm > high:
            raise FileError(path, f"{row}: {label} {norm:.6g} {unit} from the origin is implausible for "
                                    f"{unit} (at most {high:g}); is the file in {other}?")
    if len(norms) and norms.max() < low:
        raise FileError(path, f"{label}: every position lies within {norms.max():.6g} {unit} of the origin, "
                                f"implausible for {unit} (a flange is at least {low:g} {unit} from its base); "
                                f"is the file in {other}?")

