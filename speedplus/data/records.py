"""One joined record per labelled image, from a workspace (labels with their capture, twin,
mask and ground-truth EXR) or from a SPEED+ export (camera.json and the domains' jsons)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from manifests import Workspace, read_manifest
from manifests.sidecars import read_calibration
from speedplus.errors import InputError

SETS = ("testbed", "twins")


@dataclass(frozen=True)
class Sample:
    """A labelled image: where its files are (absolute paths; None when it has none), its
    pose and camera. Arrays: q (4,), r (3,) m full scale, keypoints (K, 2) px (distorted),
    bbox (4,) px, camera_matrix (3, 3) px, dist (5,); sigmas null outside a workspace."""

    sample_id: str
    set: str  # testbed, twins, or the export's domain folder
    domain: str  # lightbox, sunlamp, or synthetic
    image: Path
    mask: Path | None
    ground_truth: Path | None  # the twin's EXR (docs/formats.md)
    q_vbs2tango_true: np.ndarray
    r_Vo2To_vbs_true: np.ndarray  # noqa: N815 - SPEED+'s name
    keypoints_px: np.ndarray | None
    bbox_px: np.ndarray | None
    sigma_t_m: np.ndarray | None
    sigma_r_rad: float | None
    camera_matrix: np.ndarray
    dist: np.ndarray


def samples(root: str | Path, sets: tuple[str, ...] = SETS) -> list[Sample]:
    """Every labelled image under ``root``: a workspace (``sets``: testbed captures, twins) or
    a SPEED+ export (``sets``: its domain folders, e.g. lightbox, sunlamp, twins, synthetic;
    the defaults take every domain there is), in sample_id order."""
    root = Path(root)
    if (root / "manifests" / "labels").is_dir():
        return _workspace(Workspace(root), sets)
    if (root / "camera.json").is_file():
        return _export(root, None if sets == SETS else sets)
    raise InputError(f"{root}: neither a workspace (manifests/labels) nor a SPEED+ export (camera.json)")


def _workspace(workspace: Workspace, sets: tuple[str, ...]) -> list[Sample]:
    unknown = set(sets) - set(SETS)
    if unknown:
        raise InputError(f"sets {sorted(unknown)}: a workspace's labelled images are testbed and twins")
    intrinsics = read_calibration(workspace).intrinsics
    camera, dist = np.array(intrinsics.camera_matrix, float), np.array(intrinsics.dist, float)
    labels = sorted(read_manifest(workspace, "labels").to_pylist(), key=lambda r: r["sample_id"])
    sources = {}
    if "testbed" in sets:
        sources["testbed"] = {r["sample_id"]: r for r in read_manifest(workspace, "captures").to_pylist()}
    if "twins" in sets:
        sources["twins"] = {r["sample_id"]: r for r in read_manifest(workspace, "renders").to_pylist()}
    out = []
    for label in labels:
        for name in sets:
            row = sources[name].get(label["sample_id"])
            if row is None:  # a twin render refused (render's rejected.json says why)
                continue
            twin = name == "twins"
            out.append(Sample(
                label["sample_id"], name, "synthetic" if twin else label["domain"],
                workspace.root / row["image_path"], workspace.root / row["mask_path"] if twin else None,
                workspace.root / row["ground_truth_path"] if twin and row["ground_truth_path"] else None,
                np.asarray(label["q_vbs2tango_true"], float), np.asarray(label["r_Vo2To_vbs_true"], float),
                np.asarray(label["keypoints_px"], float), np.asarray(label["bbox_px"], float),
                np.asarray(label["sigma_t_m"], float), float(label["sigma_r_rad"]), camera, dist))
    return out


def _export(root: Path, domains: tuple[str, ...] | None) -> list[Sample]:
    camera = json.loads((root / "camera.json").read_text())
    matrix, dist = np.array(camera["cameraMatrix"], float), np.array(camera["distCoeffs"], float)
    folders = domains or tuple(sorted(p.name for p in root.iterdir() if p.is_dir() and (p / "images").is_dir()))
    out = []
    for folder in folders:
        files = sorted((root / folder).glob("*.json"))
        if not files:
            raise InputError(f"{root / folder}: no annotation json (test.json, train.json, validation.json)")
        for path in files:
            for index, entry in enumerate(_entries(path)):
                image = (root / folder / "images" / entry["filename"]).resolve()
                if root.resolve() not in image.parents:
                    raise InputError(f"{path}: entry {index}: filename {entry['filename']!r} leaves the export folder")
                out.append(Sample(Path(entry["filename"]).stem, folder,
                                  "synthetic" if folder in ("synthetic", "twins") else folder, image, None, None,
                                  np.asarray(entry["q_vbs2tango_true"], float),
                                  np.asarray(entry["r_Vo2To_vbs_true"], float), None, None, None, None, matrix, dist))
    return sorted(out, key=lambda s: (s.sample_id, s.set))


def _entries(path: Path) -> list[dict]:
    """A SPEED+ json's entries, each checked for its filename and pose; else an InputError
    naming the file, the entry and the key."""
    try:
        entries = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise InputError(f"{path}: not a readable JSON list ({error})") from None
    if not isinstance(entries, list):
        raise InputError(f"{path}: expected a list of {{filename, q_vbs2tango_true, r_Vo2To_vbs_true}}")
    for index, entry in enumerate(entries):
        for key, size in (("filename", None), ("q_vbs2tango_true", 4), ("r_Vo2To_vbs_true", 3)):
            value = entry.get(key) if isinstance(entry, dict) else None
            good = isinstance(value, str) if size is None else (
                isinstance(value, list) and len(value) == size
                and all(isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) for v in value))
            if not good:
                raise InputError(f"{path}: entry {index}: key {key}: expected "
                                 f"{'a file name' if size is None else f'{size} finite numbers'}, got {value!r}")
    return entries
