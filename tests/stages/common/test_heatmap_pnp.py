"""Poses from several peaks per heatmap: the geometry chooses between a peak and its mirror."""

import dataclasses

import cv2
import numpy as np
import pytest

from stages.common import geometry as g
from stages.common import tango
from stages.common.heatmap_pnp import (
    CHUNK,
    GROUP,
    ITERATIONS,
    RELATIVE_PEAK,
    _draw,
    _ransacs,
    _samples_needed,
    _support,
    decode_candidates,
    explained_value,
    pose_from_candidates,
    poses_from_candidates,
    poses_from_heatmaps,
    target_extent,
)
from stages.common.keypoint_pnp import decode_heatmaps, farthest_plausible_m, in_reach, pose_from_keypoints
from stages.common.model_contract import CROP_MARGIN, ModelContract

K = np.array([[1494.3, 0, 479.5], [0, 1494.2, 299.5], [0, 0, 1.0]])
DIST = np.array([-0.2238, 0.5141, -0.000665, -0.000214, -0.1312])
CONTRACT = ModelContract(192, 192, "rgb", (0.5, 0.5, 0.5), (0.25, 0.25, 0.25), "heatmaps", tango.KEYPOINTS_M.copy(),
                         "oracle_box")


def gaussians(centres: np.ndarray, heights: np.ndarray, size: int = 48) -> np.ndarray:
    """Heatmaps (..., size, size): a sum of Gaussians (sigma 1) at centres (..., P, 2) of heights (..., P)."""
    ys, xs = np.mgrid[0:size, 0:size]
    d2 = (xs - centres[..., 0, None, None]) ** 2 + (ys - centres[..., 1, None, None]) ** 2
    return (heights[..., None, None] * np.exp(-d2 / 2.0)).sum(axis=-3).astype(np.float32)


def test_candidates_are_the_peaks_highest_first_with_sub_pixel_positions():
    rng = np.random.default_rng(0)
    centres = np.stack([rng.uniform(4, 14, (3, 11, 2)), rng.uniform(30, 43, (3, 11, 2)),
                        rng.uniform(4, 43, (3, 11, 2)) * [1, 0] + [0, 24]], axis=2)  # (3, 11, 3, 2), apart
    heights = np.broadcast_to([1.0, 0.6, 0.5 * RELATIVE_PEAK], (3, 11, 3))
    heatmaps = gaussians(centres, heights)
    points, values = decode_candidates(heatmaps, 192, 192)
    assert points.shape == (3, 11, 3, 2) and values.shape == (3, 11, 3)
    np.testing.assert_allclose(points[:, :, :2], (centres[:, :, :2] + 0.5) * 4 - 0.5, atol=0.35)
    assert np.all(values[:, :, 0] > values[:, :, 1]) and np.all(values[:, :, 1] > 0.45)
    # a peak under RELATIVE_PEAK of the highest is no candidate
    assert np.all(np.isnan(points[:, :, 2])) and np.all(values[:, :, 2] == 0)
    # the first candidate is what decode_heatmaps gives
    first, confidence = decode_heatmaps(heatmaps, 192, 192)
    np.testing.assert_array_equal(points[:, :, 0], first)
    np.testing.assert_array_equal(values[:, :, 0], confidence)


def test_a_flat_or_non_finite_heatmap_has_one_candidate_or_none():
    heatmaps = np.zeros((1, 2, 8, 8), np.float32)
    heatmaps[0, 1] = np.nan
    points, values = decode_candidates(heatmaps, 32, 32)
    assert np.all(np.isfinite(points[0, 0, 0])) and np.all(np.isnan(points[0, 0, 1:]))
    assert np.all(np.isnan(points[0, 1]))


def mirrored_case(rng: np.random.Generator):
    """Candidates where 7 of 11 highest peaks agree on a wrong pose and the true keypoints
    are their second peaks: what a view of a nearly symmetric body looks like."""
    q_true = g.random_quats(rng, 1)[0]
    true_pixels = g.project(g.transform_from_qt(q_true, [0.2, -0.1, 7.0]), tango.KEYPOINTS_M, K, DIST)
    q_wrong = g.quat_multiply(q_true, g.matrix_to_quat(g.axis_angle_matrix("z", np.radians(35))))
    wrong_pixels = g.project(g.transform_from_qt(q_wrong, [0.2, -0.1, 7.0]), tango.KEYPOINTS_M, K, DIST)
    candidates = np.full((11, 2, 2), np.nan)
    values = np.zeros((11, 2))
    fooled = rng.choice(11, 7, replace=False)
    for keypoint in range(11):
        if keypoint in fooled:
            candidates[keypoint] = wrong_pixels[keypoint], true_pixels[keypoint]
            values[keypoint] = 1.0, 0.6
        else:
            candidates[keypoint, 0], values[keypoint, 0] = true_pixels[keypoint], 0.9
    return q_true, candidates, values


def test_a_pose_explaining_second_peaks_too_wins_over_the_highest_peaks_consensus():
    rng = np.random.default_rng(4)
    for _ in range(5):
        q_true, candidates, values = mirrored_case(rng)
        highest_only = pose_from_keypoints(candidates[:, 0], tango.KEYPOINTS_M, K, DIST, 3.0, values[:, 0])
        assert g.quat_angular_distance(highest_only.q, q_true) > np.radians(20)  # fooled
        solution = pose_from_candidates(candidates, values, tango.KEYPOINTS_M, K, DIST, 3.0)
        assert solution.method == "ransac" and solution.inliers == 11
        assert g.quat_angular_distance(solution.q, q_true) < 1e-6
        np.testing.assert_allclose(solution.t, [0.2, -0.1, 7.0], atol=1e-5)


def test_the_same_candidates_give_the_same_bytes_whatever_ran_before():
    q_true, candidates, values = mirrored_case(np.random.default_rng(5))
    first = pose_from_candidates(candidates, values, tango.KEYPOINTS_M, K, DIST, 3.0)
    np.random.seed(9)
    cv2.setRNGSeed(9)
    np.random.default_rng().random(100)
    second = pose_from_candidates(candidates, values, tango.KEYPOINTS_M, K, DIST, 3.0)
    assert first.q.tobytes() == second.q.tobytes() and first.t.tobytes() == second.t.tobytes()


def test_a_pose_of_the_wrong_size_for_the_crop_is_refused_and_finite_candidates_always_give_a_pose():
    rng = np.random.default_rng(6)
    span_of = []
    for _ in range(30):
        candidates = rng.uniform(300, 660, (11, 3, 2))
        candidates[rng.uniform(size=(11, 3)) < 0.3] = np.nan
        candidates[:, 0] = rng.uniform(300, 660, (11, 2))  # every keypoint has its highest peak
        values = np.where(np.isnan(candidates[..., 0]), 0.0, rng.uniform(0.1, 1.0, (11, 3)))
        extent = (180.0, 540.0)
        solution = pose_from_candidates(candidates, values, tango.KEYPOINTS_M, K, DIST, 20.0, extent)
        assert solution is not None and np.all(np.isfinite(solution.q)) and np.all(np.isfinite(solution.t))
        if solution.method == "ransac":
            pixels = g.project(g.transform_from_qt(solution.q, solution.t), tango.KEYPOINTS_M, K, DIST)
            span_of.append((pixels.max(axis=0) - pixels.min(axis=0)).max())
    # neither the chosen sample nor its refinement leaves the span
    assert span_of and all(180 - 1e-6 <= span <= 540 + 1e-6 for span in span_of), sorted(span_of)


def test_heatmaps_of_a_crop_give_the_pose_in_the_image():
    rng = np.random.default_rng(7)
    for q in g.random_quats(rng, 3):
        cam_from_target = g.transform_from_qt(q, [0.1, 0.05, 8.0])
        pixels = g.project(cam_from_target, tango.KEYPOINTS_M, K, DIST)
        box = np.concatenate([pixels.min(axis=0), pixels.max(axis=0)])
        side = CROP_MARGIN * (box[2:] - box[:2]).max()
        corner = (box[:2] + box[2:]) / 2 - side / 2
        scale = side / 192
        image_from_input = np.array([[scale, 0, corner[0] + 0.5 * scale - 0.5],
                                     [0, scale, corner[1] + 0.5 * scale - 0.5], [0, 0, 1.0]])
        in_input = (pixels - image_from_input[:2, 2]) / scale
        heatmaps = gaussians(((in_input + 0.5) / 4 - 0.5)[:, None], np.ones((11, 1)))[None]
        least, most = target_extent(image_from_input, 192)
        assert least < (box[2:] - box[:2]).max() < most
        solutions, highest = poses_from_heatmaps(heatmaps, [image_from_input], CONTRACT, K, DIST, [9.6])
        np.testing.assert_allclose(highest[0], pixels, atol=0.35 * 4 * scale)
        assert np.degrees(g.quat_angular_distance(solutions[0].q, q)) < 1.0
        assert solutions[0].inliers == 11
        # what the self crop's search ranks windows by: the peaks a pose explains
        explained = explained_value(solutions[0], heatmaps[0], image_from_input, CONTRACT, K, DIST, 9.6)
        assert 11 * 0.75 < explained <= 11.0
        turned = dataclasses.replace(solutions[0], q=g.quat_multiply(solutions[0].q, [np.cos(0.5), np.sin(0.5), 0, 0]))
        assert explained_value(turned, heatmaps[0], image_from_input, CONTRACT, K, DIST, 9.6) < 0.5 * explained
        assert explained_value(None, heatmaps[0], image_from_input, CONTRACT, K, DIST, 9.6) == 0.0


def test_ransac_draws_four_distinct_keypoints_each_at_its_highest_peak_half_the_time():
    """The chunk's draw follows the distribution ``_samples_needed`` assumes: every
    keypoint with a peak equally likely, four distinct ones, the highest peak of one with
    several half the time, its others alike."""
    rng = np.random.default_rng(3)
    counts = np.array([3, 1, 2, 0, 3, 3, 1, 2, 0, 3, 3])
    present = np.flatnonzero(counts > 0)
    keypoints_m = np.arange(11 * 3, dtype=float).reshape(11, 3)
    candidates = np.arange(11)[:, None, None] * 10.0 + np.arange(3)[None, :, None] + np.zeros((1, 1, 2))
    chosen, picks = [], []
    for _ in range(400):
        body, image = _draw(rng, present, counts, keypoints_m, candidates)
        assert body.shape == (CHUNK, 4, 3) and image.shape == (CHUNK, 4, 2)
        keypoint = (body[..., 0] / 3).astype(int)
        np.testing.assert_array_equal(image[..., 0] // 10, keypoint)  # each point is its keypoint's own peak
        chosen.append(keypoint)
        picks.append((image[..., 0] % 10).astype(int))
    chosen, picks = np.concatenate(chosen), np.concatenate(picks)
    assert all(len(set(row)) == 4 for row in chosen.tolist()) and set(chosen.ravel()) == set(present)
    share = np.bincount(chosen.ravel(), minlength=11)[present] / chosen.size
    np.testing.assert_allclose(share, 1 / len(present), rtol=0.05)
    for keypoint, count in enumerate(counts):
        taken = picks[chosen == keypoint]
        if count == 1:
            assert np.all(taken == 0)
        elif count > 1:
            assert np.all(taken < count)
            np.testing.assert_allclose(np.mean(taken == 0), 0.5, atol=0.03)
            np.testing.assert_allclose(np.bincount(taken, minlength=count)[1:] / len(taken), 0.5 / (count - 1),
                                       atol=0.03)


def test_support_projects_every_pose_as_opencv_does():
    """The chunk's poses are scored at once; each one's support is what a pose projected
    alone by cv2.projectPoints explains."""
    rng = np.random.default_rng(4)
    q_true, candidates, values = mirrored_case(rng)
    usable = np.all(np.isfinite(candidates), axis=-1)
    spread = np.geomspace(1e-4, 1e-1, 40)[:, None]  # from the truth to far off it
    rotvecs = g.quat_to_rotvec(q_true) + rng.normal(0, 1, (40, 3)) * spread
    translations = np.array([0.2, -0.1, 7.0]) + rng.normal(0, 1, (40, 3)) * spread
    totals = _support(g.rotvec_to_matrix(rotvecs), translations, candidates, values, usable, tango.KEYPOINTS_M, K,
                      DIST, 3.0, None)
    for rotvec, translation, total in zip(rotvecs, translations, totals, strict=True):
        projected = cv2.projectPoints(tango.KEYPOINTS_M, rotvec, translation, K, DIST)[0][:, 0]
        near = usable & (np.linalg.norm(candidates - projected[:, None], axis=-1) <= 3.0)
        expected = np.where(near, values, 0.0).max(axis=1).sum() if near.any(axis=1).sum() >= 5 else -np.inf
        assert total == expected or abs(total - expected) < 1e-12
    assert 5 < np.isfinite(totals).sum() < 35  # poses near the truth explain enough keypoints, far ones not


def _chunk_at_a_time(candidates: np.ndarray, values: np.ndarray, keypoints_m: np.ndarray, reprojection_px: float,
                     extent_px: tuple[float, float] | None, seed: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The RANSAC as it was written first: a chunk drawn, each sample solved by
    ``cv2.solvePnP(AP3P)``, the best so far taken and the count of samples needed redone,
    until the count is reached. (rotation (3, 3), translation (3,)) of its best pose."""
    usable = np.all(np.isfinite(candidates), axis=-1) & np.isfinite(values)
    counts = usable.sum(axis=1)
    present = np.flatnonzero(counts > 0)
    rng, farthest = np.random.default_rng(seed), farthest_plausible_m(keypoints_m, K)
    rotations, translations, best = [], [], None
    drawn, needed = 0, ITERATIONS
    while drawn < needed and drawn < ITERATIONS:
        body, image = _draw(rng, present, counts, keypoints_m, candidates)
        drawn += CHUNK
        for points_m, points_px in zip(body, image, strict=True):
            ok, rvec, tvec = cv2.solvePnP(points_m, points_px, K, DIST, flags=cv2.SOLVEPNP_AP3P)
            if ok and in_reach(tvec[:, 0], farthest):
                rotations.append(cv2.Rodrigues(rvec)[0])
                translations.append(tvec[:, 0])
        if rotations:
            totals = _support(np.array(rotations), np.array(translations), candidates, values, usable,
                              keypoints_m, K, DIST, reprojection_px, extent_px)
            index = int(np.argmax(totals))
            if np.isfinite(totals[index]):
                best = rotations[index], translations[index]
                needed = _samples_needed(cv2.Rodrigues(best[0])[0], best[1].reshape(3, 1), candidates, values,
                                         usable, counts, keypoints_m, K, DIST, reprojection_px)
    return best


#: the keypoints of two targets: Tango's 11, and a 3U CubeSat's 8 corners (0.1 x 0.1 x 0.34 m)
CUBESAT_CORNERS_M = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.17, 0.17)])
TARGETS = {"tango": (tango.KEYPOINTS_M, 8.0), "cubesat3u": (CUBESAT_CORNERS_M, 2.0)}


def _noisy_case(rng: np.random.Generator, target: str = "tango") -> tuple[np.ndarray, np.ndarray]:
    """Candidates (K, 3, 2) round a true pose's keypoints, a third of them off by far, and
    their values: a RANSAC that runs long."""
    keypoints_m, distance_m = TARGETS[target]
    count = len(keypoints_m)
    q_true = g.random_quats(rng, 1)[0]
    truth = g.project(g.transform_from_qt(q_true, [0.1, 0.2, distance_m]), keypoints_m, K, DIST)
    offsets = (rng.uniform(size=(count, 3, 1)) < 0.35) * rng.uniform(-80, 80, (count, 3, 2))
    candidates = truth[:, None] + rng.normal(0, 1.5, (count, 3, 2)) + offsets
    return candidates, rng.uniform(0.2, 1.0, (count, 3))


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_the_batched_ransac_picks_the_pose_a_chunk_at_a_time_over_opencv_picks(target):
    """The samples of every chunk solved at once and the schedule read off them afterwards
    pick the pose that solving each chunk by cv2.solvePnP and stopping when enough were
    drawn picks: cases that stop after a chunk or two and cases that draw all, on Tango and
    on a target of another shape."""
    rng = np.random.default_rng(11)
    keypoints_m = TARGETS[target][0]
    mirrored = [mirrored_case(rng)[1:] for _ in range(3)] if target == "tango" else []
    cases = mirrored + [_noisy_case(rng, target) for _ in range(7 - len(mirrored))]
    extents = [None, None, (40.0, 400.0), None, (60.0, 300.0), None, (40.0, 400.0)]
    for (candidates, values), extent in zip(cases, extents, strict=True):
        count = len(keypoints_m)
        candidates = np.concatenate([candidates, np.full((count, 3 - candidates.shape[1], 2), np.nan)], axis=1)
        values = np.concatenate([values, np.zeros((count, 3 - values.shape[1]))], axis=1)
        usable = np.all(np.isfinite(candidates), axis=-1)
        expected = _chunk_at_a_time(candidates, values, keypoints_m, 4.0, extent, seed=3)
        found = _ransacs([0], candidates[None], values[None], usable[None], keypoints_m, K, DIST, [4.0],
                         [extent], 3)[0]
        assert (found is None) == (expected is None)
        if expected is not None:
            np.testing.assert_allclose(cv2.Rodrigues(found[0])[0], expected[0], atol=1e-8)
            np.testing.assert_allclose(found[1][:, 0], expected[1], rtol=1e-8)


def test_images_solved_together_give_the_bytes_each_gives_alone():
    """More images than a group, with and without span bounds: the same bytes as one image
    at a time (the batch's composition never shows in a pose)."""
    rng = np.random.default_rng(12)
    cases = [_noisy_case(rng) for _ in range(GROUP + 4)]
    candidates, values = np.array([c for c, _ in cases]), np.array([v for _, v in cases])
    extents = [(40.0, 400.0) if i % 3 else None for i in range(len(cases))]
    keypoints_m = tango.KEYPOINTS_M
    together = poses_from_candidates(candidates, values, keypoints_m, K, DIST, [4.0] * len(cases), extents, 7)
    for i, solution in enumerate(together):
        alone = pose_from_candidates(candidates[i], values[i], keypoints_m, K, DIST, 4.0, extents[i], 7)
        assert solution.method == alone.method and solution.inliers == alone.inliers
        assert solution.q.tobytes() == alone.q.tobytes() and solution.t.tobytes() == alone.t.tobytes()
