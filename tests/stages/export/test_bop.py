"""The BOP export read by a loader written from BOP's format specification
(thodan/bop_toolkit, docs/bop_datasets_format.md), not from this program's code."""

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from manifests import read_manifest
from stages.common.tango import KEYPOINTS_M

SPLITS = ("test", "test_twin", "train_pbr")


def load_ply(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ASCII PLY: vertices (V, 3), normals (V, 3), faces (F, 3), as bop_toolkit's load_ply reads it."""
    lines = path.read_text().splitlines()
    assert lines[0] == "ply" and lines[1] == "format ascii 1.0"
    end = lines.index("end_header")
    header = lines[:end]
    vertices = int(next(line.split()[-1] for line in header if line.startswith("element vertex")))
    faces = int(next(line.split()[-1] for line in header if line.startswith("element face")))
    properties = [line.split()[-1] for line in header if line.startswith("property float")]
    assert properties == ["x", "y", "z", "nx", "ny", "nz"]
    data = np.array([[float(v) for v in line.split()] for line in lines[end + 1:end + 1 + vertices]])
    first_face = end + 1 + vertices
    face_rows = np.array([[int(v) for v in line.split()] for line in lines[first_face:first_face + faces]])
    assert (face_rows[:, 0] == 3).all()
    return data[:, :3], data[:, 3:], face_rows[:, 1:]


def project(points_mm, cam_k, cam_r, cam_t):
    """BOP's P_m2i = K [R | t]."""
    camera = np.asarray(points_mm) @ np.reshape(cam_r, (3, 3)).T + np.asarray(cam_t)
    pixels = camera @ np.reshape(cam_k, (3, 3)).T
    return pixels[:, :2] / pixels[:, 2:], camera[:, 2]


def load_scene(folder: Path) -> dict:
    """One scene as the specification defines it: three json files keyed by im_id, and the
    image, masks and depth of every im_id."""
    scene = {name: json.loads((folder / f"{name}.json").read_text())
             for name in ("scene_camera", "scene_gt", "scene_gt_info")}
    assert set(scene["scene_camera"]) == set(scene["scene_gt"]) == set(scene["scene_gt_info"])
    images = {}
    for key in scene["scene_gt"]:
        im_id = int(key)
        found = [folder / kind / f"{im_id:06d}.png" for kind in ("rgb", "gray")
                 if (folder / kind / f"{im_id:06d}.png").exists()]
        assert len(found) == 1, (folder, im_id)
        image = cv2.imread(str(found[0]), cv2.IMREAD_UNCHANGED)
        assert (image.ndim == 2) == (found[0].parent.name == "gray")
        masks = [cv2.imread(str(folder / kind / f"{im_id:06d}_{gt_id:06d}.png"), cv2.IMREAD_UNCHANGED)
                 for kind in ("mask", "mask_visib") for gt_id in range(len(scene["scene_gt"][key]))]
        depth_path = folder / "depth" / f"{im_id:06d}.png"
        depth = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED) if depth_path.exists() else None
        images[im_id] = {"image": image, "mask": masks[0], "mask_visib": masks[1], "depth": depth}
    scene["images"] = images
    return scene


@pytest.fixture(scope="module")
def dataset(exported):
    root = exported["bop"]
    scenes = {}
    for split in SPLITS:
        for folder in sorted((root / split).iterdir()):
            assert re.fullmatch(r"\d{6}", folder.name), folder
            scenes[(split, int(folder.name))] = load_scene(folder)
    return root, scenes


def test_root_files_follow_the_specification(dataset):
    root, scenes = dataset
    camera = json.loads((root / "camera.json").read_text())
    assert set(camera) >= {"cx", "cy", "fx", "fy", "width", "height", "depth_scale"}
    info = json.loads((root / "models" / "models_info.json").read_text())["1"]
    vertices, normals, faces = load_ply(root / "models" / "obj_000001.ply")
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    assert faces.max() < len(vertices)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    np.testing.assert_allclose([info["min_x"], info["min_y"], info["min_z"]], low, atol=1e-3)
    np.testing.assert_allclose([info["size_x"], info["size_y"], info["size_z"]], high - low, atol=1e-3)
    # mm: the full-scale Tango is about a metre across (its keypoints span 0.77 m of panel)
    assert 800 < info["diameter"] < 3000 and info["diameter"] >= np.linalg.norm(high - low) * 0.5
    eval_vertices, _, _ = load_ply(root / "models_eval" / "obj_000001.ply")
    assert len(eval_vertices) > 10 * len(vertices)
    np.testing.assert_allclose(eval_vertices.min(axis=0), low, atol=1e-3)
    targets = json.loads((root / "test_targets_bop19.json").read_text())
    assert targets and all(t["obj_id"] == 1 and t["inst_count"] == 1 for t in targets)
    tested = {(scene_id, im_id) for (split, scene_id), scene in scenes.items() if split == "test"
              for im_id in scene["images"]}
    assert {(t["scene_id"], t["im_id"]) for t in targets} == tested
    assert "obj_id 1" in (root / "dataset_info.md").read_text()


def test_every_split_has_its_scenes(dataset, rendered):
    _, scenes = dataset
    labels = read_manifest(rendered, "labels").to_pylist()
    assert {scene_id for split, scene_id in scenes if split == "test"} == {
        {"lightbox": 1, "sunlamp": 2}[r["domain"]] for r in labels}
    count = {split: sum(len(s["images"]) for (name, _), s in scenes.items() if name == split) for split in SPLITS}
    assert count == {"test": len(labels), "test_twin": read_manifest(rendered, "renders").num_rows,
                     "train_pbr": read_manifest(rendered, "train").num_rows}


def undistorted(keypoints_px, camera_matrix, dist):
    points = np.asarray(keypoints_px, float).reshape(-1, 1, 2)
    return cv2.undistortPointsIter(points, camera_matrix, dist, None, camera_matrix,
                                   (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)).reshape(-1, 2)


def test_keypoints_projected_through_cam_k_land_on_the_undistorted_keypoints(dataset, rendered):
    _, scenes = dataset
    calibration = json.loads((rendered.root / "calibration.json").read_text())["intrinsics"]
    dist = np.array(calibration["dist"], float)
    assert np.abs(dist).max() > 0  # the source images are distorted: the export must undo it
    rows = {"test": read_manifest(rendered, "labels").to_pylist(),
            "test_twin": read_manifest(rendered, "renders").to_pylist(),
            "train_pbr": read_manifest(rendered, "train").to_pylist()}
    errors = []
    for split, table in rows.items():
        by_pose = {tuple(np.round(r["r_Vo2To_vbs_true"], 9)): r for r in table}
        for (name, _), scene in scenes.items():
            if name != split:
                continue
            for key, (gt,) in scene["scene_gt"].items():
                row = by_pose[tuple(np.round(np.asarray(gt["cam_t_m2c"]) / 1000.0, 9))]
                cam_k = np.reshape(scene["scene_camera"][key]["cam_K"], (3, 3))
                projected, _ = project(KEYPOINTS_M * 1000.0, cam_k, gt["cam_R_m2c"], gt["cam_t_m2c"])
                expected = undistorted(row["keypoints_px"], cam_k, dist if split != "train_pbr" else
                                       _train_dist(rendered))
                errors.append(np.abs(projected - expected).max())
    assert len(errors) == sum(len(t) for t in rows.values())
    assert max(errors) < 0.5, max(errors)


def _train_dist(ws):
    from pipeline.config import load_config

    return load_config(None, ws.config_path).camera.dist_coeffs()


def test_masks_cover_the_projected_body_and_info_matches_them(dataset, exported):
    root, scenes = dataset
    vertices, _, _ = load_ply(root / "models" / "obj_000001.ply")
    body = KEYPOINTS_M[:8] * 1000.0
    for (split, _), scene in scenes.items():
        for key, (gt,) in scene["scene_gt"].items():
            images = scene["images"][int(key)]
            mask = images["mask"] > 0
            assert (images["mask_visib"] == images["mask"]).all()
            height, width = mask.shape
            cam_k = scene["scene_camera"][key]["cam_K"]
            corners, _ = project(body, cam_k, gt["cam_R_m2c"], gt["cam_t_m2c"])
            hull = np.zeros_like(mask, np.uint8)
            cv2.fillConvexPoly(hull, np.round(cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2)).astype(
                np.int32), 1)
            # the body's convex silhouette, a pixel in from its edge and a pixel out (the
            # antennas add thin lines outside it)
            inner = cv2.erode(hull, np.ones((3, 3), np.uint8)) > 0
            outer = cv2.dilate(hull, np.ones((3, 3), np.uint8)) > 0
            assert (mask & inner).sum() >= 0.995 * inner.sum() > 0
            assert (mask & ~outer).sum() < 0.1 * mask.sum()
            info = scene["scene_gt_info"][key][0]
            ys, xs = np.nonzero(mask)
            assert info["px_count_all"] == info["px_count_visib"] == mask.sum() > 0
            assert info["visib_fract"] == pytest.approx(info["px_count_visib"] / info["px_count_all"])
            assert info["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
            x, y, w, h = info["bbox_obj"]
            assert x <= xs.min() and y <= ys.min() and x + w >= xs.max() + 1 and y + h >= ys.max() + 1
            depth = images["depth"]
            if split == "test":
                assert depth is None and info["px_count_valid"] == 0
            else:  # depth in mm between the model's nearest and farthest points
                _, z = project(vertices, cam_k, gt["cam_R_m2c"], gt["cam_t_m2c"])
                scale = scene["scene_camera"][key]["depth_scale"]
                values = depth[mask].astype(float) * scale
                assert values.min() >= z.min() - 1 and values.max() <= z.max() + 1
                assert info["px_count_valid"] == mask.sum() and (depth[~mask] == 0).all()
            assert images["image"].shape[:2] == (height, width)
