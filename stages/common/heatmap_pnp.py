"""Poses from heatmaps that keep more than their highest peak.

A keypoint's heatmap on a nearly symmetric body often has two peaks: the keypoint and its
mirror (a left corner where the right one is). Taking each heatmap's highest peak and
then RANSAC over keypoints (``keypoint_pnp.pose_from_keypoints``) cannot recover when the
wrong peak is higher; here every keypoint keeps up to ``CANDIDATES`` peaks, RANSAC draws a
candidate per keypoint, and a pose is worth the heatmap values of the candidates it
explains (within the reprojection threshold), so the geometry decides between a peak and
its mirror. A pose must also be of the size the crop says the target is: an oracle (or
self) crop is ``CROP_MARGIN`` times the target's box, so a pose whose keypoints span less
than half or more than 1.5 times that box is not the target (it explains clustered peaks
from far away).

Measured on the plain reference model's 300 held-out renders (oracle crop, four turns),
with these constants chosen before looking: mean SPEED score 0.27 -> 0.12, poses off by
more than 10 deg 16% -> 10%, median rotation error 0.84 -> 0.87 deg (docs/models.md, "The
reference models").
"""

from __future__ import annotations

import cv2
import numpy as np

from stages.common import geometry as g
from stages.common.keypoint_pnp import (
    MIN_CONSENSUS,
    PnPSolution,
    farthest_plausible_m,
    in_reach,
    peak_positions,
    plausible,
    pose_from_keypoints,
    spans,
)
from stages.common.model_contract import CROP_MARGIN, ModelContract
from stages.common.model_input import apply_affine

#: peaks kept per keypoint heatmap, highest first
CANDIDATES = 3
#: a peak below this fraction of its heatmap's highest is not a candidate
RELATIVE_PEAK = 0.2
#: RANSAC samples at most; each draws 4 keypoints, each its highest peak or (half the time) another
ITERATIONS = 500
#: RANSAC samples are drawn by chunks of this many, and stop once ``CONFIDENCE`` is reached
CHUNK = 50
#: probability that some sample drew only peaks of the best pose (standard adaptive RANSAC)
CONFIDENCE = 0.999
#: the span of a pose's keypoints, as a fraction of the target box the crop implies
EXTENT_RANGE = (0.5, 1.5)


def decode_candidates(heatmaps: np.ndarray, width: int, height: int,
                      count: int = CANDIDATES) -> tuple[np.ndarray, np.ndarray]:
    """Peaks of heatmaps (N, K, h, w): points (N, K, count, 2) in input pixels (a W x H
    input; NaN where a heatmap has fewer peaks) and their values (N, K, count) (0 there),
    highest first. A peak is a 3x3 local maximum of at least ``RELATIVE_PEAK`` of its
    heatmap's highest, refined by a parabola in x and in y; the first is ``decode_heatmaps``'s."""
    n, k, h, w = heatmaps.shape
    padded = np.pad(heatmaps, ((0, 0), (0, 0), (1, 1), (1, 1)), constant_values=-np.inf)
    neighbours = np.stack([padded[..., 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                           for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)])
    highest = heatmaps.reshape(n, k, -1).max(axis=-1)
    # ties (flat tops) keep one: a peak is >= every neighbour and > those before it in scan order
    earlier = neighbours[:4]
    peak = (heatmaps >= neighbours.max(axis=0)) & (heatmaps > earlier.max(axis=0))
    peak &= (heatmaps >= RELATIVE_PEAK * highest[..., None, None]) | (heatmaps == highest[..., None, None])
    values = np.where(peak, heatmaps, -np.inf).reshape(n, k, -1)
    order = np.argsort(-values, axis=-1, kind="stable")[..., :count]
    top = np.take_along_axis(values, order, axis=-1)
    ys, xs = np.divmod(order, w)
    points, _ = peak_positions(heatmaps, ys, xs, width, height)
    found = np.isfinite(top)
    return np.where(found[..., None], points, np.nan), np.where(found, top, 0.0)


def target_extent(image_from_input: np.ndarray, input_width: int) -> tuple[float, float]:
    """(least, most) span [px] of the target's keypoints in an oracle-type crop mapped to the
    image by ``image_from_input`` (3, 3): the crop is ``CROP_MARGIN`` times the target's box."""
    box_side = abs(image_from_input[0, 0]) * input_width / CROP_MARGIN
    return EXTENT_RANGE[0] * box_side, EXTENT_RANGE[1] * box_side


def pose_from_candidates(candidates_px: np.ndarray, values: np.ndarray, keypoints_m: np.ndarray,
                         camera_matrix: np.ndarray, dist: np.ndarray, reprojection_px: float,
                         extent_px: tuple[float, float] | None = None, seed: int = 0) -> PnPSolution | None:
    """The pose of cam_from_target from each keypoint's candidate image points (K, C, 2)
    [px] (NaN: none) with their heatmap values (K, C), body points (K, 3) [m] and the label
    camera: the RANSAC pose whose explained candidates have the most heatmap value, among
    poses in front of the camera whose keypoints span ``extent_px`` (least, most) [px]; then
    Levenberg-Marquardt on the explained candidates; ``rms_px`` over every keypoint with a
    peak, each at its nearest. Without such a pose (at least ``MIN_CONSENSUS`` keypoints
    explained): ``pose_from_keypoints`` on the highest peaks (whose RANSAC pose must span
    ``extent_px`` too). Deterministic for ``seed``, whatever was computed before."""
    candidates_px = np.asarray(candidates_px, np.float64)
    values = np.asarray(values, np.float64)
    keypoints_m = np.ascontiguousarray(keypoints_m, np.float64)
    usable = np.all(np.isfinite(candidates_px), axis=-1) & np.isfinite(values)
    counts = usable.sum(axis=1)
    present = np.flatnonzero(counts > 0)
    best = None
    if len(present) >= 4:
        rng = np.random.default_rng(seed)
        farthest = farthest_plausible_m(keypoints_m, camera_matrix)
        rotvecs, translations, totals = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
        drawn, needed = 0, ITERATIONS
        while drawn < needed and drawn < ITERATIONS:
            # samples by chunk; after each, as many as give CONFIDENCE of one sample of the best pose's peaks
            object_points, image_points = _draw(rng, present, counts, keypoints_m, candidates_px)
            drawn += CHUNK  # an unusable sample still counts: the schedule depends on the draws alone
            chunk_r, chunk_t = _ap3p(object_points, image_points, camera_matrix, dist, farthest)
            # each valid pose's support is scored once: the chunks only add poses
            rotvecs, translations = np.concatenate([rotvecs, chunk_r]), np.concatenate([translations, chunk_t])
            totals = np.concatenate([totals, _support(chunk_r, chunk_t, candidates_px, values, usable, keypoints_m,
                                                      camera_matrix, dist, reprojection_px, extent_px)])
            best = _best_supported(rotvecs, translations, totals)
            if best is not None:
                needed = _samples_needed(*best, candidates_px, values, usable, counts, keypoints_m, camera_matrix,
                                         dist, reprojection_px)
    if best is None:
        return pose_from_keypoints(candidates_px[:, 0], keypoints_m, camera_matrix, dist, reprojection_px, values[:, 0],
                                   extent_px)
    rvec, tvec = best
    for _ in range(2):  # refine on what the pose explains, then once more on what the refined pose explains
        explained, points = _explained(rvec, tvec, candidates_px, values, usable, keypoints_m, camera_matrix, dist,
                                       reprojection_px)
        if explained.sum() < 4:
            break
        refined = cv2.solvePnPRefineLM(keypoints_m[explained], np.ascontiguousarray(points[explained]),
                                       camera_matrix, dist, rvec.copy(), tvec.copy())
        # a few explained points can pull the refinement off to a body far away: keep the sample's pose then
        if not _acceptable(*refined, keypoints_m, camera_matrix, dist, extent_px):
            break
        rvec, tvec = refined
    # the RMS of each keypoint's residual to its nearest peak: a pose that took a second peak
    # is judged by that peak, not by the mirror it rejected
    projected = cv2.projectPoints(keypoints_m, rvec, tvec, camera_matrix, dist)[0][:, 0]
    distance = np.where(usable, np.linalg.norm(candidates_px - projected[:, None], axis=-1), np.inf)
    residuals = distance.min(axis=1)[usable.any(axis=1)]
    explained, _ = _explained(rvec, tvec, candidates_px, values, usable, keypoints_m, camera_matrix, dist,
                              reprojection_px)
    q, t = g.transform_to_qt(g.make_transform(cv2.Rodrigues(rvec)[0], tvec[:, 0]))
    return PnPSolution(q, t, "ransac", int(explained.sum()), float(np.sqrt(np.mean(residuals ** 2))))


def _samples_needed(rvec: np.ndarray, tvec: np.ndarray, candidates_px: np.ndarray, values: np.ndarray,
                    usable: np.ndarray, counts: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray,
                    dist: np.ndarray, reprojection_px: float) -> int:
    """Samples that draw, with probability ``CONFIDENCE``, at least once 4 keypoints each
    with the peak the pose explains it by (each keypoint drawn alike, its highest peak half
    the time)."""
    projected = cv2.projectPoints(keypoints_m, rvec, tvec, camera_matrix, dist)[0][:, 0]
    near = usable & (np.linalg.norm(candidates_px - projected[:, None], axis=-1) <= reprojection_px)
    pick = np.argmax(np.where(near, values, -np.inf), axis=1)
    chance = np.where(counts == 1, 1.0, np.where(pick == 0, 0.5, 0.5 / np.maximum(counts - 1, 1)))
    per_keypoint = np.where(near.any(axis=1), chance, 0.0)[counts > 0]
    good = float(np.mean(per_keypoint)) ** 4
    if good >= 1.0:
        return CHUNK
    if good <= 0.0:
        return ITERATIONS
    return int(np.ceil(np.log(1 - CONFIDENCE) / np.log(1 - good)))


def _acceptable(rvec: np.ndarray, tvec: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray,
                dist: np.ndarray, extent_px: tuple[float, float] | None) -> bool:
    """Finite, in front of the camera and spanning ``extent_px`` (when given)."""
    return bool(np.all(np.isfinite(rvec)) and plausible(tvec[:, 0], keypoints_m, camera_matrix)
                and spans(rvec, tvec, keypoints_m, camera_matrix, dist, extent_px))


def _explained(rvec: np.ndarray, tvec: np.ndarray, candidates_px: np.ndarray, values: np.ndarray,
               usable: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
               reprojection_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Which keypoints (K,) have a candidate within the threshold of the pose's projection,
    and for each the most valuable such candidate (K, 2) [px]."""
    projected = cv2.projectPoints(keypoints_m, rvec, tvec, camera_matrix, dist)[0][:, 0]
    near = usable & (np.linalg.norm(candidates_px - projected[:, None], axis=-1) <= reprojection_px)
    pick = np.argmax(np.where(near, values, -np.inf), axis=1)
    return near.any(axis=1), candidates_px[np.arange(len(pick)), pick]


def _draw(rng: np.random.Generator, present: np.ndarray, counts: np.ndarray, keypoints_m: np.ndarray,
          candidates_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A chunk of RANSAC samples: body points (CHUNK, 4, 3) [m] and image points (CHUNK, 4,
    2) [px] of 4 distinct keypoints of ``present`` each, each keypoint at its highest peak or
    (half the time, when it has more) at one of its others, uniformly."""
    order = np.argsort(rng.random((CHUNK, len(present))), axis=1, kind="stable")[:, :4]
    chosen = present[order]  # (CHUNK, 4): a uniform draw of 4 distinct keypoints
    count = counts[chosen]
    other = rng.integers(1, np.maximum(count, 2))
    picks = np.where((count == 1) | (rng.random((CHUNK, 4)) < 0.5), 0, other)
    return keypoints_m[chosen], np.ascontiguousarray(candidates_px[chosen, picks])


def _ap3p(object_points: np.ndarray, image_points: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
          farthest_m: float) -> tuple[np.ndarray, np.ndarray]:
    """AP3P's pose of each sample (S, 4, 3) [m] / (S, 4, 2) [px]: rotation vectors and
    translations (P, 3) of the solved samples whose pose is plausible (``in_reach``)."""
    rotvecs, translations = [], []
    for body, image in zip(object_points, image_points, strict=True):
        ok, rvec, tvec = cv2.solvePnP(body, image, camera_matrix, dist, flags=cv2.SOLVEPNP_AP3P)
        if ok:
            rotvecs.append(rvec[:, 0])
            translations.append(tvec[:, 0])
    if not rotvecs:
        return np.zeros((0, 3)), np.zeros((0, 3))
    rotvecs, translations = np.array(rotvecs), np.array(translations)
    reach = in_reach(translations, farthest_m)
    return rotvecs[reach], translations[reach]


def _support(rotvecs: np.ndarray, translations: np.ndarray, candidates_px: np.ndarray, values: np.ndarray,
             usable: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
             reprojection_px: float, extent_px: tuple[float, float] | None) -> np.ndarray:
    """Each pose's worth (P,) (rotation vectors and translations (P, 3)): the heatmap value
    of the candidates it explains, -inf for a pose of the wrong span or explaining fewer
    than ``MIN_CONSENSUS`` keypoints."""
    if not len(rotvecs):
        return np.zeros(0)
    # every pose at once (cv2.projectPoints takes one): (P, K, 2)
    rotations = g.rotvec_to_matrix(rotvecs)
    projected = g.project_points(keypoints_m @ rotations.transpose(0, 2, 1) + translations[:, None], camera_matrix,
                                 dist)
    distance = np.linalg.norm(candidates_px[None] - projected[:, :, None], axis=-1)  # (P, K, C)
    near = usable[None] & (distance <= reprojection_px)
    support = np.where(near, values[None], -np.inf).max(axis=-1)  # (P, K)
    support = np.where(np.isfinite(support), support, 0.0)
    total = np.where(near.any(axis=-1).sum(axis=-1) >= MIN_CONSENSUS, support.sum(axis=-1), -np.inf)
    if extent_px is not None:
        span = (projected.max(axis=1) - projected.min(axis=1)).max(axis=-1)
        total = np.where((span >= extent_px[0]) & (span <= extent_px[1]), total, -np.inf)
    return total


def _best_supported(rotvecs: np.ndarray, translations: np.ndarray, totals: np.ndarray,
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """(rvec, tvec) (3, 1) of the pose of the highest ``_support`` ``totals`` (the first on
    ties), if any is acceptable."""
    if not len(totals):
        return None
    index = int(np.argmax(totals))
    return (rotvecs[index].reshape(3, 1), translations[index].reshape(3, 1)) if np.isfinite(totals[index]) else None


def poses_from_heatmaps(heatmaps: np.ndarray, image_from_inputs: list[np.ndarray], contract: ModelContract,
                        camera_matrix: np.ndarray, dist: np.ndarray,
                        reprojection_px: list[float], seed: int = 0) -> tuple[list[PnPSolution | None], np.ndarray]:
    """Poses of a batch of heatmaps (N, K, h, w) of crops mapped to their images by
    ``image_from_inputs`` (N of (3, 3)), each with its RANSAC threshold [px] (each RANSAC
    seeded with ``seed``); and the highest peaks (N, K, 2) in image pixels. The span bound
    applies to oracle-type crops."""
    candidates, values = decode_candidates(heatmaps, contract.width, contract.height)
    solutions, highest = [], []
    for points, value, affine, threshold in zip(candidates, values, image_from_inputs, reprojection_px, strict=True):
        in_image = apply_affine(affine, points)
        highest.append(in_image[:, 0])
        extent = target_extent(affine, contract.width) if contract.crop == "oracle_box" else None
        solutions.append(pose_from_candidates(in_image, value, contract.keypoints_m, camera_matrix, dist, threshold,
                                              extent, seed))
    return solutions, np.array(highest).reshape(len(candidates), -1, 2)


def explained_value(solution: PnPSolution | None, heatmaps: np.ndarray, image_from_input: np.ndarray,
                    contract: ModelContract, camera_matrix: np.ndarray, dist: np.ndarray,
                    reprojection_px: float) -> float:
    """The heatmap value (K, h, w) a pose explains: over keypoints, the most valuable peak
    within ``reprojection_px`` of its projection (0 without a pose)."""
    if solution is None:
        return 0.0
    candidates, values = decode_candidates(heatmaps[None], contract.width, contract.height)
    in_image = apply_affine(image_from_input, candidates[0])
    usable = np.all(np.isfinite(in_image), axis=-1)
    rvec = cv2.Rodrigues(g.quat_to_matrix(solution.q))[0]
    projected = cv2.projectPoints(contract.keypoints_m, rvec, np.asarray(solution.t, float).reshape(3, 1),
                                  camera_matrix, dist)[0][:, 0]
    near = usable & (np.linalg.norm(in_image - projected[:, None], axis=-1) <= reprojection_px)
    return float(np.where(near, values[0], 0.0).max(axis=1).sum())
