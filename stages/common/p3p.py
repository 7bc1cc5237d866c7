"""Many minimal pose problems at once: AP3P on a batch of 4-point samples, as OpenCV's
``solvePnP(..., flags=SOLVEPNP_AP3P)`` solves one.

RANSAC over heatmap peaks (``stages.common.heatmap_pnp``) solves up to 500 samples a
prediction; one OpenCV call a sample cost 9-11 us of call overhead each, 70% of an
evaluate. Here every sample is solved in the same NumPy operations:

1. The image points are undistorted by ``cv2.undistortPoints`` at its default criteria,
   as ``solvePnP`` undistorts them (one call for every point of every sample).
2. The first three points give up to four poses: Ke and Roumeliotis, "An Efficient
   Algebraic Solution to the Perspective-Three-Point Problem", CVPR 2017
   (arXiv:1701.08237), section 3: the quartic in cos(theta1') (their eq. 14), solved in
   closed form by Ferrari's method and polished by two Newton steps, as OpenCV's
   ``ap3p.cpp``; a complex pair of roots, or a root whose magnitude exceeds 1, is no pose,
   and a pose whose cos and sin of theta3 are off the unit circle (a root off by a little)
   is taken at its nearest rotation, as OpenCV's ``Rodrigues`` takes it.
3. The fourth point chooses: the pose of least summed squared reprojection error [px^2]
   over all four points through the lens (``solveP3P``'s order), ties going to the least
   normalised error of the fourth point alone (``ap3p::computePoses``' order), then to
   the root's index.

OpenCV keeps a pose whose root is NaN (a degenerate sample: collinear body points or
bearings); here such a pose is not a solution. Poses equal OpenCV's to 1e-9 relative on
generic samples, and to 1e-6 on 3,000 draws of four real chessboard corners (Ali et al.'s
KUKA images, where both find no pose for the same 2-4%: three corners in a row)
(``tests/stages/common/test_p3p.py``). Near a double root (cos(theta1')
near +-1, or a complex pair nearly real) OpenCV's solutions missed their own three points
by 3-63 px where these meet them within 0.03 px, and the choice may differ there: one
RANSAC seed in 15,840 of the paper profile (docs/development.md, Speed).
"""

from __future__ import annotations

import cv2
import numpy as np

from stages.common import geometry as g

#: a solution whose cos^2 + sin^2 of theta3 is further than this from 1 is replaced by its nearest rotation
ORTHONORMAL_TOLERANCE = 1e-10
#: Newton steps that polish each root of the quartic (``ap3p.cpp``'s ``polishQuarticRoots``)
POLISH_STEPS = 2


def undistort_normalized(image_px: np.ndarray, camera_matrix: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Normalised image coordinates (..., 2) of distorted pixels (..., 2): ``cv2.undistortPoints``
    at its default criteria (five fixed-point iterations), as ``solvePnP`` undistorts, all the
    points in one call (NaN stays NaN)."""
    points = np.ascontiguousarray(image_px, np.float64).reshape(-1, 1, 2)
    if not len(points):
        return np.zeros(np.shape(image_px))
    return cv2.undistortPoints(points, np.asarray(camera_matrix, np.float64),
                               np.asarray(dist, np.float64)).reshape(np.shape(image_px))


# NumPy reduces over a last axis of 2 or 3 slowly: these sum its components by hand
def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _unit(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = np.sqrt(_dot(a, a))
    return a / norm[..., None], norm


def quartic_roots(coeffs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The four roots (S, 4) of a4 x^4 + a3 x^3 + a2 x^2 + a1 x + a0 (coefficients (S, 5),
    a4 first) by Ferrari's closed form, polished, and which are real (S, 4): Ferrari's two
    pairs, each real where the square root that splits it is of a number >= 0 (a complex
    pair's real parts polish onto a real root's neighbourhood, a pose that is none)."""
    a4, a3, a2, a1, a0 = np.moveaxis(coeffs, -1, 0)
    a4_2, a3_2 = a4 * a4, a3 * a3
    a4_3, a2a4 = a4_2 * a4, a2 * a4
    p4 = (8 * a2a4 - 3 * a3_2) / (8 * a4_2)
    q4 = (a3_2 * a3 - 4 * a2a4 * a3 + 8 * a1 * a4_2) / (8 * a4_3)
    r4 = (256 * a0 * a4_3 - 3 * (a3_2 * a3_2) - 64 * a1 * a3 * a4_2 + 16 * a2a4 * a3_2) / (256 * (a4_3 * a4))
    p3 = ((p4 * p4) / 12 + r4) / 3
    q3 = (72 * r4 * p4 - 2 * p4 * p4 * p4 - 27 * q4 * q4) / 432
    root = np.sqrt((q3 * q3 - p3 * p3 * p3).astype(complex))
    w = np.where(q3 >= 0, -root - q3, root - q3)
    real_w = w.imag == 0
    # the resolvent cubic's real root: a real cube root where w is real, else 4 Re(w^(1/3))
    cube = np.cbrt(w.real)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(real_w, 2.0 * (cube + p3 / cube), 4.0 * (w ** (1.0 / 3)).real)
        sqrt_2m = np.sqrt((-2 * p4 / 3 + t).astype(complex))
        complex1 = 4 * p4 / 3 + t
        complex2 = 2 * q4 / sqrt_2m
    b_4a, half = -a3 / (4 * a4), sqrt_2m.real / 2
    first, second = -(complex1 + complex2), -(complex1 - complex2)
    sqrt1, sqrt2 = np.sqrt(first).real / 2, np.sqrt(second).real / 2
    real = np.stack([first.real >= 0, first.real >= 0, second.real >= 0, second.real >= 0], axis=-1)
    roots = np.stack([b_4a + half + sqrt1, b_4a + half - sqrt1, b_4a - half + sqrt2, b_4a - half - sqrt2], axis=-1)
    c = coeffs[..., None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(POLISH_STEPS):
            error = (((c[..., 0] * roots + c[..., 1]) * roots + c[..., 2]) * roots + c[..., 3]) * roots + c[..., 4]
            derivative = ((4 * c[..., 0] * roots + 3 * c[..., 1]) * roots + 2 * c[..., 2]) * roots + c[..., 3]
            roots = roots - error / derivative
    return roots, real


def ap3p_poses(bearings: np.ndarray, body_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The poses cam_from_body of three bearings (S, 3, 3) (unit vectors in the camera)
    of three body points (S, 3, 3) [m]: rotations (S, 4, 3, 3), translations (S, 4, 3) [m]
    and which of the four are poses (S, 4) (Ke and Roumeliotis, section 3, in OpenCV's
    notation)."""
    w1, w2, w3 = body_m[:, 0], body_m[:, 1], body_m[:, 2]
    b1, b2, b3 = bearings[:, 0], bearings[:, 1], bearings[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        k1, nu0 = _unit(w1 - w2)
        k3, nk3 = _unit(np.cross(b1, b2))
        tz = np.cross(b1, k3)
        v1, v2 = np.cross(b1, b3), np.cross(b2, b3)
        u1 = w1 - w3
        u1k1, k3b3 = _dot(u1, k1), _dot(k3, b3)
        nl, delta = _unit(np.cross(u1, k1))
        f11, f13, f15 = k3b3 * delta, _dot(k3, v1) * delta, -u1k1 * k3b3
        u2k1 = u1k1 - nu0
        f21, f22, f23 = _dot(tz, v2), nk3 * k3b3, _dot(k3, v2)
        f24, f25 = u2k1 * f22, -u2k1 * f21
        f21, f22, f23 = f21 * delta, f22 * delta, f23 * delta
        g1, g2, g3, g4 = f13 * f22, f13 * f25 - f15 * f23, f11 * f23 - f13 * f21, -f13 * f24
        g5, g6, g7 = f11 * f22, f11 * f25 - f15 * f21, -f15 * f24
        coeffs = np.stack([g5 * g5 + g1 * g1 + g3 * g3, 2 * (g5 * g6 + g1 * g2 + g3 * g4),
                           g6 * g6 + 2 * g5 * g7 + g2 * g2 + g4 * g4 - g1 * g1 - g3 * g3,
                           2 * (g6 * g7 - g1 * g2 - g3 * g4), g7 * g7 - g2 * g2 - g4 * g4], axis=-1)
        cos1, real = quartic_roots(coeffs)  # (S, 4): cos(theta1')
        sin1 = np.sqrt(1 - cos1 * cos1) * np.where(k3b3 > 0, 1.0, -1.0)[:, None]
        n3 = sin1 / ((g5[:, None] * cos1 + g6[:, None]) * cos1 + g7[:, None])
        cos3, sin3 = (g1[:, None] * cos1 + g2[:, None]) * n3, (g3[:, None] * cos1 + g4[:, None]) * n3
        zero = np.zeros_like(cos1)
        c13 = np.stack([np.stack([cos3, zero, -sin3], -1), np.stack([sin1 * sin3, cos1, sin1 * cos3], -1),
                        np.stack([cos1 * sin3, -sin1, cos1 * cos3], -1)], -2)  # (S, 4, 3, 3)
        body_from_cam = (np.stack([k1, nl, np.cross(k1, nl)], -1)[:, None] @ c13
                         @ np.stack([b1, k3, tz], -2)[:, None])
        rotations = np.swapaxes(body_from_cam, -1, -2)
        translations = (sin1[..., None] * (b3 * (delta / k3b3)[:, None])[:, None]
                        - (w3[:, None, None] @ body_from_cam)[:, :, 0])
    finite = np.all(np.isfinite(rotations), axis=(-1, -2)) & np.all(np.isfinite(translations), axis=-1)
    solved = real & (np.abs(cos1) <= 1) & finite
    # C13 is a rotation where cos3^2 + sin3^2 = 1 (the other factors are by construction): a
    # root off by a little leaves it off the unit circle (by 1e-5 near cos(theta1') = +-1), and
    # OpenCV's Rodrigues then takes the nearest rotation; so do we
    off = solved & (np.abs(cos3 * cos3 + sin3 * sin3 - 1) > ORTHONORMAL_TOLERANCE)
    if off.any():
        rotations[off] = g.project_to_so3(rotations[off])
    return rotations, translations, solved


def solve_p4p(body_m: np.ndarray, image_px: np.ndarray, camera_matrix: np.ndarray,
              dist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cam_from_body of each sample of 4 body points (S, 4, 3) [m] seen at 4 distorted
    pixels (S, 4, 2): rotations (S, 3, 3), translations (S, 3) [m], and which samples have
    a pose (S,) (elsewhere NaN); OpenCV's AP3P choice among the first three points' poses."""
    body_m, image_px = np.asarray(body_m, np.float64), np.asarray(image_px, np.float64)
    camera_matrix = np.asarray(camera_matrix, np.float64)
    normalised = undistort_normalized(image_px, camera_matrix, dist)
    rays = np.concatenate([normalised, np.ones(normalised.shape[:-1] + (1,))], axis=-1)
    rotations, translations, solved = ap3p_poses(_unit(rays[:, :3])[0], body_m[:, :3])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        in_camera = body_m[:, None] @ np.swapaxes(rotations, -1, -2) + translations[:, :, None]  # (S, 4, 4, 3)
        fourth = in_camera[:, :, 3]
        fourth_off = fourth[..., :2] / fourth[..., 2:] - normalised[:, None, 3]
        fourth_error = fourth_off[..., 0] ** 2 + fourth_off[..., 1] ** 2
        off = g.project_points(in_camera, camera_matrix, dist) - image_px[:, None]  # (S, 4, 4, 2)
        error = (off[..., 0] ** 2 + off[..., 1] ** 2).sum(axis=-1)
    # NaN errors (a NaN input point) sort last among the solved roots, never below an unsolved one
    error, fourth_error = np.nan_to_num(error, nan=np.inf), np.nan_to_num(fourth_error, nan=np.inf)
    order = np.lexsort((np.broadcast_to(np.arange(4), error.shape), fourth_error, error, ~solved), axis=-1)
    best = order[:, 0]
    rows = np.arange(len(best))
    found = solved[rows, best]
    return (np.where(found[:, None, None], rotations[rows, best], np.nan),
            np.where(found[:, None], translations[rows, best], np.nan), found)
