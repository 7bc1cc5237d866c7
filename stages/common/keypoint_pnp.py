"""From a model's outputs to a pose: heatmap peaks to sub-pixel keypoints, then
keypoints to ``cam_from_target`` by AP3P inside RANSAC and Levenberg-Marquardt refinement
on the inliers, with the label camera (intrinsics and distortion); without a consensus, by
EPnP on every point and a confidence-weighted refinement (``pose_from_keypoints``): finite
outputs always give a pose, which ``evaluate``'s support test may then refuse. Heatmap
outputs keep several peaks per keypoint (``stages.common.heatmap_pnp``), which shares
these functions. Lepetit, Moreno-Noguer and Fua, "EPnP", IJCV 2009; Ke and Roumeliotis,
"An efficient algebraic solution to the perspective-three-point problem", CVPR 2017."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stages.common import geometry as g

#: keypoints that must agree with a RANSAC pose for it to stand
MIN_CONSENSUS = 5


def parabola_offset(lo: np.ndarray, mid: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sub-pixel position of a peak from its value and its two neighbours, in [-0.5, 0.5]."""
    curvature = lo - 2 * mid + hi
    safe = np.where(np.abs(curvature) > 1e-12, curvature, -1.0)
    return np.clip(np.where(np.abs(curvature) > 1e-12, 0.5 * (lo - hi) / safe, 0.0), -0.5, 0.5)


def decode_heatmaps(heatmaps: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (N, K, 2) in input pixels and confidences (N, K) from heatmaps (N, K, h, w):
    the peak, refined by a parabola through its neighbours in x and in y."""
    n, k, h, w = heatmaps.shape
    ys, xs = np.divmod(heatmaps.reshape(n, k, -1).argmax(axis=-1), w)
    return peak_positions(heatmaps, ys, xs, width, height)


def peak_positions(heatmaps: np.ndarray, ys: np.ndarray, xs: np.ndarray, width: int,
                   height: int) -> tuple[np.ndarray, np.ndarray]:
    """Input-pixel positions (N, K, ..., 2) and values (N, K, ...) of heatmap pixels (ys, xs)
    (N, K, ...) of heatmaps (N, K, h, w) (a W x H input), each refined by a parabola through
    its neighbours in x and in y (not at the border)."""
    n, k, h, w = heatmaps.shape
    trailing = (1,) * (ys.ndim - 2)
    i, j = np.arange(n).reshape(n, 1, *trailing), np.arange(k).reshape(1, k, *trailing)
    peak = heatmaps[i, j, ys, xs]
    left, right = heatmaps[i, j, ys, np.maximum(xs - 1, 0)], heatmaps[i, j, ys, np.minimum(xs + 1, w - 1)]
    up, down = heatmaps[i, j, np.maximum(ys - 1, 0), xs], heatmaps[i, j, np.minimum(ys + 1, h - 1), xs]
    x = xs + parabola_offset(left, peak, right) * ((xs > 0) & (xs < w - 1))
    y = ys + parabola_offset(up, peak, down) * ((ys > 0) & (ys < h - 1))
    points = np.stack([(x + 0.5) * width / w - 0.5, (y + 0.5) * height / h - 0.5], axis=-1)
    return points, peak


#: how a prediction's pose was found: AP3P inside RANSAC, EPnP on all points (RANSAC found no
#: consensus), given by the model itself (``speedplus.output=pose``), or not at all
PNP_METHODS = ("ransac", "all_points", "direct", "none")


@dataclass(frozen=True)
class PnPSolution:
    """A pose recovered from keypoints: ``q`` (4,) and ``t`` (3,) [m] of cam_from_target,
    ``method`` (``PNP_METHODS``), the keypoints within the RANSAC threshold of it
    (``inliers``) and the reprojection RMS over every finite keypoint (``rms_px``)."""

    q: np.ndarray
    t: np.ndarray
    method: str
    inliers: int
    rms_px: float


def plausible(tvec: np.ndarray, object_points: np.ndarray, camera_matrix: np.ndarray) -> bool:
    """In front of the camera and at least a couple of pixels across (degenerate solutions
    at huge distances explain collapsed keypoints perfectly)."""
    return bool(in_reach(np.ravel(tvec), farthest_plausible_m(object_points, camera_matrix)))


def farthest_plausible_m(object_points: np.ndarray, camera_matrix: np.ndarray) -> float:
    """The distance [m] beyond which the object (K, 3) [m] would be under a couple of pixels
    across (``plausible``): computed once, for RANSAC's many samples."""
    radius = float(np.max(np.linalg.norm(object_points - object_points.mean(axis=0), axis=1)))
    return camera_matrix[0][0] * radius


def in_reach(tvec: np.ndarray, farthest_m: float) -> np.ndarray:
    """``plausible`` for translations (..., 3) [m] and the object's ``farthest_plausible_m``:
    (...) booleans (RANSAC asks it of a chunk of samples at once)."""
    tvec = np.asarray(tvec, float)
    return np.all(np.isfinite(tvec), axis=-1) & (tvec[..., 2] > 0) & (np.sqrt(np.sum(tvec ** 2, axis=-1)) <= farthest_m)


def spans(rvec: np.ndarray, tvec: np.ndarray, object_points: np.ndarray, camera_matrix: np.ndarray,
          dist: np.ndarray, extent_px: tuple[float, float] | None) -> bool:
    """Whether the object's points at a pose span (least, most) pixels in the image (the
    larger of the x and y extents); always true without ``extent_px``."""
    if extent_px is None:
        return True
    projected = cv2.projectPoints(object_points, rvec, tvec, camera_matrix, dist)[0][:, 0]
    span = (projected.max(axis=0) - projected.min(axis=0)).max()
    return bool(extent_px[0] <= span <= extent_px[1])


def _residuals(object_points: np.ndarray, image_points: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
               rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """(K,) reprojection distances [px]."""
    projected = cv2.projectPoints(object_points, rvec, tvec, camera_matrix, dist)[0][:, 0]
    return np.linalg.norm(projected - image_points, axis=1)


def _weighted_lm(object_points: np.ndarray, image_points: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
                 rvec: np.ndarray, tvec: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on the reprojection errors, each weighted by its keypoint's
    confidence (OpenCV's refinement has no weights)."""
    from scipy.optimize import least_squares

    root = np.sqrt(weights)[:, None]

    def residual(x: np.ndarray) -> np.ndarray:
        projected = cv2.projectPoints(object_points, x[:3], x[3:], camera_matrix, dist)[0][:, 0]
        return ((projected - image_points) * root).ravel()

    start = np.concatenate([rvec.ravel(), tvec.ravel()])
    solution = least_squares(residual, start, method="lm", max_nfev=200)
    x = solution.x if np.all(np.isfinite(solution.x)) else start
    return x[:3].reshape(3, 1), x[3:].reshape(3, 1)


def pose_from_keypoints(keypoints_px: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray,
                        dist: np.ndarray, reprojection_px: float, confidence: np.ndarray | None = None,
                        extent_px: tuple[float, float] | None = None) -> PnPSolution | None:
    """The pose of cam_from_target from K image points (K, 2) [px] and body points (K, 3)
    [m], with the label camera: AP3P inside RANSAC (threshold ``reprojection_px``), then LM
    on the inliers; when RANSAC finds no plausible consensus (in front of the camera and,
    given ``extent_px``, spanning it: ``spans``), EPnP on every point, then LM with each
    residual weighted by its keypoint's ``confidence`` (K,) (heatmap peaks).
    None only when fewer than 4 keypoints are finite: finite outputs always give a pose."""
    image_points = np.asarray(keypoints_px, np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(image_points), axis=1)
    if finite.sum() < 4:
        return None
    object_points = np.ascontiguousarray(np.asarray(keypoints_m, np.float64)[finite])
    image_points = np.ascontiguousarray(image_points[finite])
    weights = np.ones(len(image_points)) if confidence is None else np.asarray(confidence, float)[finite]
    weights = np.clip(np.nan_to_num(weights, nan=0.0, posinf=1.0, neginf=0.0), 1e-3, None)
    method = "ransac"
    # minimal samples of 4 solved by AP3P: on the previous reference model's held-out
    # keypoints this found the right consensus more often than EPnP's samples (30% vs 32%
    # of poses off by more than 10 deg, median error 1.95 vs 2.8 deg) and 3x faster
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        object_points, image_points, camera_matrix, dist, flags=cv2.SOLVEPNP_AP3P,
        reprojectionError=reprojection_px, iterationsCount=500, confidence=0.999)
    # a consensus is more than the sample: AP3P fits any 4 points (the 4th only picks a root)
    if ok and inliers is not None and len(inliers) >= MIN_CONSENSUS:
        chosen = inliers[:, 0]
        rvec, tvec = cv2.solvePnPRefineLM(object_points[chosen], image_points[chosen], camera_matrix, dist, rvec,
                                          tvec)
        ok = plausible(tvec[:, 0], object_points, camera_matrix) and spans(rvec, tvec, object_points, camera_matrix,
                                                                           dist, extent_px)
    else:
        ok = False
    if not ok:
        method = "all_points"
        ok, rvec, tvec = cv2.solvePnP(object_points, image_points, camera_matrix, dist, flags=cv2.SOLVEPNP_EPNP)
        if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
            ok, rvec, tvec = cv2.solvePnP(object_points, image_points, camera_matrix, dist, flags=cv2.SOLVEPNP_SQPNP)
        rvec, tvec = _weighted_lm(object_points, image_points, camera_matrix, dist, np.asarray(rvec, float),
                                  np.asarray(tvec, float), weights)
    residuals = _residuals(object_points, image_points, camera_matrix, dist, rvec, tvec)
    q, t = g.transform_to_qt(g.make_transform(cv2.Rodrigues(rvec)[0], tvec[:, 0]))
    return PnPSolution(q, t, method, int(np.sum(residuals <= reprojection_px)),
                       float(np.sqrt(np.mean(residuals ** 2))))
