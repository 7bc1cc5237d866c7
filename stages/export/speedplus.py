"""The SPEED+ layout (docs/architecture.md section 4): what the Stanford devkits read.

::

    OUT/camera.json                       Nu, Nv, ppx, ppy, fx, fy (metres), ccx, ccy, cameraMatrix, distCoeffs
    OUT/lightbox/images/<filename>        OUT/lightbox/test.json   testbed captures (light boxes)
    OUT/sunlamp/images/<filename>         OUT/sunlamp/test.json    testbed captures (sun lamp)
    OUT/twins/images/<filename>           OUT/twins/test.json      their synthetic twins (same filenames)
    OUT/synthetic/images/<sample_id>.png  OUT/synthetic/train.json, validation.json   the training set
    OUT/tangoPoints.mat                   the target's 3-D keypoints as the devkits load them:
                                          ``tango3Dpoints``, 3 x N, metres, body frame (that
                                          name whatever the target: the loaders' contract)
    OUT/keypoints.json                    the same points: {version, target, unit, frame, points}

Every json is ``[{filename, q_vbs2tango_true, r_Vo2To_vbs_true}]``. The devkit projects
body points with ``[quat2dcm(q).T | r]``; ``quat2dcm(q).T`` is the Hamilton rotation
matrix of ``q``, i.e. the rotation of ``cam_from_target``. Images are copied as they
are: distorted, with the distortion in ``camera.json`` (the devkits apply it). The
training images come from the training camera (``stages.common.cameras.train_camera``);
SPEED+ has one ``camera.json``, so the training camera must be the labels' camera for a
devkit to project both right, which ``check_one_camera`` makes sure of.
"""

from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import Any

import numpy as np

from manifests.files import write_bytes_atomic, write_json_atomic
from speedplus.errors import InputError
from stages.common.lens import LensCamera

TWINS_DOMAIN = "twins"
TRAIN_DOMAIN = "synthetic"


def camera_json(camera: LensCamera, pixel_pitch_m: float) -> dict[str, Any]:
    """SPEED+ ``camera.json``: focal lengths in metres through the pixel pitch."""
    k = camera.camera_matrix
    return {"Nu": int(camera.width), "Nv": int(camera.height), "ppx": pixel_pitch_m, "ppy": pixel_pitch_m,
            "fx": float(k[0, 0] * pixel_pitch_m), "fy": float(k[1, 1] * pixel_pitch_m),
            "ccx": float(k[0, 2]), "ccy": float(k[1, 2]),
            "cameraMatrix": k.tolist(), "distCoeffs": [float(v) for v in camera.dist]}


def check_one_camera(labels_camera: LensCamera, train: LensCamera, tolerance_px: float = 0.5) -> None:
    """Refuse a training set whose camera differs from the labels' by more than
    ``tolerance_px`` at any image corner: one ``camera.json`` must serve both."""
    if (train.width, train.height) != (labels_camera.width, labels_camera.height):
        raise InputError(f"export: the training images are {train.width}x{train.height}, the labelled ones "
                         f"{labels_camera.width}x{labels_camera.height}; SPEED+ has one camera.json for both")
    import cv2

    corners = np.array([[0, 0, 1], [train.width - 1, 0, 1], [0, train.height - 1, 1],
                        [train.width - 1, train.height - 1, 1]], float)
    rays = corners @ np.linalg.inv(train.camera_matrix).T
    moved = []
    for camera in (train, labels_camera):
        projected, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), camera.camera_matrix, camera.dist)
        moved.append(projected.reshape(-1, 2))
    if np.abs(moved[0] - moved[1]).max() > tolerance_px:
        raise InputError("export: the training set was rendered with another camera than the labels' calibrated "
                         f"one (up to {np.abs(moved[0] - moved[1]).max():.1f} px apart); SPEED+ has one camera.json; "
                         "export the training set in the bop format, or render it with the calibrated camera")


def image_file(export_set: str, domain: str, filename: str) -> str:
    """Where an image goes, relative to the export folder."""
    folder = {"testbed": domain, "twins": TWINS_DOMAIN, "train": TRAIN_DOMAIN}[export_set]
    return f"{folder}/images/{filename}"


def is_validation(sample_id: str, fraction: float) -> bool:
    """A deterministic split: the first 8 bytes of SHA-256(sample_id) as a share of 2^64."""
    share = int.from_bytes(hashlib.sha256(sample_id.encode()).digest()[:8], "big") / 2.0**64
    return share < fraction


def _entry(row: dict[str, Any], filename: str) -> dict[str, Any]:
    return {"filename": filename, "q_vbs2tango_true": [float(v) for v in row["q_vbs2tango_true"]],
            "r_Vo2To_vbs_true": [float(v) for v in row["r_Vo2To_vbs_true"]]}


KEYPOINTS_VERSION = 1
#: the text of a MAT-file's 116-byte header; SciPy's carries the time, and the same export
#: must give the same bytes
_MAT_HEADER = b"MATLAB 5.0 MAT-file, written by SPEED+ builder"


def write_keypoints(out: Path, target_name: str, keypoints_m: np.ndarray) -> None:
    """``tangoPoints.mat`` and ``keypoints.json`` of the target's keypoints (K, 3), metres,
    body frame (the labels' frame)."""
    from scipy.io import savemat

    buffer = io.BytesIO()
    savemat(buffer, {"tango3Dpoints": np.asarray(keypoints_m, float).T})
    data = buffer.getvalue()
    write_bytes_atomic(out / "tangoPoints.mat", _MAT_HEADER.ljust(116) + data[116:])
    write_json_atomic(out / "keypoints.json", {"version": KEYPOINTS_VERSION, "target": target_name, "unit": "m",
                                               "frame": "the body frame of the labels (q_vbs2tango_true)",
                                               "points": np.asarray(keypoints_m, float).tolist()})


def write_annotations(out: Path, items: list[dict[str, Any]], camera: dict[str, Any],
                      validation_fraction: float) -> dict[str, int]:
    """``camera.json`` and every domain's json from ``items`` (export items in export_id
    order: set, domain, filename, q_vbs2tango_true, r_Vo2To_vbs_true); counts per file."""
    write_json_atomic(out / "camera.json", camera)
    files: dict[str, list[dict[str, Any]]] = {}
    for item in items:
        if item["set"] == "train":
            split = "validation" if is_validation(item["sample_id"], validation_fraction) else "train"
            key = f"{TRAIN_DOMAIN}/{split}.json"
        else:
            key = f"{item['domain'] if item['set'] == 'testbed' else TWINS_DOMAIN}/test.json"
        files.setdefault(key, []).append(_entry(item, item["filename"]))
    for key, entries in sorted(files.items()):
        write_json_atomic(out / key, entries)
    return {key: len(entries) for key, entries in sorted(files.items())}
