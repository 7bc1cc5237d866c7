"""Per-pixel ground truth as one multi-channel OpenEXR file per image (written by
``stages.common.exr``, tiled and ZIP-compressed; read through OpenImageIO); the format is
defined here, once, and checked on read.

Channels (one value per output pixel of the image it belongs to, in that image's distorted
geometry; NaN where the model is not hit; float32, but the radiance in half floats):

=========================  ============================================================
``R``, ``G``, ``B``        linear HDR radiance of the render (the 8-bit PNG is its tone
                           map, toned before rounding: toning these values gives it
                           within one level); synthetic images only. Half (float16, 11
                           significant bits) where all of it fits half's range, float32
                           where not (``radiance_planes``); version 1 files hold float32
``Z``                      depth: z of the surface in the OpenCV camera frame, metres
``N.X``, ``N.Y``, ``N.Z``  unit surface normal in the camera frame, towards the camera
``P.X``, ``P.Y``, ``P.Z``  the surface point in the target's body coordinates, metres
``part``                   0 background, then 1, 2, ... the target's mesh parts in order
                           (``stages.common.surface.part_ids``; Tango: 1 solar panel, 2 rear
                           panel, 3 sides, 4 antennas); exact small integers
=========================  ============================================================

The testbed's truth maps (virtual backend, for evaluation only) hold ``Z`` and ``part``
at the mock-up's true pose and scale. Header: ``speedplus:ground_truth`` (JSON: version 2,
or 1 as read; camera_matrix (3, 3) px, dist (5,) OpenCV, cam_from_target (4, 4) m,
length_scale, part_ids: part name -> index). OpenEXR's own ``worldToCamera`` is not
written: its camera looks along -z, not OpenCV's +z, and a second convention for the same
pose would invite mistakes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from manifests.files import write_bytes_atomic
from speedplus.errors import InputError
from stages.common import exr
from stages.common.lens import LensCamera
from stages.common.surface import SurfaceMaps, WindowedMaps

VERSION = 2
#: versions read: 1 differs only in its radiance, float32 (an OpenEXR reader widens either)
READABLE = (1, 2)
HEADER_KEY = "speedplus:ground_truth"
RADIANCE = ("R", "G", "B")
#: the largest finite half float
HALF_MAX = 65504.0
GEOMETRY = ("Z", "N.X", "N.Y", "N.Z", "P.X", "P.Y", "P.Z", "part")
TRUTH = ("Z", "part")


class GroundTruthError(InputError):
    """An unreadable or malformed ground-truth file; the message names the file and key."""


@dataclass(frozen=True)
class GroundTruth:
    """A read file: ``channels`` {name: (H, W) float32} and the header's camera and pose."""

    channels: dict[str, np.ndarray]
    camera: LensCamera
    cam_from_target: np.ndarray
    length_scale: float
    part_ids: dict[str, int]

    def stack(self, names: tuple[str, ...]) -> np.ndarray:
        """(H, W, len(names)) of the named channels."""
        return np.stack([self.channels[name] for name in names], axis=-1)


def channels_of(maps: SurfaceMaps | WindowedMaps, radiance: np.ndarray | None, names: tuple[str, ...],
                length_scale: float = 1.0, black_outside: bool = False) -> dict[str, np.ndarray | exr.Windowed]:
    """The named channels from ray-cast maps (full scale; of the whole image, or of the
    window the target can be in) and an optional (H, W, 3) linear radiance; ``length_scale``
    turns the full-scale model's lengths into the scene's (the testbed's half-scale mock-up).
    Maps of a window give its planes with their fill outside (``exr.Windowed``), and so does
    the radiance where ``black_outside`` (a render of black space: exactly zero there)."""
    # a scale of 1 (the synthetic images) copies nothing: every fresh frame is page faults
    scaled = (lambda values: values) if length_scale == 1.0 else (lambda values: values * length_scale)
    inside = maps.inside if isinstance(maps, WindowedMaps) else maps
    if inside is None:  # an empty window: nothing of the target in the image
        inside = SurfaceMaps(np.zeros((0, 0), np.float32), np.zeros((0, 0, 3), np.float32),
                             np.zeros((0, 0, 3), np.float32), np.zeros((0, 0), np.uint8), maps.ids)
    source = {"Z": scaled(inside.depth_m), "part": inside.part.astype(np.float32)}
    for axis, name in enumerate("XYZ"):
        source[f"N.{name}"] = inside.normal_cam[..., axis]
        source[f"P.{name}"] = scaled(inside.body_m[..., axis])
    windowed = isinstance(maps, WindowedMaps)
    if radiance is not None:
        rows, columns = maps.window.slices() if windowed and black_outside else (slice(None), slice(None))
        source.update(zip(RADIANCE, radiance_planes(radiance[rows, columns]), strict=True))
    out: dict[str, np.ndarray | exr.Windowed] = {}
    for name in names:
        values = source[name] if name in RADIANCE else np.asarray(source[name], np.float32)
        if windowed and (name not in RADIANCE or black_outside):
            fill = 0.0 if name in ("part", *RADIANCE) else np.nan
            values = exr.Windowed(values, maps.window.y, maps.window.x, (maps.height, maps.width), fill)
        out[name] = values
    return out


def radiance_planes(radiance: np.ndarray) -> tuple[np.ndarray, ...]:
    """The (H, W, 3) linear radiance as its three (H, W) planes to write: half floats
    (float16, rounded to nearest even) where every value is within half's range (|L| <=
    65504), as every render of this project's scenes is, else float32. A half keeps 11
    significant bits, a relative step of 2^-11 = 4.9e-4: below a render's Monte-Carlo noise
    and below the 8-bit PNG's step at any tone, and it halves the bytes and the deflate of an
    image whose radiance fills the frame (an Earth behind the target; docs/architecture.md
    section 7). OpenCV's conversion (the CPU's F16C) gives NumPy's bits at a tenth of its time."""
    values = np.ascontiguousarray(radiance, np.float32)
    if values.size == 0 or not (values.min() >= -HALF_MAX and values.max() <= HALF_MAX):  # NaN fails both
        return tuple(values[..., axis] for axis in range(3))
    half = cv2.convertFp16(values.reshape(values.shape[0], -1)).view(np.float16).reshape(values.shape)
    return tuple(np.ascontiguousarray(half.transpose(2, 0, 1)))


def encode(channels: dict[str, np.ndarray | exr.Windowed], camera: LensCamera, cam_from_target: np.ndarray,
           part_ids: dict[str, int], length_scale: float = 1.0) -> bytes:
    """The file's bytes: the channels {name: (H, W)}, float16 planes as half and any other
    as float32, tiled and ZIP-compressed (``stages.common.exr``), with the header."""
    header = {"version": VERSION, "camera_matrix": np.asarray(camera.camera_matrix, float).tolist(),
              "dist": [float(v) for v in camera.dist], "cam_from_target": np.asarray(cam_from_target, float).tolist(),
              "length_scale": float(length_scale), "part_ids": dict(part_ids)}
    return exr.encode(channels, {HEADER_KEY: json.dumps(header)})


def write(path: Path, channels: dict[str, np.ndarray | exr.Windowed], camera: LensCamera, cam_from_target: np.ndarray,
          part_ids: dict[str, int], length_scale: float = 1.0) -> None:
    """Write ``encode``'s file atomically."""
    write_bytes_atomic(path, encode(channels, camera, cam_from_target, part_ids, length_scale))


def _header(path: Path, text: Any) -> dict[str, Any]:
    def fail(key: str, expected: str) -> GroundTruthError:
        return GroundTruthError(f"{path}: header {HEADER_KEY}, key {key}: expected {expected}")

    try:
        header = json.loads(text) if isinstance(text, str) else None
    except ValueError:
        header = None
    if not isinstance(header, dict):
        raise fail("(top level)", "a JSON object; not a SPEED+ builder ground-truth file")
    if header.get("version") not in READABLE:
        raise fail("version", f"one of {READABLE} (this program's); rerun the stage that wrote it with --force")
    for key, shape in (("camera_matrix", (3, 3)), ("dist", (5,)), ("cam_from_target", (4, 4))):
        value = np.asarray(header.get(key, []), dtype=object)
        if value.shape != shape or not all(isinstance(v, (int, float)) for v in value.ravel()):
            raise fail(key, f"numbers of shape {shape}")
    if not isinstance(header.get("length_scale"), (int, float)) or header["length_scale"] <= 0:
        raise fail("length_scale", "a positive number")
    ids = header.get("part_ids")
    if (not isinstance(ids, dict) or not all(isinstance(k, str) and isinstance(v, int) and 0 <= v < 256
                                             for k, v in ids.items())):
        raise fail("part_ids", "an object of part names to indices 0-255")
    return header


def read(path: Path, required: tuple[str, ...] = TRUTH) -> GroundTruth:
    """Read and check a ground-truth file: its header and the ``required`` channels."""
    import OpenImageIO as oiio  # noqa: N813 - the library's own documented alias

    image_input = oiio.ImageInput.open(str(path))
    if image_input is None:
        raise GroundTruthError(f"{path}: not a readable EXR ({oiio.geterror().strip() or 'missing'})")
    try:
        spec = image_input.spec()
        header = _header(path, spec.getattribute(HEADER_KEY))
        names = tuple(spec.channelnames)
        missing = [name for name in required if name not in names]
        if missing:
            raise GroundTruthError(f"{path}: channel {missing[0]} missing (has {', '.join(names)})")
        pixels = image_input.read_image(0, 0, 0, len(names), "float")
        if pixels is None or image_input.has_error:
            raise GroundTruthError(f"{path}: truncated or corrupt EXR ({image_input.geterror().strip()})")
    finally:
        image_input.close()
    pixels = np.asarray(pixels, np.float32).reshape(spec.height, spec.width, len(names))
    camera = LensCamera(np.array(header["camera_matrix"], float), np.array(header["dist"], float), spec.width,
                        spec.height)
    return GroundTruth({name: pixels[..., i] for i, name in enumerate(names)}, camera,
                       np.array(header["cam_from_target"], float), float(header["length_scale"]),
                       dict(header["part_ids"]))
