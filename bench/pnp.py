"""PnP from heatmaps: time per image and accuracy of the highest-peak decoding
(``keypoint_pnp.pose_from_keypoints``) against the multi-peak one (``heatmap_pnp``) on
heatmaps where a share of the keypoints' highest peak sits on a wrong pose's keypoint and
the true one is the second peak, as a nearly symmetric body's views produce.

    python -m bench pnp [IMAGES]

Heatmaps are drawn (Gaussians, sigma 1 heatmap pixel, 48 x 48 for a 192 x 192 crop) from
seeded poses at 3-10 m in the default profile's training camera; 0, 3 or 6 of the 11
keypoints are fooled towards a pose turned by 20-180 deg.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from bench.common import report
from pipeline.config import load_config
from stages.common import geometry as g
from stages.common import tango
from stages.common.cameras import train_camera
from stages.common.heatmap_pnp import poses_from_heatmaps
from stages.common.keypoint_pnp import decode_heatmaps, pose_from_keypoints
from stages.common.model_contract import CROP_MARGIN, ModelContract
from stages.common.model_input import apply_affine

SIZE, STRIDE = 192, 4


def _to_heatmap(pixels: np.ndarray, image_from_input: np.ndarray) -> np.ndarray:
    """Image pixels (K, 2) -> heatmap pixels of the crop (centres spread evenly over the input)."""
    in_input = (pixels - image_from_input[:2, 2]) / image_from_input[0, 0]
    return (in_input + 0.5) / STRIDE - 0.5


def _case(rng: np.random.Generator, camera_matrix: np.ndarray, dist: np.ndarray,
          fooled: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(heatmaps (11, 48, 48), image_from_input (3, 3), true q (4,)) of one drawn view."""
    q_true = g.random_quats(rng, 1)[0]
    t = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(3, 10)])
    pixels = g.project(g.transform_from_qt(q_true, t), tango.KEYPOINTS_M, camera_matrix, dist)
    axis = rng.normal(size=3)
    turn = g.rotvec_to_quat(axis / np.linalg.norm(axis) * np.radians(rng.uniform(20, 180)))
    wrong = g.project(g.transform_from_qt(g.quat_multiply(q_true, turn), t), tango.KEYPOINTS_M, camera_matrix, dist)
    low, high = pixels.min(axis=0), pixels.max(axis=0)
    side = CROP_MARGIN * (high - low).max()
    corner = (low + high) / 2 - side / 2
    scale = side / SIZE
    image_from_input = np.array([[scale, 0, corner[0] + 0.5 * scale - 0.5], [0, scale, corner[1] + 0.5 * scale - 0.5],
                                 [0, 0, 1.0]])
    # image pixels -> input pixels -> heatmap pixels (centres spread evenly over the input)
    ys, xs = np.mgrid[0:SIZE // STRIDE, 0:SIZE // STRIDE]
    heatmaps = np.zeros((11, SIZE // STRIDE, SIZE // STRIDE), np.float32)
    pairs = zip(_to_heatmap(pixels, image_from_input), _to_heatmap(wrong, image_from_input), strict=True)
    for keypoint, (right, mistaken) in enumerate(pairs):
        is_fooled = keypoint < fooled
        for centre, height in ((right, 0.6 if is_fooled else 0.9), (mistaken, 1.0 if is_fooled else 0.0)):
            heatmaps[keypoint] += height * np.exp(-((xs - centre[0]) ** 2 + (ys - centre[1]) ** 2) / 2.0)
    heatmaps += rng.normal(0, 0.02, heatmaps.shape).astype(np.float32)
    return heatmaps, image_from_input, q_true


def main(*args: str) -> None:
    images = int(args[0]) if args else 100
    config = load_config("default")
    camera = train_camera(config)
    camera_matrix, dist = camera.camera_matrix, camera.dist
    contract = ModelContract(SIZE, SIZE, "rgb", (0.5,) * 3, (0.25,) * 3, "heatmaps", tango.KEYPOINTS_M.copy(),
                             "oracle_box")
    threshold = 0.01 * config.camera.width_px
    rows = []
    for fooled in (0, 3, 6):
        rng = np.random.default_rng(fooled)
        cases = [_case(rng, camera_matrix, dist, fooled) for _ in range(images)]
        for name in ("highest peaks", "3 peaks per keypoint"):
            started = time.perf_counter()
            errors = []
            for heatmaps, image_from_input, q_true in cases:
                if name == "highest peaks":
                    points, confidence = decode_heatmaps(heatmaps[None], SIZE, SIZE)
                    solution = pose_from_keypoints(apply_affine(image_from_input, points[0]), tango.KEYPOINTS_M,
                                                   camera_matrix, dist, threshold, confidence[0])
                else:
                    solution = poses_from_heatmaps(heatmaps[None], [image_from_input], contract, camera_matrix,
                                                   dist, [threshold])[0][0]
                errors.append(np.degrees(g.quat_angular_distance(solution.q, q_true)))
            seconds = (time.perf_counter() - started) / images
            errors = np.array(errors)
            rows.append({"fooled keypoints": fooled, "decoding": name, "ms_per_image": 1000 * seconds,
                         "median_rotation_error_deg": float(np.median(errors)),
                         "share_off_10_deg": float(np.mean(errors > 10))})
    report("pnp", f"PnP from heatmaps: {images} drawn views per row, highest peaks vs 3 peaks per keypoint", rows)


if __name__ == "__main__":
    main(*sys.argv[1:])
