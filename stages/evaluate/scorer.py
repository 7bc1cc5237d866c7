"""An evaluate worker: one ONNX Runtime session that scores batches of images sent to it
with their bytes (it never reads the workspace), in this process, a spawned one or a Ray
actor (``core.engines``)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.engines import reserved_cpus
from stages.common import geometry as g
from stages.common.detector import Detector
from stages.common.heatmap_pnp import explained_value, poses_from_heatmaps
from stages.common.image_io import decode_image, to_uint8
from stages.common.keypoint_pnp import PnPSolution, plausible, pose_from_keypoints
from stages.common.model_contract import CROP_MARGIN
from stages.common.model_input import apply_affine, points_box
from stages.common.pose_model import PoseModel
from stages.common.pose_support import refusal
from stages.common.scores import score


@dataclass(frozen=True)
class Decoding:
    """How a model's outputs become poses (the ``evaluate`` keys of the same names)."""

    #: RANSAC's inlier threshold, as a fraction of the image width
    ransac_fraction: float
    #: a model that asks for it sees each crop at four quarter turns
    turns: bool = True
    #: seed of RANSAC's draws
    ransac_seed: int = 0
    #: the final pass is decoded with this many seeds (ransac_seed, ransac_seed + 1, ...): the
    #: row's pose is the first's; the others' scores carry the decoder's spread into the intervals
    seeds: int = 1


class Scorer:
    """Scores batches of items (dicts with ``image_path``, ``image_bytes``, ``box`` and the
    label) with a model given by its bytes; the label camera (K (3, 3) px, dist (5,)) turns
    keypoints into poses. ``threads``: ONNX Runtime's; negative: the driver's share of the
    cores for each worker, unless this worker runs on a cluster that reserved it CPUs."""

    def __init__(self, model: bytes, name: str, threads: int, camera_matrix: np.ndarray, dist: np.ndarray,
                 decoding: Decoding, detector: bytes | None = None) -> None:
        threads = threads if threads > 0 else reserved_cpus(-threads)
        self.model = PoseModel(model, threads, name)
        self.detector = None if detector is None else Detector(detector, threads)
        self.camera_matrix, self.dist = np.asarray(camera_matrix, float), np.asarray(dist, float)
        self.decoding = decoding

    def score(self, items: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """``predictions`` rows of a batch, in its order."""
        return predict(self.model, items, self.camera_matrix, self.dist, self.decoding, self.detector)


def open_scorer(model: bytes, name: str, threads: int, camera_matrix: np.ndarray, dist: np.ndarray,
                decoding: Decoding, detector: bytes | None = None) -> Scorer:
    """Picklable factory for the engines."""
    return Scorer(model, name, threads, camera_matrix, dist, decoding, detector)


#: passes of the self crop: the search over windows, then twice around what the previous pass found
SELF_PASSES = 3
#: window sides of the self crop's search, as fractions of the image's larger side; windows
#: overlap by half. A model of oracle crops sees a target of the size it was trained on in
#: one of them (a whole-image pass alone found boxes of IoU 0.16 on the default profile)
SEARCH_SIDES = (1.0, 0.67, 0.45, 0.3, 0.2)
#: windows of the search whose poses are compared (the most confident ones)
SEARCH_FINALISTS = 5


def search_windows(width: int, height: int) -> list[np.ndarray]:
    """Square windows (x_min, y_min, x_max, y_max) [px] over an image, at every side of
    ``SEARCH_SIDES``, overlapping by half, covering the image."""
    windows = []
    for fraction in SEARCH_SIDES:
        side = fraction * max(width, height)
        starts = []
        for extent in (width, height):
            count = max(1, int(np.ceil((extent - side) / (side / 2))) + 1)
            starts.append(np.linspace(0.0, max(0.0, extent - side), count) if count > 1
                          else np.array([(extent - side) / 2]))
        windows += [np.array([x, y, x + side, y + side]) for y in starts[1] for x in starts[0]]
    return windows


def _box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boxes (x_min, y_min, x_max, y_max) [px]."""
    width = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    height = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = width * height
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def _search(model: PoseModel, image: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
            decoding: Decoding) -> np.ndarray:
    """The box of the self crop's first pass: the model on every window of
    ``search_windows``; of the ``SEARCH_FINALISTS`` windows whose keypoints are most
    confident (mean heatmap peak), the one whose pose (of the size the window implies)
    explains the most heatmap value is where the target is, and the keypoints reprojected at
    that pose span the box the pass found."""
    height, width = image.shape[:2]
    reprojection_px = decoding.ransac_fraction * width
    windows = search_windows(width, height)
    # the oracle crop is CROP_MARGIN times the box: a box of 1/CROP_MARGIN of a window crops that window
    centres = [(w[:2] + w[2:]) / 2 for w in windows]
    boxes = [np.concatenate([c - (w[2] - w[0]) / (2 * CROP_MARGIN), c + (w[2] - w[0]) / (2 * CROP_MARGIN)])
             for c, w in zip(centres, windows, strict=True)]
    tensors, affines = model.preprocess([image] * len(boxes), boxes)
    # one pass a window, never the quarter turns: this only has to say where the target is
    heatmaps = model.infer(tensors, turns=False)[0]
    confidence = heatmaps.reshape(*heatmaps.shape[:2], -1).max(axis=-1).mean(axis=1)
    finalists = np.argsort(-confidence, kind="stable")[:SEARCH_FINALISTS]
    solutions, peaks = poses_from_heatmaps(heatmaps[finalists], [affines[i] for i in finalists], model.contract,
                                           camera_matrix, dist, [reprojection_px] * len(finalists),
                                           decoding.ransac_seed)
    values = [explained_value(solution, heatmaps[i], affines[i], model.contract, camera_matrix, dist,
                              reprojection_px) for solution, i in zip(solutions, finalists, strict=True)]
    best = int(np.argmax(values))  # the first, most confident, on ties
    return _found_box(model, solutions[best], peaks[best], camera_matrix, dist, width, height)


def _solve(model: PoseModel, images: list[np.ndarray], boxes: list[np.ndarray], camera_matrix: np.ndarray,
           dist: np.ndarray, decoding: Decoding, seeds: int = 1) -> tuple[list[list[PnPSolution | None]],
                                                                         list[np.ndarray]]:
    """One pass of the model on crops around ``boxes`` (the contract's crop), its heatmaps
    averaged over quarter turns when the model asks for it and ``turns``: the poses under
    each of ``seeds`` RANSAC seeds (the first ``decoding.ransac_seed``; a decoding that
    draws nothing gives the same poses for each), and the keypoints (K, 2) in image pixels."""
    solutions, keypoints, heatmaps, affines = _solve_once(model, images, boxes, camera_matrix, dist, decoding)
    by_seed = [solutions]
    if model.contract.output == "heatmaps" and seeds > 1:
        thresholds = [decoding.ransac_fraction * image.shape[1] for image in images]
        by_seed += [poses_from_heatmaps(heatmaps, affines, model.contract, camera_matrix, dist, thresholds,
                                        decoding.ransac_seed + offset)[0] for offset in range(1, seeds)]
    return by_seed + [solutions] * (seeds - len(by_seed)), keypoints


def _solve_once(model: PoseModel, images: list[np.ndarray], boxes: list[np.ndarray], camera_matrix: np.ndarray,
                dist: np.ndarray, decoding: Decoding) -> tuple[list[PnPSolution | None], list[np.ndarray],
                                                               np.ndarray, list[np.ndarray]]:
    """``_solve`` under the one seed ``decoding.ransac_seed``, with the model's first output
    and the crops' input-to-image maps."""
    contract = model.contract
    tensors, affines = model.preprocess(images, boxes)
    outputs = model.infer(tensors, decoding.turns)
    if contract.output == "pose":
        solutions = []
        for q, t in zip(outputs[0], outputs[1], strict=True):
            direct = bool(np.all(np.isfinite(q)) and np.all(np.isfinite(t)) and np.linalg.norm(q) > 0)
            solutions.append(PnPSolution(g.quat_normalize(q), np.asarray(t, float), "direct", 0, float("nan"))
                             if direct else None)
        return solutions, [np.full((len(contract.keypoints_m), 2), np.nan)] * len(images), outputs[0], affines
    if contract.output == "heatmaps":
        solutions, in_images = poses_from_heatmaps(outputs[0], affines, contract, camera_matrix, dist,
                                                   [decoding.ransac_fraction * image.shape[1] for image in images],
                                                   decoding.ransac_seed)
        return solutions, list(in_images), outputs[0], affines
    points = np.asarray(outputs[0], float)
    confidences = np.ones(points.shape[:2])
    solutions, in_images = [], []
    for keypoints, confidence, affine, image in zip(points, confidences, affines, images, strict=True):
        in_image = apply_affine(affine, keypoints)
        in_images.append(in_image)
        solutions.append(pose_from_keypoints(in_image, contract.keypoints_m, camera_matrix, dist,
                                             decoding.ransac_fraction * image.shape[1], confidence))
    return solutions, in_images, outputs[0], affines


def _found_box(model: PoseModel, solution: PnPSolution | None, keypoints: np.ndarray, camera_matrix: np.ndarray,
               dist: np.ndarray, width: int, height: int) -> np.ndarray:
    """The box a pass found: the model's keypoints reprojected at its pose (robust to a few
    wild keypoints) when that pose is plausible, else the finite keypoints themselves, else
    the whole image."""
    if solution is not None and plausible(solution.t, model.contract.keypoints_m, camera_matrix):
        points = g.project(g.transform_from_qt(solution.q, solution.t), model.contract.keypoints_m, camera_matrix,
                           dist)
    else:
        points = keypoints[np.all(np.isfinite(keypoints), axis=1)]
    if len(points) == 0 or not np.all(np.isfinite(points)):
        return np.array([0.0, 0.0, width - 1.0, height - 1.0])
    box = points_box(points)
    # a crop stays near the image, however wild the pass was
    return np.clip(box, [-width, -height, -width, -height], [2 * width, 2 * height, 2 * width, 2 * height])


def _first_boxes(model: PoseModel, images: list[np.ndarray], labelled: list[np.ndarray], crops: list[str],
                 camera_matrix: np.ndarray, dist: np.ndarray, decoding: Decoding,
                 detector: Detector | None) -> list[np.ndarray]:
    """The box of each item's first pass: the label's for the contract's crop; for ``self``,
    the detector's box, else the model's own search, else (a model that cannot search) the
    whole image."""
    own = [index for index, crop in enumerate(crops) if crop == "self"]
    found = dict(zip(own, detector.boxes([images[i] for i in own])[0], strict=True)) \
        if detector is not None and own else {}
    searchable = model.contract.crop == "oracle_box" and model.contract.output == "heatmaps"
    boxes = []
    for index, (image, box, crop) in enumerate(zip(images, labelled, crops, strict=True)):
        if crop != "self":
            boxes.append(box)
        elif index in found:
            boxes.append(found[index])
        elif searchable:
            boxes.append(_search(model, image, camera_matrix, dist, decoding))
        else:
            boxes.append(np.array([0.0, 0.0, image.shape[1] - 1.0, image.shape[0] - 1.0]))
    return boxes


def predict(model: PoseModel, items: list[dict[str, Any]], camera_matrix: np.ndarray, dist: np.ndarray,
            decoding: Decoding, detector: Detector | None = None) -> list[dict[str, Any]]:
    """Prediction rows for a batch of items, each scored with its ``crop``: the contract's
    (``full``, or ``oracle_box`` from the label's box), or ``self``: the model's own crop,
    started by the detector's box (or a search over windows of the whole image,
    ``_search``), then ``SELF_PASSES - 1`` passes, each around what the last one found."""
    started = time.perf_counter()
    images = [to_uint8(decode_image(item["image_bytes"], item["image_path"], "bgr")) for item in items]
    labelled = [np.asarray(item["box"], float) for item in items]
    crops = [item.get("crop", model.contract.crop) for item in items]
    searchable = model.contract.crop == "oracle_box" and model.contract.output == "heatmaps"
    boxes = _first_boxes(model, images, labelled, crops, camera_matrix, dist, decoding, detector)
    # the detector's box or the search is the self crop's first pass; without them, the whole image
    passes = (SELF_PASSES - 1 if searchable or detector is not None else SELF_PASSES) if "self" in crops else 1
    for index in range(passes):
        by_seed, keypoints = _solve(model, images, boxes, camera_matrix, dist, decoding,
                                    decoding.seeds if index == passes - 1 else 1)
        solutions = by_seed[0]
        if index < passes - 1:
            boxes = [_found_box(model, solution, points, camera_matrix, dist, image.shape[1], image.shape[0])
                     if crop == "self" else box
                     for solution, points, image, crop, box in zip(solutions, keypoints, images, crops, boxes,
                                                                    strict=True)]
    seconds = (time.perf_counter() - started) / len(items)
    rows = []
    for index, (item, solution, crop, box, label_box, image) in enumerate(zip(items, solutions, crops, boxes, labelled,
                                                                              images, strict=True)):
        seen = None if crop == "full" else box
        refused, numbers = _scored(solution, item, model, seen, camera_matrix, dist, image.shape)
        found = solution is not None and refused is None
        draws = [numbers] + [_scored(other[index], item, model, seen, camera_matrix, dist, image.shape)[1]
                             for other in by_seed[1:]]
        keypoint_pose = found and solution.method != "direct"
        rows.append({"prediction_id": f"{item['model']}:{crop}:{item['domain']}:{item['sample_id']}",
                     "model": item["model"], "sample_id": item["sample_id"], "domain": item["domain"],
                     "view": item["view"], "light": item["light"], "crop": crop,
                     "box_iou": _box_iou(box, label_box) if crop == "self" else None,
                     "pose_found": found, "pose_refused": refused,
                     "pnp_method": solution.method if found else "none",
                     "pnp_inliers": solution.inliers if keypoint_pose else None,
                     "reprojection_rms_px": solution.rms_px if keypoint_pose else None,
                     "q_pred": solution.q if found else None, "t_pred": solution.t if found else None,
                     **numbers, "score_speed_seeds": [d["score_speed"] for d in draws],
                     "score_speedplus_seeds": [d["score_speedplus"] for d in draws], "seconds": seconds})
    return rows


def _scored(solution: PnPSolution | None, item: dict[str, Any], model: PoseModel, box: np.ndarray | None,
            camera_matrix: np.ndarray, dist: np.ndarray, shape: tuple[int, ...]) -> tuple[str | None, dict[str, float]]:
    """Why the image cannot support ``solution`` (None: it can) and its scores: a pose
    refused or missing scores the worst case, ``e_q = pi``, ``e_t = 1`` (stages/common/pose_support.py)."""
    refused = None if solution is None else refusal(solution, model.contract.keypoints_m, box, camera_matrix, dist,
                                                    shape[1], shape[0])
    if solution is not None and refused is None:
        return None, {k: float(v) for k, v in score(solution.q, solution.t, item["q_true"], item["t_true"]).items()}
    return refused, {"err_q_rad": float(np.pi), "err_t_norm": 1.0, "score_speed": np.pi + 1.0,
                     "score_speedplus": np.pi + 1.0}
