"""The evaluate stage: score an ONNX pose model on pairs of synthetic twins and testbed
captures that share their labels (the paper's Table 2 and Figure 12).

Every labelled capture is one ``lightbox`` or ``sunlamp`` image; its twin is one
``synthetic`` image. Both are scored against the label with the label camera. Writes the
``predictions`` manifest (per image) and the ``scores`` manifest (per domain and
configuration), and prints Table 2.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from rich.console import Console

from manifests import Workspace, open_sink, read_keys, read_manifest, write_part
from manifests import clear as clear_manifest
from manifests.integrity import sha256
from pipeline.config import Config
from pipeline.progress import track
from stages.common import geometry as g
from stages.common.image_io import read_image, to_uint8
from stages.common.pose_model import PoseModel, decode_heatmaps, pose_from_keypoints
from stages.common.scores import score
from stages.common.sidecars import calibrated_camera
from stages.evaluate.table import print_table2, summarise

REPOSITORY = Path(__file__).resolve().parents[2]


def model_path(config: Config) -> Path:
    """``evaluate.model``: absolute, relative to the current directory, or to the repository."""
    path = Path(config.evaluate.model).expanduser()
    if path.is_absolute() or path.exists():
        return path.resolve()
    return (REPOSITORY / path).resolve()


def _digest(path: Path) -> str:
    return sha256(path)[:16] if path.exists() else "missing"


def resolve(config: Config) -> tuple[tuple[str, ...], tuple[str, ...], dict[str, Any], tuple[str, ...]]:
    """(inputs, configuration sections, extra fingerprint content, outputs) of this stage
    (pipeline/registry.py): the model is fingerprinted by its bytes."""
    path = model_path(config)
    return ("labels", "renders", "captures"), ("evaluate",), {"model_digest": _digest(path)}, ("predictions", "scores")


def _items(workspace: Workspace) -> list[dict[str, Any]]:
    """One item per image to score: the testbed capture and the twin of every label."""
    labels = sorted(read_manifest(workspace, "labels").to_pylist(), key=lambda r: r["sample_id"])
    captures = {row["sample_id"]: row["image_path"] for row in read_manifest(workspace, "captures").to_pylist()}
    twins = {row["sample_id"]: row["image_path"] for row in read_manifest(workspace, "renders").to_pylist()}
    items = []
    for label in labels:
        common = {"sample_id": label["sample_id"], "view": label["view"], "light": label["domain"],
                  "q_true": label["q_vbs2tango_true"], "t_true": label["r_Vo2To_vbs_true"], "box": label["bbox_px"]}
        if label["sample_id"] in captures:
            items.append({**common, "domain": label["domain"], "image_path": captures[label["sample_id"]]})
        if label["sample_id"] in twins:
            items.append({**common, "domain": "synthetic", "image_path": twins[label["sample_id"]]})
    return items


def predict(model: PoseModel, workspace: Workspace, items: list[dict[str, Any]], camera_matrix: np.ndarray,
            dist: np.ndarray, reprojection_fraction: float) -> list[dict[str, Any]]:
    """Prediction rows for a batch of items."""
    started = time.perf_counter()
    tensors, image_from_input, widths = [], [], []
    for item in items:
        path = workspace.resolve(item["image_path"])
        image = to_uint8(read_image(path, "bgr"))  # 16-bit and float captures scaled by their range
        tensor, affine = model.preprocess(image, np.asarray(item["box"]))
        tensors.append(tensor)
        image_from_input.append(affine)
        widths.append(image.shape[1])
    outputs = model.infer(np.stack(tensors))
    contract = model.contract
    if contract.output == "pose":
        poses = list(zip(outputs[0], outputs[1], strict=True))
    else:
        if contract.output == "heatmaps":
            points, _ = decode_heatmaps(outputs[0], contract.width, contract.height)
        else:
            points = np.asarray(outputs[0], float)
        poses = []
        for keypoints, affine, width in zip(points, image_from_input, widths, strict=True):
            in_image = keypoints @ affine[:2, :2].T + affine[:2, 2]
            poses.append(pose_from_keypoints(in_image, contract.keypoints_m, camera_matrix, dist,
                                             reprojection_fraction * width))
    seconds = (time.perf_counter() - started) / len(items)
    rows = []
    for item, pose in zip(items, poses, strict=True):
        found = pose is not None and bool(np.all(np.isfinite(pose[0])) and np.all(np.isfinite(pose[1]))
                                          and np.linalg.norm(pose[0]) > 0)
        if found:
            q = g.quat_normalize(pose[0])
            t = np.asarray(pose[1], float)
            numbers = {k: float(v) for k, v in score(q, t, item["q_true"], item["t_true"]).items()}
        else:
            q = t = None
            numbers = {"err_q_rad": float(np.pi), "err_t_norm": 1.0}
            numbers |= {"score_speed": np.pi + 1.0, "score_speedplus": np.pi + 1.0}
        rows.append({"prediction_id": f"{item['domain']}:{item['sample_id']}", "sample_id": item["sample_id"],
                     "domain": item["domain"], "view": item["view"], "light": item["light"], "crop": contract.crop,
                     "pose_found": found, "q_pred": q, "t_pred": t, **numbers, "seconds": seconds})
    return rows


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Score every image missing from ``predictions``, then rewrite the ``scores`` summary."""
    path = model_path(config)
    model = PoseModel(path, threads=config.evaluate.threads)
    camera = calibrated_camera(workspace)
    done = read_keys(workspace, "predictions")
    items = [item for item in _items(workspace) if f"{item['domain']}:{item['sample_id']}" not in done]
    batch = config.evaluate.batch_size
    batches = [items[i:i + batch] for i in range(0, len(items), batch)]
    with open_sink(workspace, "predictions", config.run.part_rows) as sink:
        for chunk in track(batches, len(batches), f"evaluate {path.name} (batches of {batch})"):
            for row in predict(model, workspace, chunk, camera.camera_matrix, camera.dist,
                               config.evaluate.ransac_fraction):
                sink.add(row)
    predictions = read_manifest(workspace, "predictions")
    table = summarise(predictions.to_pylist())
    clear_manifest(workspace, "scores")  # a summary of all predictions: rewritten whole
    write_part(workspace, "scores", table, workspace.output_fingerprint("scores"))
    Console().print(print_table2(table, path.name, model.contract.crop))  # results: standard output
    return predictions
