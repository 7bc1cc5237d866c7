"""An evaluate worker: one ONNX Runtime session that scores batches of images sent to it
with their bytes (it never reads the workspace), in this process, a spawned one or a Ray
actor (``pipeline.engines``)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from stages.common import geometry as g
from stages.common.image_io import decode_image, to_uint8
from stages.common.pose_model import PnPSolution, PoseModel, decode_heatmaps, pose_from_keypoints
from stages.common.scores import score


class Scorer:
    """Scores batches of items (dicts with ``image_path``, ``image_bytes``, ``box`` and the
    label) with a model given by its bytes; the label camera (K (3, 3) px, dist (5,)) turns
    keypoints into poses."""

    def __init__(self, model: bytes, name: str, threads: int, camera_matrix: np.ndarray, dist: np.ndarray,
                 reprojection_fraction: float) -> None:
        self.model = PoseModel(model, threads, name)
        self.camera_matrix, self.dist = np.asarray(camera_matrix, float), np.asarray(dist, float)
        self.reprojection_fraction = reprojection_fraction

    def score(self, items: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """``predictions`` rows of a batch, in its order."""
        return predict(self.model, items, self.camera_matrix, self.dist, self.reprojection_fraction)


def open_scorer(model: bytes, name: str, threads: int, camera_matrix: np.ndarray, dist: np.ndarray,
                reprojection_fraction: float) -> Scorer:
    """Picklable factory for the engines."""
    return Scorer(model, name, threads, camera_matrix, dist, reprojection_fraction)


def predict(model: PoseModel, items: list[dict[str, Any]], camera_matrix: np.ndarray, dist: np.ndarray,
            reprojection_fraction: float) -> list[dict[str, Any]]:
    """Prediction rows for a batch of items."""
    started = time.perf_counter()
    tensors, image_from_input, widths = [], [], []
    for item in items:
        image = to_uint8(decode_image(item["image_bytes"], item["image_path"], "bgr"))  # 16-bit, float: by range
        tensor, affine = model.preprocess(image, np.asarray(item["box"]))
        tensors.append(tensor)
        image_from_input.append(affine)
        widths.append(image.shape[1])
    outputs = model.infer(np.stack(tensors))
    contract = model.contract
    solutions: list[PnPSolution | None] = []
    if contract.output == "pose":
        for q, t in zip(outputs[0], outputs[1], strict=True):
            direct = bool(np.all(np.isfinite(q)) and np.all(np.isfinite(t)) and np.linalg.norm(q) > 0)
            solutions.append(PnPSolution(g.quat_normalize(q), np.asarray(t, float), "direct", 0, float("nan"))
                             if direct else None)
    else:
        if contract.output == "heatmaps":
            points, confidences = decode_heatmaps(outputs[0], contract.width, contract.height)
        else:
            points = np.asarray(outputs[0], float)
            confidences = np.ones(points.shape[:2])
        for keypoints, confidence, affine, width in zip(points, confidences, image_from_input, widths, strict=True):
            in_image = keypoints @ affine[:2, :2].T + affine[:2, 2]
            solutions.append(pose_from_keypoints(in_image, contract.keypoints_m, camera_matrix, dist,
                                                 reprojection_fraction * width, confidence))
    seconds = (time.perf_counter() - started) / len(items)
    rows = []
    for item, solution in zip(items, solutions, strict=True):
        found = solution is not None
        if found:
            q, t = solution.q, solution.t
            numbers = {k: float(v) for k, v in score(q, t, item["q_true"], item["t_true"]).items()}
        else:
            q = t = None
            numbers = {"err_q_rad": float(np.pi), "err_t_norm": 1.0}
            numbers |= {"score_speed": np.pi + 1.0, "score_speedplus": np.pi + 1.0}
        keypoint_pose = found and solution.method != "direct"
        rows.append({"prediction_id": f"{item['domain']}:{item['sample_id']}", "sample_id": item["sample_id"],
                     "domain": item["domain"], "view": item["view"], "light": item["light"], "crop": contract.crop,
                     "pose_found": found, "pnp_method": solution.method if found else "none",
                     "pnp_inliers": solution.inliers if keypoint_pose else None,
                     "reprojection_rms_px": solution.rms_px if keypoint_pose else None,
                     "q_pred": q, "t_pred": t, **numbers, "seconds": seconds})
    return rows
