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
from stages.common import p3p
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
#: images whose RANSAC samples are solved and scored together (bounds the arrays: (GROUP, ITERATIONS, K, C))
GROUP = 16
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
    return poses_from_candidates(np.asarray(candidates_px)[None], np.asarray(values)[None], keypoints_m,
                                 camera_matrix, dist, [reprojection_px], [extent_px], seed)[0]


def poses_from_candidates(candidates_px: np.ndarray, values: np.ndarray, keypoints_m: np.ndarray,
                          camera_matrix: np.ndarray, dist: np.ndarray, reprojection_px: list[float],
                          extents_px: list[tuple[float, float] | None], seed: int = 0) -> list[PnPSolution | None]:
    """``pose_from_candidates`` of N images' candidates (N, K, C, 2) [px] and values
    (N, K, C), each with its threshold [px] and span bound, each RANSAC seeded with
    ``seed``: the same poses, the RANSACs' samples solved and scored together
    (``GROUP`` images at a time)."""
    candidates_px = np.asarray(candidates_px, np.float64)
    values = np.asarray(values, np.float64)
    keypoints_m = np.ascontiguousarray(keypoints_m, np.float64)
    usable = np.all(np.isfinite(candidates_px), axis=-1) & np.isfinite(values)
    sampled = [i for i in range(len(candidates_px)) if np.count_nonzero(usable[i].any(axis=1)) >= 4]
    bests: dict[int, tuple[np.ndarray, np.ndarray] | None] = {}
    for start in range(0, len(sampled), GROUP):
        group = sampled[start:start + GROUP]
        bests.update(zip(group, _ransacs(group, candidates_px, values, usable, keypoints_m, camera_matrix, dist,
                                         reprojection_px, extents_px, seed), strict=True))
    return [_finished(bests.get(i), candidates_px[i], values[i], usable[i], keypoints_m, camera_matrix, dist,
                      reprojection_px[i], extents_px[i]) for i in range(len(candidates_px))]


def _finished(best: tuple[np.ndarray, np.ndarray] | None, candidates_px: np.ndarray, values: np.ndarray,
              usable: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
              reprojection_px: float, extent_px: tuple[float, float] | None) -> PnPSolution | None:
    """The solution from an image's RANSAC pose ``best`` (rvec, tvec) (3, 1), refined on the
    candidates it explains; without one, ``pose_from_keypoints`` on the highest peaks."""
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


def _ransacs(cases: list[int], candidates_px: np.ndarray, values: np.ndarray, usable: np.ndarray,
             keypoints_m: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray, reprojection_px: list[float],
             extents_px: list[tuple[float, float] | None], seed: int) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """Each case's (an image index's) (rvec, tvec) (3, 1) of its best supported sample pose
    (the first on ties), if any. Samples are taken by chunks of ``CHUNK``, until as many as
    give ``CONFIDENCE`` of a sample of the best pose's peaks have been (``_samples_needed``)
    or ``ITERATIONS``; an unusable sample still counts, so the schedule depends on the draws
    alone. Every chunk of every case is drawn, solved (``p3p.solve_p4p``) and scored first,
    at once, and each schedule then read off them: the same poses as solving a chunk at a
    time, for one NumPy pass instead of ten a case (most RANSACs of the default profile's
    evaluate run all ``ITERATIONS``: 94%)."""
    counts = usable[cases].sum(axis=-1)  # (M, K)
    chunks = -(-ITERATIONS // CHUNK)  # the schedule never draws more
    drawn_samples = []
    for case, count in zip(cases, counts, strict=True):
        rng, present = np.random.default_rng(seed), np.flatnonzero(count > 0)
        drawn_samples += [_draw(rng, present, count, keypoints_m, candidates_px[case]) for _ in range(chunks)]
    body_m, image_px = (np.concatenate(parts) for parts in zip(*drawn_samples, strict=True))
    rotations, translations, found = p3p.solve_p4p(body_m, image_px, camera_matrix, dist)
    shape = (len(cases), chunks * CHUNK)
    rotations, translations = rotations.reshape(shape + (3, 3)), translations.reshape(shape + (3,))
    posed = found.reshape(shape) & in_reach(translations, farthest_plausible_m(keypoints_m, camera_matrix))
    extents = np.array([extents_px[case] or (-np.inf, np.inf) for case in cases], float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # unposed samples' poses, masked below
        totals = _support(rotations, translations, candidates_px[cases], values[cases], usable[cases], keypoints_m,
                          camera_matrix, dist, np.array([reprojection_px[case] for case in cases]), extents)
    totals = np.where(posed, totals, -np.inf)
    return [_scheduled(totals[m], rotations[m], translations[m], candidates_px[case], values[case], usable[case],
                       counts[m], keypoints_m, camera_matrix, dist, reprojection_px[case])
            for m, case in enumerate(cases)]


def _scheduled(totals: np.ndarray, rotations: np.ndarray, translations: np.ndarray, candidates_px: np.ndarray,
               values: np.ndarray, usable: np.ndarray, counts: np.ndarray, keypoints_m: np.ndarray,
               camera_matrix: np.ndarray, dist: np.ndarray,
               reprojection_px: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The best pose (rvec, tvec) (3, 1) among the samples the adaptive schedule draws, from
    every sample's support ``totals`` (S,) and pose (rotations (S, 3, 3), translations
    (S, 3)), S the ``ITERATIONS`` rounded up to whole chunks."""
    drawn, needed, best_index = 0, ITERATIONS, -1
    while drawn < needed and drawn < ITERATIONS:
        drawn += CHUNK
        index = int(np.argmax(totals[:drawn]))
        if np.isfinite(totals[index]) and index != best_index:
            best_index = index
            needed = _samples_needed(*_rvec_tvec(rotations[index], translations[index]), candidates_px, values,
                                     usable, counts, keypoints_m, camera_matrix, dist, reprojection_px)
    return _rvec_tvec(rotations[best_index], translations[best_index]) if best_index >= 0 else None


def _rvec_tvec(rotation: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's rotation vector and translation (3, 1) of a pose (rotation (3, 3), translation (3,))."""
    return cv2.Rodrigues(rotation)[0], translation.reshape(3, 1).copy()


def _support(rotations: np.ndarray, translations: np.ndarray, candidates_px: np.ndarray, values: np.ndarray,
             usable: np.ndarray, keypoints_m: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray,
             reprojection_px: float | np.ndarray, extent_px: tuple[float, float] | np.ndarray | None) -> np.ndarray:
    """Each pose's worth (..., P) (rotations (..., P, 3, 3) and translations (..., P, 3), of
    images whose candidates are (..., K, C, 2), values and usability (..., K, C), thresholds
    (...) [px] and span bounds (..., 2) [px]): the heatmap value of the candidates it
    explains, -inf for a pose of the wrong span or explaining fewer than ``MIN_CONSENSUS``
    keypoints."""
    if not rotations.size:
        return np.zeros(rotations.shape[:-2])
    # every pose at once (cv2.projectPoints takes one): (..., P, K, 2)
    projected = g.project_points(keypoints_m @ np.swapaxes(rotations, -1, -2) + translations[..., None, :],
                                 camera_matrix, dist)
    # a candidate at a time, components by hand: NumPy reduces over a last axis of 2 or 3 slowly
    threshold = np.asarray(reprojection_px)[..., None, None]
    support = np.full(projected.shape[:-1], -np.inf)  # (..., P, K)
    explained = np.zeros(projected.shape[:-1], bool)
    for c in range(candidates_px.shape[-2]):
        off_x = candidates_px[..., None, :, c, 0] - projected[..., 0]
        off_y = candidates_px[..., None, :, c, 1] - projected[..., 1]
        near = usable[..., None, :, c] & (np.sqrt(off_x * off_x + off_y * off_y) <= threshold)
        support = np.where(near, np.maximum(support, values[..., None, :, c]), support)
        explained |= near
    total = np.where(explained.sum(axis=-1) >= MIN_CONSENSUS, np.where(explained, support, 0.0).sum(axis=-1),
                     -np.inf)
    if extent_px is not None:
        extent = np.asarray(extent_px, float)
        extents = projected.max(axis=-2) - projected.min(axis=-2)
        span = np.maximum(extents[..., 0], extents[..., 1])
        unbounded = ~np.isfinite(extent).any(axis=-1)[..., None]  # (-inf, inf): no bound, whatever the span
        within = (span >= extent[..., 0, None]) & (span <= extent[..., 1, None])
        total = np.where(unbounded | within, total, -np.inf)
    return total


def poses_from_heatmaps(heatmaps: np.ndarray, image_from_inputs: list[np.ndarray], contract: ModelContract,
                        camera_matrix: np.ndarray, dist: np.ndarray,
                        reprojection_px: list[float], seed: int = 0) -> tuple[list[PnPSolution | None], np.ndarray]:
    """Poses of a batch of heatmaps (N, K, h, w) of crops mapped to their images by
    ``image_from_inputs`` (N of (3, 3)), each with its RANSAC threshold [px] (each RANSAC
    seeded with ``seed``); and the highest peaks (N, K, 2) in image pixels. The span bound
    applies to oracle-type crops."""
    candidates, values = decode_candidates(heatmaps, contract.width, contract.height)
    in_images = np.array([apply_affine(affine, points) for points, affine in zip(candidates, image_from_inputs,
                                                                                  strict=True)])
    extents = [target_extent(affine, contract.width) if contract.crop == "oracle_box" else None
               for affine in image_from_inputs]
    solutions = poses_from_candidates(in_images.reshape(candidates.shape), values, contract.keypoints_m,
                                      camera_matrix, dist, list(reprojection_px), extents, seed)
    return solutions, in_images.reshape(candidates.shape)[:, :, 0]


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
