"""The export layouts (docs/architecture.md section 4): SPEED+ and BOP's scene format, each
a function that writes one image and one writing the annotation files from every label.

SPEED+ (``--format speedplus``)::

    OUT/camera.json                  Nu, Nv, ppx, ppy, fx, fy (metres), ccx, ccy, cameraMatrix, distCoeffs
    OUT/lightbox/images/<filename>   OUT/lightbox/test.json   [{filename, q_vbs2tango_true, r_Vo2To_vbs_true}]
    OUT/sunlamp/images/<filename>    OUT/sunlamp/test.json

The devkit projects body points with ``[quat2dcm(q).T | r]``; ``quat2dcm(q).T`` is the
Hamilton rotation matrix of ``q``, i.e. the rotation of ``cam_from_target``.

BOP (``--format bop``)::

    OUT/<domain>/rgb/<im_id:06d>.png, scene_camera.json ({im_id: {cam_K, depth_scale}}),
    scene_gt.json ({im_id: [{cam_R_m2c, cam_t_m2c (mm), obj_id: 1}]}), image_ids.json
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from manifests.files import copy_atomic, write_json_atomic
from manifests.schema import DOMAINS
from stages.common import geometry as g


def camera_json(camera_matrix: np.ndarray, dist: np.ndarray, width: int, height: int,
                pixel_pitch_m: float) -> dict[str, Any]:
    """SPEED+ ``camera.json``: focal lengths in metres through the pixel pitch."""
    return {"Nu": int(width), "Nv": int(height), "ppx": pixel_pitch_m, "ppy": pixel_pitch_m,
            "fx": float(camera_matrix[0, 0] * pixel_pitch_m), "fy": float(camera_matrix[1, 1] * pixel_pitch_m),
            "ccx": float(camera_matrix[0, 2]), "ccy": float(camera_matrix[1, 2]),
            "cameraMatrix": camera_matrix.tolist(), "distCoeffs": [float(v) for v in dist]}


def speedplus_image(label: dict[str, Any]) -> str:
    """Where a label's image goes in the SPEED+ layout (relative to the export folder)."""
    return f"{label['domain']}/images/{label['filename']}"


def write_speedplus(out: Path, labels: list[dict[str, Any]], camera: dict[str, Any]) -> dict[str, int]:
    """SPEED+ ``camera.json`` and ``<domain>/test.json`` of ``labels`` (in sample_id order);
    returns the number of labels per domain."""
    write_json_atomic(out / "camera.json", camera)
    counts: dict[str, int] = {}
    for domain in DOMAINS:
        chosen = [r for r in labels if r["domain"] == domain]
        if chosen:
            write_json_atomic(out / domain / "test.json", [
                {"filename": row["filename"], "q_vbs2tango_true": list(row["q_vbs2tango_true"]),
                 "r_Vo2To_vbs_true": list(row["r_Vo2To_vbs_true"])} for row in chosen])
            counts[domain] = len(chosen)
    return counts


def bop_image_ids(labels: list[dict[str, Any]]) -> dict[str, int]:
    """BOP image id of each label: its index among its domain's labels in sample_id order."""
    ids: dict[str, int] = {}
    for domain in DOMAINS:
        for im_id, row in enumerate(r for r in labels if r["domain"] == domain):
            ids[row["sample_id"]] = im_id
    return ids


def bop_image(label: dict[str, Any], im_id: int) -> str:
    return f"{label['domain']}/rgb/{im_id:06d}.png"


def write_bop(out: Path, labels: list[dict[str, Any]], camera_matrix: np.ndarray) -> dict[str, int]:
    """BOP scenes, one per domain (object 1 = Tango, full scale, millimetres)."""
    ids = bop_image_ids(labels)
    counts: dict[str, int] = {}
    for domain in DOMAINS:
        chosen = [r for r in labels if r["domain"] == domain]
        if not chosen:
            continue
        scene_camera, scene_gt, image_ids = {}, {}, {}
        for row in chosen:
            im_id = str(ids[row["sample_id"]])
            rotation = g.quat_to_matrix(row["q_vbs2tango_true"])
            scene_camera[im_id] = {"cam_K": camera_matrix.ravel().tolist(), "depth_scale": 1.0}
            scene_gt[im_id] = [{"cam_R_m2c": rotation.ravel().tolist(),
                                "cam_t_m2c": (np.asarray(row["r_Vo2To_vbs_true"]) * 1000.0).tolist(), "obj_id": 1}]
            image_ids[im_id] = row["sample_id"]
        write_json_atomic(out / domain / "scene_camera.json", scene_camera)
        write_json_atomic(out / domain / "scene_gt.json", scene_gt)
        write_json_atomic(out / domain / "image_ids.json", image_ids)
        counts[domain] = len(chosen)
    return counts


def copy_image(source: Path, destination: Path) -> None:
    copy_atomic(source, destination)
