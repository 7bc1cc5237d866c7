"""The BOP layout (thodan/bop_toolkit, docs/bop_datasets_format.md; docs/architecture.md
section 4): what bop_toolkit's loaders and projection read, without a distortion model.

::

    OUT/camera.json                      cx, cy, fx, fy, width, height, depth_scale (the labels' camera)
    OUT/models/obj_000001.ply            the target's mesh, mm, per-face normals; models_info.json
    OUT/models_eval/obj_000001.ply       the same surface subdivided to edges of at most 20 mm
    OUT/test_targets_bop19.json          [{scene_id, im_id, obj_id: 1, inst_count: 1}] of test/
    OUT/dataset_info.md
    OUT/test/000001/ (light boxes)  OUT/test/000002/ (sun lamp)       testbed captures
    OUT/test_twin/000001/, 000002/                                    their twins (same im_ids)
    OUT/train_pbr/000000/, 000001/, ...                               the training set, 1000 a scene
      gray/ or rgb/<im_id:06d>.png       UNDISTORTED to the scene's cam_K (BOP has no distortion)
      mask/, mask_visib/<im_id:06d>_000000.png   the model's silhouette at the label's pose
      depth/<im_id:06d>.png              synthetic sets only: uint16, mm = value * depth_scale
      scene_camera.json  scene_gt.json  scene_gt_info.json

The model frame is the target's body frame of the labels (Tango: origin on the body, not at
the bounding-box centre BOP's own datasets use), so ``cam_R_m2c``, ``cam_t_m2c`` are the
labels' rotation and translation (mm) unchanged. Only one object is in a scene and the
testbed's fixtures are not modelled, so ``mask_visib`` equals ``mask``.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from manifests.files import write_bytes_atomic, write_json_atomic
from manifests.schema import DOMAINS
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common.image_io import read_image, to_uint8, write_png_atomic
from stages.common.lens import LensCamera
from stages.common.surface import TargetSurfaces
from stages.common.target import Target

OBJ_ID = 1
IMAGES_PER_SCENE = 1000  # BOP's train_pbr scenes
DEPTH_SCALE_MM = 1.0  # uint16 depth in mm: 65 m of range, finer than the renders' geometry needs
EVAL_EDGE_MM = 20.0
SPLITS = {"testbed": "test", "twins": "test_twin", "train": "train_pbr"}


def place(export_set: str, domain: str, index: int) -> tuple[int, int]:
    """(scene_id, im_id) of the ``index``-th image of a set (testbed and twins: index within
    its light set-up; train: within the whole set)."""
    if export_set == "train":
        return index // IMAGES_PER_SCENE, index % IMAGES_PER_SCENE
    return DOMAINS.index(domain) + 1, index


def scene_dir(export_set: str, scene_id: int) -> str:
    return f"{SPLITS[export_set]}/{scene_id:06d}"


def cam_from_model_mm(q_vbs2tango_true: Any, r_vo2to_vbs_true: Any) -> np.ndarray:
    """The label's cam_from_target (4, 4) with the translation in mm."""
    return g.transform_from_qt(q_vbs2tango_true, np.asarray(r_vo2to_vbs_true, float) * 1000.0)


@lru_cache(maxsize=4)
def _undistort_maps(k: tuple[float, ...], dist: tuple[float, ...], width: int, height: int) -> tuple[Any, Any]:
    camera_matrix = np.array(k, float).reshape(3, 3)
    return cv2.initUndistortRectifyMap(camera_matrix, np.array(dist, float), None, camera_matrix, (width, height),
                                       cv2.CV_32FC1)


def undistort(image: np.ndarray, camera: LensCamera) -> np.ndarray:
    """The image as an ideal pinhole with the same ``K`` would have taken it (H, W[, C])."""
    maps = _undistort_maps(tuple(camera.camera_matrix.ravel()), tuple(camera.dist), camera.width, camera.height)
    return cv2.remap(image, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def write_image(out: Path, item: dict[str, Any], source: Path, camera: LensCamera, surfaces: TargetSurfaces
                ) -> str:
    """Undistorted image, masks and (synthetic sets) depth of one item; returns the image's
    path relative to ``out``."""
    image = read_image(source)
    if image.dtype not in (np.uint8, np.uint16):
        image = to_uint8(image)  # float captures (EXR): BOP images are 8- or 16-bit PNG
    folder = scene_dir(item["set"], item["scene_id"])
    kind = "gray" if image.ndim == 2 else "rgb"
    file = f"{folder}/{kind}/{item['im_id']:06d}.png"
    maps = surfaces.pinhole(g.transform_from_qt(item["q_vbs2tango_true"], item["r_Vo2To_vbs_true"]),
                            camera.camera_matrix, camera.width, camera.height)
    mask = maps.mask.astype(np.uint8) * 255
    for mask_kind in ("mask", "mask_visib"):
        write_png_atomic(out / folder / mask_kind / f"{item['im_id']:06d}_000000.png", mask)
    if item["set"] != "testbed":
        depth_mm = np.nan_to_num(maps.depth_m * 1000.0 / DEPTH_SCALE_MM, nan=0.0)
        write_png_atomic(out / folder / "depth" / f"{item['im_id']:06d}.png",
                         np.clip(np.rint(depth_mm), 0, 65535).astype(np.uint16))
    write_png_atomic(out / file, undistort(image, camera))
    return file


# ------------------------------------------------------------------------------- models
def _triangles_mm(target: Target) -> np.ndarray:
    """Every triangle of the target's mesh (F, 3, 3), mm, body frame."""
    triangles = [part.vertices[part.faces] for part in target.parts.values()]
    return np.concatenate(triangles) * 1000.0


def _subdivide(triangles: np.ndarray, max_edge_mm: float) -> np.ndarray:
    """Split every triangle into 4 until no edge is longer than ``max_edge_mm``."""
    done, todo = [], triangles
    while len(todo):
        edges = np.linalg.norm(todo - np.roll(todo, 1, axis=1), axis=2).max(axis=1)
        done.append(todo[edges <= max_edge_mm])
        big = todo[edges > max_edge_mm]
        a, b, c = big[:, 0], big[:, 1], big[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        todo = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return np.concatenate(done)


def ply_bytes(triangles: np.ndarray, name: str) -> bytes:
    """ASCII PLY of triangles (F, 3, 3) with per-face normals (3 vertices per face, so a
    flat face keeps its own normal), as BOP's models are read by ``inout.load_ply``."""
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    vertices = triangles.reshape(-1, 3)
    vertex_normals = np.repeat(normals, 3, axis=0)
    header = (f"ply\nformat ascii 1.0\ncomment SPEED+ builder: target {name}, full scale, mm, its body frame\n"
              f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float nx\nproperty float ny\nproperty float nz\n"
              f"element face {len(triangles)}\nproperty list uchar int vertex_indices\nend_header\n")
    rows = [f"{x:.4f} {y:.4f} {z:.4f} {nx:.6f} {ny:.6f} {nz:.6f}"
            for (x, y, z), (nx, ny, nz) in zip(vertices, vertex_normals, strict=True)]
    faces = [f"3 {3 * i} {3 * i + 1} {3 * i + 2}" for i in range(len(triangles))]
    return (header + "\n".join(rows + faces) + "\n").encode()


def model_info(triangles: np.ndarray) -> dict[str, float]:
    """BOP's models_info entry: diameter (largest vertex distance) and bounding box, mm."""
    points = np.unique(triangles.reshape(-1, 3).round(6), axis=0)
    differences = points[:, None, :] - points[None, :, :]
    low, high = points.min(axis=0), points.max(axis=0)
    return {"diameter": float(np.sqrt((differences**2).sum(axis=2).max())),
            "min_x": float(low[0]), "min_y": float(low[1]), "min_z": float(low[2]),
            "size_x": float(high[0] - low[0]), "size_y": float(high[1] - low[1]), "size_z": float(high[2] - low[2])}


def symmetries_mm(target: Target) -> dict[str, Any]:
    """BOP's ``symmetries_discrete`` (4 x 4 row-major, mm) and ``symmetries_continuous``
    (axis, offset mm) of the target folder's ``[symmetries]``; none when it declares none."""
    out: dict[str, Any] = {}
    if target.symmetries_discrete:
        scaled = [np.concatenate([m[:3, :3], m[:3, 3:] * 1000.0], axis=1) for m in target.symmetries_discrete]
        out["symmetries_discrete"] = [[float(v) for v in np.vstack([m, [0, 0, 0, 1]]).ravel()] for m in scaled]
    if target.symmetries_continuous:
        out["symmetries_continuous"] = [{"axis": [float(v) for v in axis], "offset": [float(v) * 1000 for v in offset]}
                                        for axis, offset in target.symmetries_continuous]
    return out


def write_models(out: Path, target: Target) -> None:
    triangles = _triangles_mm(target)
    write_bytes_atomic(out / "models" / f"obj_{OBJ_ID:06d}.ply", ply_bytes(triangles, target.name))
    write_bytes_atomic(out / "models_eval" / f"obj_{OBJ_ID:06d}.ply",
                       ply_bytes(_subdivide(triangles, EVAL_EDGE_MM), target.name))
    info = {str(OBJ_ID): {**model_info(triangles), **symmetries_mm(target)}}
    write_json_atomic(out / "models" / "models_info.json", info)
    write_json_atomic(out / "models_eval" / "models_info.json", info)


# --------------------------------------------------------------------------- annotations
def _bbox(xs: np.ndarray, ys: np.ndarray) -> list[int]:
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(np.floor(xs.min())), int(np.floor(ys.min()))
    return [x0, y0, int(np.floor(xs.max())) - x0 + 1, int(np.floor(ys.max())) - y0 + 1]


def gt_info(out: Path, item: dict[str, Any], camera_matrix: np.ndarray, vertices_mm: np.ndarray) -> dict[str, Any]:
    """scene_gt_info entry from the written mask (and depth): bbox_obj from the projected
    model (may reach outside the image, as BOP's), the rest from the silhouette."""
    folder = out / scene_dir(item["set"], item["scene_id"])
    mask_path = folder / "mask" / f"{item['im_id']:06d}_000000.png"
    written = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
    if written is None:  # recorded in the manifest, since removed from the export folder
        raise InputError(f"{mask_path}: missing or unreadable; rerun the same export command (its --format and "
                         "--out) with --force")
    mask = written > 0
    depth_path = folder / "depth" / f"{item['im_id']:06d}.png"
    valid = mask & (cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED) > 0) if depth_path.exists() else mask & False
    pose = cam_from_model_mm(item["q_vbs2tango_true"], item["r_Vo2To_vbs_true"])
    projected = g.project(pose, vertices_mm, camera_matrix, np.zeros(5))
    ys, xs = np.nonzero(mask)
    count = int(mask.sum())
    return {"bbox_obj": _bbox(projected[:, 0], projected[:, 1]), "bbox_visib": _bbox(xs, ys),
            "px_count_all": count, "px_count_valid": int(valid.sum()), "px_count_visib": count,
            "visib_fract": 1.0 if count else 0.0}


def write_annotations(out: Path, items: list[dict[str, Any]], cameras: dict[str, LensCamera], target: Target
                      ) -> dict[str, int]:
    """Root files and every scene's json from ``items`` (each with set, scene_id, im_id and
    the label's pose); ``cameras`` by set. Returns the image count per split."""
    write_models(out, target)
    labels_camera = cameras.get("testbed") or next(iter(cameras.values()))
    k = labels_camera.camera_matrix
    write_json_atomic(out / "camera.json", {"cx": float(k[0, 2]), "cy": float(k[1, 2]), "fx": float(k[0, 0]),
                                            "fy": float(k[1, 1]), "width": labels_camera.width,
                                            "height": labels_camera.height, "depth_scale": DEPTH_SCALE_MM})
    vertices = np.unique(_triangles_mm(target).reshape(-1, 3), axis=0)
    scenes: dict[str, dict[str, dict[str, Any]]] = {}
    for item in items:
        folder = scene_dir(item["set"], item["scene_id"])
        entry = scenes.setdefault(folder, {"scene_camera": {}, "scene_gt": {}, "scene_gt_info": {}})
        key = str(item["im_id"])
        camera_matrix = cameras[item["set"]].camera_matrix
        pose = cam_from_model_mm(item["q_vbs2tango_true"], item["r_Vo2To_vbs_true"])
        entry["scene_camera"][key] = {"cam_K": camera_matrix.ravel().tolist(), "depth_scale": DEPTH_SCALE_MM}
        entry["scene_gt"][key] = [{"cam_R_m2c": pose[:3, :3].ravel().tolist(), "cam_t_m2c": pose[:3, 3].tolist(),
                                   "obj_id": OBJ_ID}]
        entry["scene_gt_info"][key] = [gt_info(out, item, camera_matrix, vertices)]
    for folder, entry in sorted(scenes.items()):
        for name, content in entry.items():
            ordered = dict(sorted(content.items(), key=lambda kv: int(kv[0])))
            write_json_atomic(out / folder / f"{name}.json", ordered)
    targets = [{"im_id": item["im_id"], "inst_count": 1, "obj_id": OBJ_ID, "scene_id": item["scene_id"]}
               for item in sorted(items, key=lambda i: (i["scene_id"], i["im_id"])) if item["set"] == "testbed"]
    write_json_atomic(out / "test_targets_bop19.json", targets)
    counts = {split: sum(1 for i in items if i["set"] == s) for s, split in SPLITS.items()}
    write_bytes_atomic(out / "dataset_info.md", dataset_info(counts, target).encode())
    return {split: n for split, n in counts.items() if n}


def dataset_info(counts: dict[str, int], target: Target) -> str:
    lines = [f"# SPEED+ builder: the {target.name} mock-up on a TRON-like testbed", "",
             f"One object, obj_id 1: {target.name} (its target folder's mesh, full scale, mm). Its frame is the",
             "body frame of the labels (the target folder's; for Tango SPEED+'s, origin on the body, not the",
             "bounding-box centre).", "",
             "| split | images | what |", "|---|---|---|",
             f"| test | {counts['test']} | testbed captures: scene 1 light boxes, scene 2 sun lamp |",
             f"| test_twin | {counts['test_twin']} | Mitsuba twins of the test images (same scene and im_id) |",
             f"| train_pbr | {counts['train_pbr']} | synthetic training set, 1000 images a scene |", "",
             "Images are undistorted to each scene's cam_K. Poses are the testbed's fused labels (test), the",
             "same labels (test_twin) or the rendered poses (train_pbr). Masks are the model's silhouette at that",
             "pose (ray-cast at pixel centres); nothing occludes the model, so mask_visib = mask. Depth (uint16,",
             "mm = value * depth_scale) exists for the synthetic splits only. Symmetries: those the target",
             "folder declares (models_info.json), none otherwise."]
    return "\n".join(lines) + "\n"
