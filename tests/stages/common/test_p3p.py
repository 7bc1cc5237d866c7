"""The batched AP3P: exact poses from exact points, OpenCV's choice on noisy ones."""

from pathlib import Path

import cv2
import numpy as np

from stages.common import geometry as g
from stages.common import p3p

K = np.array([[1494.3, 0, 959.5], [0, 1494.2, 599.5], [0, 0, 1.0]])
DIST = np.array([-0.2238, 0.5141, -0.000665, -0.000214, -0.1312])


def samples(rng: np.random.Generator, count: int, noise_px: float) -> tuple[np.ndarray, ...]:
    """Body points (S, 4, 3) [m] within a 1.2 m cube, cam_from_body rotations (S, 3, 3) and
    translations (S, 3) 4-12 m ahead, and their distorted pixels (S, 4, 2) with noise."""
    body_m = rng.uniform(-0.6, 0.6, (count, 4, 3))
    rotations = g.quat_to_matrix(g.random_quats(rng, count))
    translations = np.stack([rng.uniform(-1, 1, count), rng.uniform(-0.6, 0.6, count), rng.uniform(4, 12, count)], -1)
    image_px = g.project_points(body_m @ rotations.transpose(0, 2, 1) + translations[:, None], K, DIST)
    return body_m, rotations, translations, image_px + rng.normal(0, noise_px, image_px.shape)


def test_quartic_roots_are_the_real_roots_and_a_complex_pair_is_none():
    rng = np.random.default_rng(1)
    real_roots = np.sort(rng.uniform(-1, 1, (200, 4)), axis=1)
    coeffs = np.array([np.poly(r) for r in real_roots]) * rng.uniform(0.5, 2, (200, 1))
    roots, real = p3p.quartic_roots(coeffs)
    assert real.all()
    np.testing.assert_allclose(np.sort(roots, axis=1), real_roots, atol=1e-7)
    # two real roots and a complex pair: the pair is flagged, the real roots found
    pair = rng.uniform(-1, 1, (200, 1)) + 1j * rng.uniform(0.2, 1, (200, 1))
    mixed = np.concatenate([real_roots[:, :2], pair, pair.conj()], axis=1)
    roots, real = p3p.quartic_roots(np.array([np.poly(r).real for r in mixed]))
    assert np.all(real.sum(axis=1) == 2)
    np.testing.assert_allclose(np.sort(roots[real].reshape(200, 2), axis=1), real_roots[:, :2], atol=1e-7)


def test_exact_points_give_the_pose():
    """Seeded property: the pose that made four noiseless points is the one chosen."""
    rng = np.random.default_rng(2)
    body_m, rotations, translations, image_px = samples(rng, 2000, 0.0)
    found_r, found_t, found = p3p.solve_p4p(body_m, image_px, K, DIST)
    assert found.all()
    assert np.max(g.angular_distance(found_r, rotations)) < 1e-7
    np.testing.assert_allclose(found_t, translations, rtol=1e-7)


def test_every_pose_in_front_projects_the_three_points_onto_their_bearings():
    rng = np.random.default_rng(3)
    body_m, _, _, image_px = samples(rng, 2000, 1.0)
    normalised = p3p.undistort_normalized(image_px, K, DIST)
    rays = np.concatenate([normalised, np.ones(normalised.shape[:-1] + (1,))], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    rotations, translations, solved = p3p.ap3p_poses(rays[:, :3], body_m[:, :3])
    assert solved.any(axis=1).mean() > 0.99
    np.testing.assert_allclose(np.swapaxes(rotations[solved], -1, -2) @ rotations[solved], np.broadcast_to(
        np.eye(3), (solved.sum(), 3, 3)), atol=1e-9)
    in_camera = body_m[:, None, :3] @ np.swapaxes(rotations, -1, -2) + translations[:, :, None]  # (S, 4, 3, 3)
    front = solved & np.all(in_camera[..., 2] > 0, axis=-1)
    assert front.sum() > 0.99 * solved.sum()
    cosines = np.sum(in_camera / np.linalg.norm(in_camera, axis=-1, keepdims=True) * rays[:, None, :3], axis=-1)
    assert np.all(np.arccos(np.clip(cosines[front], -1, 1)) < 1e-6)


def test_noisy_samples_take_opencvs_pose():
    """The chosen pose is ``cv2.solvePnP(..., SOLVEPNP_AP3P)``'s, on a seeded set with a
    pixel of noise (the fourth point then decides between the first three's poses)."""
    rng = np.random.default_rng(4)
    body_m, _, _, image_px = samples(rng, 2000, 1.0)
    found_r, found_t, found = p3p.solve_p4p(body_m, image_px, K, DIST)
    for body, image, rotation, translation, ok in zip(body_m, image_px, found_r, found_t, found, strict=True):
        expected_ok, rvec, tvec = cv2.solvePnP(body, np.ascontiguousarray(image), K, DIST, flags=cv2.SOLVEPNP_AP3P)
        assert ok == expected_ok
        np.testing.assert_allclose(rotation, cv2.Rodrigues(rvec)[0], atol=1e-8)
        np.testing.assert_allclose(translation, tvec[:, 0], rtol=1e-6)


def test_degenerate_samples_have_no_pose_and_raise_nothing():
    body_m = np.array([[[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0]],  # collinear
                       [[0, 0, 0], [0, 0, 0], [0.2, 0.1, 0], [0.3, 0, 0.1]]], float)  # a point twice
    image_px = np.array([[[900, 600], [910, 600], [920, 600], [930, 600]],
                         [[900, 600], [900, 600], [920, 610], [930, 605]]], float)
    with np.errstate(all="raise"):
        rotations, translations, found = p3p.solve_p4p(body_m, image_px, K, DIST)
    assert not found.any() and np.all(np.isnan(rotations)) and np.all(np.isnan(translations))


def test_a_nan_fourth_point_keeps_the_first_three_points_pose_as_opencv_does():
    rng = np.random.default_rng(5)
    body_m, rotations, translations, image_px = samples(rng, 20, 0.0)
    image_px[:, 3] = np.nan
    found_r, found_t, found = p3p.solve_p4p(body_m, image_px, K, DIST)
    for body, image, ok in zip(body_m, image_px, found, strict=True):
        assert ok == cv2.solvePnP(body, np.ascontiguousarray(image), K, DIST, flags=cv2.SOLVEPNP_AP3P)[0]
    assert found.all() and np.all(np.isfinite(found_t))


def test_real_chessboard_corners_take_opencvs_pose():
    """Data recorded by others: corners found in three of Ali et al.'s KUKA images (1928 x
    1208, a 28 x 17 board of 20 mm squares), the lens calibrated on them; 1,000 draws of four
    corners an image, coplanar and often with three in a row (degenerate: no pose). Where
    OpenCV finds a pose so does this, and it is OpenCV's; where OpenCV finds none, neither."""
    kuka = Path(__file__).resolve().parents[4] / "shared" / "external" / "ali2019_kuka_1"
    board_m = np.zeros((28 * 17, 3))
    board_m[:, :2] = np.mgrid[0:28, 0:17].T.reshape(-1, 2) * 0.020
    corners = []
    for number in (6, 14, 22):
        gray = cv2.imread(str(kuka / f"{number:02d}.png"), cv2.IMREAD_GRAYSCALE)
        found, points = cv2.findChessboardCornersSB(gray, (28, 17))
        assert found
        corners.append(points.reshape(-1, 2).astype(np.float64))
    _, camera_matrix, dist, *_ = cv2.calibrateCamera([board_m.astype(np.float32)] * 3,
                                                     [c.astype(np.float32) for c in corners], gray.shape[::-1],
                                                     None, None)
    dist = dist.ravel()[:5]
    rng = np.random.default_rng(6)
    unsolved = 0
    for image_corners in corners:
        drawn = np.argsort(rng.random((1000, len(board_m))), axis=1)[:, :4]
        rotations, translations, found = p3p.solve_p4p(board_m[drawn], image_corners[drawn], camera_matrix, dist)
        for body, image, rotation, translation, ok in zip(board_m[drawn], image_corners[drawn], rotations,
                                                          translations, found, strict=True):
            expected_ok, rvec, tvec = cv2.solvePnP(body, np.ascontiguousarray(image), camera_matrix, dist,
                                                   flags=cv2.SOLVEPNP_AP3P)
            assert ok == expected_ok
            unsolved += not ok
            if ok:
                np.testing.assert_allclose(rotation, cv2.Rodrigues(rvec)[0], atol=1e-7)
                np.testing.assert_allclose(translation, tvec[:, 0], rtol=1e-6)
    assert 0 < unsolved < 300  # three corners in a row: a planar grid's degenerate draws
