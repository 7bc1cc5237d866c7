"""Exports of the labels for ML teams: the SPEED+ layout and BOP's scene format.

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

from manifests.io import copy_atomic, read_manifest, write_json_atomic
from manifests.schema import DOMAINS
from manifests.workspace import Workspace
from stages.common import geometry as g


def camera_json(camera_matrix: np.ndarray, dist: np.ndarray, width: int, height: int,
                pixel_pitch_m: float) -> dict[str, Any]:
    """SPEED+ ``camera.json``: focal lengths in metres through the pixel pitch."""
    return {"Nu": int(width), "Nv": int(height), "ppx": pixel_pitch_m, "ppy": pixel_pitch_m,
            "fx": float(camera_matrix[0, 0] * pixel_pitch_m), "fy": float(camera_matrix[1, 1] * pixel_pitch_m),
            "ccx": float(camera_matrix[0, 2]), "ccy": float(camera_matrix[1, 2]),
            "cameraMatrix": camera_matrix.tolist(), "distCoeffs": [float(v) for v in dist]}


def _labels_and_images(workspace: Workspace) -> tuple[list[dict[str, Any]], dict[str, str]]:
    labels = sorted(read_manifest(workspace, "labels").to_pylist(), key=lambda r: r["sample_id"])
    images = {r["sample_id"]: r["image_path"] for r in read_manifest(workspace, "captures").to_pylist()}
    return labels, images


def export_speedplus(workspace: Workspace, out: Path, camera: dict[str, Any]) -> dict[str, int]:
    """Write the SPEED+ layout; returns the number of labels per domain."""
    labels, images = _labels_and_images(workspace)
    write_json_atomic(out / "camera.json", camera)
    counts: dict[str, int] = {}
    for domain in DOMAINS:
        chosen = [r for r in labels if r["domain"] == domain]
        if not chosen:
            continue
        entries = []
        for row in chosen:
            copy_atomic(workspace.resolve(images[row["sample_id"]]), out / domain / "images" / row["filename"])
            entries.append({"filename": row["filename"], "q_vbs2tango_true": list(row["q_vbs2tango_true"]),
                            "r_Vo2To_vbs_true": list(row["r_Vo2To_vbs_true"])})
        write_json_atomic(out / domain / "test.json", entries)
        counts[domain] = len(entries)
    return counts


def export_bop(workspace: Workspace, out: Path, camera_matrix: np.ndarray) -> dict[str, int]:
    """Write BOP scenes, one per domain (object 1 = Tango, full scale, millimetres)."""
    labels, images = _labels_and_images(workspace)
    counts: dict[str, int] = {}
    for domain in DOMAINS:
        chosen = [r for r in labels if r["domain"] == domain]
        if not chosen:
            continue
        scene_camera, scene_gt, ids = {}, {}, {}
        for im_id, row in enumerate(chosen):
            copy_atomic(workspace.resolve(images[row["sample_id"]]), out / domain / "rgb" / f"{im_id:06d}.png")
            rotation = g.quat_to_matrix(row["q_vbs2tango_true"])
            scene_camera[str(im_id)] = {"cam_K": camera_matrix.ravel().tolist(), "depth_scale": 1.0}
            scene_gt[str(im_id)] = [{"cam_R_m2c": rotation.ravel().tolist(),
                                     "cam_t_m2c": (np.asarray(row["r_Vo2To_vbs_true"]) * 1000.0).tolist(),
                                     "obj_id": 1}]
            ids[str(im_id)] = row["sample_id"]
        write_json_atomic(out / domain / "scene_camera.json", scene_camera)
        write_json_atomic(out / domain / "scene_gt.json", scene_gt)
        write_json_atomic(out / domain / "image_ids.json", ids)
        counts[domain] = len(chosen)
    return counts
