"""Replay of a hand-eye folder: images plus one robot pose file, described by
``DIR/dataset.toml`` (format version 1; docs/user-guide.md documents every key).

Frames (docs/architecture.md section 4): the target T is the pattern's frame. With ``camera_on =
"flange"`` (eye-in-hand: the camera rides the flange, the pattern stands still) the camera
flange C_K is the flange and the target flange T_K is the robot base, which is the robot
world K. With ``camera_on = "world"`` (eye-to-hand) the roles swap: C_K is the robot base,
T_K the flange that carries the pattern. Either way ``calibrate`` solves ``A_i X = Z B_i``
with ``B_i = camee_from_targetee`` and the robot as the only source (``kuka``).
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from manifests import Workspace, sample_ids
from manifests.sidecars import Session, SessionCamera
from speedplus.errors import unknown_keys
from stages.acquire.backend import CaptureRecord
from stages.acquire.ingest import (
    FileError,
    check_angles,
    check_finite,
    check_rotation,
    check_translation,
    number,
    read_csv,
    read_text,
)
from stages.common import geometry as g
from stages.common.geometry import pose_columns
from stages.common.image_io import IMAGE_SUFFIXES, ImageInfo, image_info, ingest_image
from stages.common.patterns import PatternSpec, pattern_from_table

DATASET_FILE = "dataset.toml"
FORMAT_VERSION = 1
#: table -> key -> allowed values (None: any value of the right type, checked below)
CHOICES: dict[str, dict[str, tuple[str, ...] | None]] = {
    "robot": {"file": None, "layout": ("rowmajor4x4", "counted4x4", "xyzabc"),
              "transform": ("base_from_flange", "flange_from_base"), "length_unit": ("m", "mm"),
              "angle_unit": ("deg", "rad")},
    "setup": {"camera_on": ("flange", "world")},
    "images": {"glob": None},
}
DEFAULTS = {"layout": "rowmajor4x4", "transform": "base_from_flange", "length_unit": "m", "angle_unit": "deg",
            "camera_on": "flange", "glob": "*.png"}
XYZABC_COLUMNS = ["sample", "x", "y", "z", "a", "b", "c"]


@dataclass(frozen=True)
class HandEyeDataset:
    """A validated ``dataset.toml`` (or a preset built in code, like Tabb's)."""

    source: Path
    pose_file: str
    layout: str
    transform: str
    length_unit: str
    angle_unit: str
    camera_on: str
    image_glob: str
    pattern: PatternSpec
    camera: dict[str, Any] | None  # width, height (px), K (3x3, px), dist (OpenCV) when given
    label: str = DATASET_FILE  # how messages name the description


def natural_key(name: str) -> list[Any]:
    """Sort key: ``image2`` before ``image10``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def inside(source: Path, relative: str, where: str, what: str) -> Path:
    """``source / relative``, refusing anything that leaves ``source`` (absolute paths,
    ``..``, symbolic links pointing out)."""
    path = (source / relative)
    if Path(relative).is_absolute() or ".." in Path(relative).parts:
        raise FileError(where, f"{what} {relative!r} must be a path inside {source}")
    if not path.resolve().is_relative_to(source.resolve()):
        raise FileError(where, f"{what} {relative!r} leads outside {source} (a symbolic link?)")
    return path


def _camera_table(table: Any, where: Path) -> dict[str, Any] | None:
    if table is None:
        return None
    if not isinstance(table, dict):
        raise FileError(where, "[camera] must be a table")
    unknown = sorted(set(table) - {"width", "height", "K", "dist"})
    if unknown:
        raise FileError(where, f"[camera] unknown key(s) {unknown_keys(unknown, ('width', 'height', 'K', 'dist'))}; "
                                 "expected width, height, K, dist")
    for key in ("width", "height"):
        if not isinstance(table.get(key), int) or table[key] < 1:
            raise FileError(where, f"[camera] {key} must be a positive integer (px), got {table.get(key)!r}")
    camera_matrix, dist = table.get("K"), table.get("dist")
    if camera_matrix is not None:
        array = np.asarray(camera_matrix, dtype=object)
        if array.shape != (3, 3) or not all(isinstance(v, int | float) for v in array.ravel()):
            raise FileError(where, "[camera] K must be a 3 x 3 matrix of numbers (px)")
        camera_matrix = np.asarray(camera_matrix, float)
        if camera_matrix[0, 0] <= 0 or camera_matrix[1, 1] <= 0 or not np.allclose(camera_matrix[2], [0, 0, 1]):
            raise FileError(where, "[camera] K needs positive fx, fy and a last row 0 0 1")
    if dist is not None and (not isinstance(dist, list) or len(dist) not in (4, 5, 8)
                             or not all(isinstance(v, int | float) for v in dist)):
        raise FileError(where, "[camera] dist must be 4, 5 or 8 OpenCV distortion coefficients")
    if (camera_matrix is None) != (dist is None):
        raise FileError(where, "[camera] give both K and dist, or neither (then they are estimated)")
    return {"width": table["width"], "height": table["height"],
            "K": None if camera_matrix is None else camera_matrix.tolist(),
            "dist": None if dist is None else [float(v) for v in dist]}


def read_dataset_toml(source: Path) -> HandEyeDataset:
    """Parse and validate ``source/dataset.toml``; every error names the file and the key."""
    path = source / DATASET_FILE
    if not source.is_dir():
        raise FileError(source, "not a directory")
    try:
        meta = tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as error:
        raise FileError(path, f"not valid TOML ({error})") from None
    if meta.get("format_version") != FORMAT_VERSION:
        raise FileError(path, f"format_version must be {FORMAT_VERSION}, got {meta.get('format_version')!r}")
    tables = {"format_version", "robot", "setup", "images", "pattern", "camera"}
    unknown = sorted(set(meta) - tables)
    if unknown:
        raise FileError(path, f"unknown key(s) or table(s) {unknown_keys(unknown, tables)}")
    values: dict[str, Any] = dict(DEFAULTS)
    for table, keys in CHOICES.items():
        given = meta.get(table, {})
        if not isinstance(given, dict):
            raise FileError(path, f"[{table}] must be a table")
        for key in sorted(set(given) - set(keys)):
            raise FileError(path, f"[{table}] unknown key {unknown_keys([key], keys)}; expected some of "
                                    f"{', '.join(keys)}")
        for key, allowed in keys.items():
            if key not in given:
                continue
            value = given[key]
            if not isinstance(value, str) or (allowed is not None and value not in allowed):
                expected = " or ".join(allowed) if allowed else "a string"
                raise FileError(path, f"[{table}] {key} must be {expected}, got {value!r}")
            values[key] = value
    if "file" not in values:
        raise FileError(path, "[robot] file is missing: the pose file, relative to the folder")
    if "pattern" not in meta:
        raise FileError(path, "[pattern] is missing: kind, size and square_m of the calibration pattern")
    inside(source, values["file"], path, "[robot] file")
    return HandEyeDataset(source, values["file"], values["layout"], values["transform"], values["length_unit"],
                          values["angle_unit"], values["camera_on"], values["glob"],
                          pattern_from_table(meta["pattern"], str(path)), _camera_table(meta.get("camera"), path))


# ------------------------------------------------------------------------------ pose files
def _number_lines(path: Path) -> list[tuple[int, list[float]]]:
    """(line, numbers) of every non-empty line of a whitespace- or comma-separated text file
    (``#`` starts a comment)."""
    out = []
    for line_number, line in enumerate(read_text(path).splitlines(), start=1):
        tokens = line.split("#", 1)[0].replace(",", " ").split()
        values = []
        for token in tokens:
            try:
                values.append(float(token))
            except ValueError:
                raise FileError(path, f"line {line_number}: not a number: {token!r}") from None
        if values:
            out.append((line_number, values))
    return out


def _rowmajor(path: Path) -> tuple[np.ndarray, list[str]]:
    matrices, where = [], []
    for line_number, values in _number_lines(path):
        if len(values) != 16:
            raise FileError(path, f"line {line_number}: expected 16 numbers (a row-major 4 x 4 matrix), "
                                    f"got {len(values)}")
        matrices.append(np.array(values).reshape(4, 4))
        where.append(f"line {line_number}")
    return np.array(matrices).reshape(-1, 4, 4), where


def _counted(path: Path) -> tuple[np.ndarray, list[str]]:
    numbers = [(line, value) for line, values in _number_lines(path) for value in values]
    if not numbers or not np.isfinite(numbers[0][1]) or numbers[0][1] != int(numbers[0][1]) or numbers[0][1] < 1:
        raise FileError(path, f"line {numbers[0][0] if numbers else 1}: must start with the number of poses, "
                                f"got {numbers[0][1] if numbers else 'nothing'}")
    count = int(numbers[0][1])
    if len(numbers) - 1 != 16 * count:
        raise FileError(path, f"announces {count} matrices but holds {(len(numbers) - 1) / 16:g}")
    values = np.array([v for _, v in numbers[1:]]).reshape(count, 4, 4)
    return values, [f"matrix {k} (line {numbers[1 + 16 * k][0]})" for k in range(count)]


def _xyzabc(path: Path, angle_unit: str) -> tuple[np.ndarray, list[str]]:
    matrices, where, seen = [], [], {}
    for line, row in read_csv(path, XYZABC_COLUMNS):
        sample = (row["sample"] or "").strip()
        if sample in seen:
            raise FileError(path, f"line {line}, column sample: duplicate {sample!r} (first at line {seen[sample]})")
        seen[sample] = line
        values = np.array([number(path, line, row, c) for c in "xyzabc"])
        check_finite(path, f"line {line}", values)
        angles = values[3:]
        check_angles(path, f"line {line}", angles, angle_unit)
        degrees = angles if angle_unit == "deg" else np.degrees(angles)
        rotation = g.kuka_to_transform(np.concatenate([np.zeros(3), degrees]))[:3, :3]  # Rz(a) Ry(b) Rx(c)
        # lengths stay in the declared unit: read_poses converts them, once, for every layout
        matrices.append(g.make_transform(rotation, values[:3]))
        where.append(f"line {line} (sample {sample})")
    return np.array(matrices).reshape(-1, 4, 4), where


def read_poses(dataset: HandEyeDataset) -> np.ndarray:
    """(N, 4, 4) ``base_from_flange`` in metres, validated: finite, a last row 0 0 0 1,
    orthonormal rotations, positions plausible for the declared unit."""
    path = inside(dataset.source, dataset.pose_file, dataset.source / dataset.label, "[robot] file")
    if dataset.layout == "rowmajor4x4":
        matrices, where = _rowmajor(path)
    elif dataset.layout == "counted4x4":
        matrices, where = _counted(path)
    else:
        matrices, where = _xyzabc(path, dataset.angle_unit)
    if not len(matrices):
        raise FileError(path, "no poses")
    for matrix, label in zip(matrices, where, strict=True):
        check_finite(path, label, matrix)
        if not np.allclose(matrix[3], [0, 0, 0, 1]):
            raise FileError(path, f"{label}: last row must be 0 0 0 1, got {matrix[3].tolist()}")
        check_rotation(path, label, matrix[:3, :3])
    check_translation(path, "translation", matrices[:, :3, 3], dataset.length_unit, where)
    matrices = matrices.copy()
    matrices[:, :3, :3] = g.project_to_so3(matrices[:, :3, :3])  # files round their rotations
    if dataset.length_unit == "mm":
        matrices[:, :3, 3] /= 1000.0  # converted once, here
    if dataset.transform == "flange_from_base":
        matrices = np.stack([g.invert(m) for m in matrices])
    return matrices


def list_images(dataset: HandEyeDataset) -> list[Path]:
    """The images matched by ``[images] glob``, in natural order, all inside the folder."""
    where = dataset.source / dataset.label
    pattern = dataset.image_glob
    if not pattern.strip() or Path(pattern).is_absolute() or ".." in Path(pattern).parts:
        raise FileError(where, f"[images] glob {pattern!r} must be a non-empty pattern inside {dataset.source}")
    try:
        found = [p for p in dataset.source.glob(pattern) if p.is_file()]
    except ValueError as error:  # pathlib's "Unacceptable pattern"
        raise FileError(where, f"[images] glob {pattern!r}: {error}") from None
    found.sort(key=lambda p: natural_key(str(p.relative_to(dataset.source))))
    for path in found:
        inside(dataset.source, str(path.relative_to(dataset.source)), where, "image")
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise FileError(path, f"not an image type the pipeline reads ({', '.join(IMAGE_SUFFIXES)})")
    return found


def check_images(images: list[Path], camera: dict[str, Any] | None, where: Path) -> ImageInfo:
    """Every image readable (header) and of one size, the camera's when it is declared."""
    infos = [image_info(path) for path in images]
    first = infos[0]
    for path, info in zip(images, infos, strict=True):
        if (info.width, info.height) != (first.width, first.height):
            raise FileError(path, f"{info.width} x {info.height} px, but {images[0].name} is "
                                    f"{first.width} x {first.height}: one camera, one image size")
    if camera is not None and (camera["width"], camera["height"]) != (first.width, first.height):
        raise FileError(images[0], f"{first.width} x {first.height} px, but {where} declares the camera "
                                     f"[camera] width x height = {camera['width']} x {camera['height']}")
    return first


class HandEyeReplay:
    """Implements ``stages.acquire.backend.Testbed`` for a hand-eye folder."""

    def __init__(self, dataset: HandEyeDataset, workspace: Workspace, format_name: str = "handeye") -> None:
        self.dataset, self.workspace, self.format_name = dataset, workspace, format_name
        self.base_from_flange = read_poses(dataset)
        self.images = list_images(dataset)
        where = dataset.source / dataset.label
        if len(self.images) != len(self.base_from_flange):
            raise FileError(where, f"{len(self.images)} images match [images] glob {dataset.image_glob!r} but "
                                     f"{dataset.pose_file} holds {len(self.base_from_flange)} poses; the N-th "
                                     "image pairs with the N-th pose")
        self.info = check_images(self.images, dataset.camera, where)

    def samples(self) -> list[dict[str, Any]]:
        return [{"sample_id": sample_ids.make("calibration", i), "session": "calibration", "index": i}
                for i in range(len(self.images))]

    def session(self) -> Session:
        camera = self.dataset.camera or {"K": None, "dist": None}
        eye_in_hand = self.dataset.camera_on == "flange"
        return Session("replay", self.format_name, ("kuka",),
                       SessionCamera(self.info.width, self.info.height, camera["K"], camera["dist"]),
                       self.dataset.pattern.to_json(), str(self.dataset.source),
                       {"camee": "flange" if eye_in_hand else "robot base",
                        "targetee": "robot base" if eye_in_hand else "flange",
                        "world": "robot base", "target": f"{self.dataset.pattern.kind} (OpenCV)"})

    def capture(self, sample: dict[str, Any]) -> CaptureRecord:
        index = sample["index"]
        source_image = self.images[index]
        relpath = self.workspace.image_relpath("calibration", sample["sample_id"])
        stored, converted = ingest_image(source_image, self.workspace.resolve(relpath))
        flange = self.base_from_flange[index]
        world_from_camee, world_from_targetee = ((flange, np.eye(4)) if self.dataset.camera_on == "flange"
                                                 else (np.eye(4), flange))
        captures = {
            "sample_id": sample["sample_id"], "session": "calibration", "fixture": "fixed",
            "image_path": str(Path(relpath).with_suffix(stored.suffix).as_posix()),
            "source_image": str(source_image.relative_to(self.dataset.source).as_posix()),
            "image_conversion": converted,
            **pose_columns("kuka_world_from_camee", world_from_camee),
            **pose_columns("kuka_world_from_targetee", world_from_targetee),
            "kuka_camera_joints_rad": None, "kuka_target_joints_rad": None, "kuka_rail_m": None, "capture_time_s": None,
            "move_s": None,
            **pose_columns("vicon_world_from_camrb", None), **pose_columns("vicon_world_from_targetrb", None),
            "vicon_camrb_markers": 0, "vicon_targetrb_markers": 0,
            "vicon_targetrb_used": None, "vicon_targetrb_residual_m": None, "status": "ok",
        }
        return CaptureRecord(captures, None)
