"""How well a motion-capture rigid body's marker fit determines the pose of the body it is
stuck on (docs/architecture.md section 6), shared by the marker choice, fuse and
``speedplus target``.

The system fits the body's marker model to the markers it triangulated (least squares,
Kabsch). With ``K`` markers seen, each with isotropic noise ``s`` (m, 1-sigma per axis),
the fit's errors to first order are independent: the markers' centroid errs by ``s^2 / K``
per axis, and the rotation (a small rotation vector ``theta``, in the body frame) by

    cov(theta) = s^2 J^-1,   J = sum_i (|q_i|^2 I - q_i q_i^T),   q_i = p_i - mean(p),

the inverse of the markers' inertia tensor about their centroid (Arun, Huang and Blostein,
IEEE PAMI 9(5), 1987, for the fit; Dorst, "First order error propagation of the Procrustes
method for 3D attitude estimation", IEEE PAMI 27(2), 2005, for its covariance). A point ``r``
of the body, the lever ``d = r - mean(p)`` from the centroid, then errs by

    cov(r) = s^2 / K I + [d]x cov(theta) [d]x^T.

Three markers nearly in a line, or markers clustered a panel's length from ``r``, make
``J`` small and ``d`` long: the fit's rotation, and the point it implies, err by
centimetres where the marker noise is a fraction of a millimetre.

The marker noise ``s`` itself is measured from the fits' residuals: a fit of ``K`` markers
leaves ``3K - 6`` degrees of freedom, so ``K`` times a fit's mean squared residual is
``s^2`` times a chi-square with that many (``marker_sigma``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a fit with fewer markers is not tracked (Vicon needs three of a rigid body)
MIN_FIT_MARKERS = 3


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` (..., 3, 3) of vectors (..., 3)."""
    v = np.asarray(v, float)
    zero = np.zeros(v.shape[:-1])
    return np.stack([np.stack([zero, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], zero, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], zero], -1)], -2)


@dataclass(frozen=True)
class FitCovariance:
    """A rigid-body fit's first-order errors per unit marker noise (multiply by ``s^2``):
    ``rotation`` (3, 3) rad^2 per m^2 in the body frame; ``point`` (3, 3) of the point it
    was evaluated at, in the body frame."""

    rotation: np.ndarray
    point: np.ndarray

    def scaled(self, marker_sigma_m: float) -> FitCovariance:
        return FitCovariance(self.rotation * marker_sigma_m**2, self.point * marker_sigma_m**2)


def fit_covariance(markers_m: np.ndarray, point_m: np.ndarray) -> FitCovariance:
    """The fit of markers (K, 3) (body frame, m), evaluated at ``point_m`` (3,), per unit
    marker noise; fewer than three markers, or three in a line, give infinite variances."""
    markers_m = np.asarray(markers_m, float)
    if len(markers_m) < MIN_FIT_MARKERS:
        return FitCovariance(np.full((3, 3), np.inf), np.full((3, 3), np.inf))
    centroid = markers_m.mean(axis=0)
    q = markers_m - centroid
    inertia = np.sum(q * q) * np.eye(3) - q.T @ q
    if np.linalg.cond(inertia) > 1e12:
        return FitCovariance(np.full((3, 3), np.inf), np.full((3, 3), np.inf))
    rotation = np.linalg.inv(inertia)
    lever = skew(np.asarray(point_m, float) - centroid)
    return FitCovariance(rotation, np.eye(3) / len(markers_m) + lever @ rotation @ lever.T)


def mean_point_variance(markers_m: np.ndarray, seen: np.ndarray, point_m: np.ndarray,
                        unseen_m2: float = 1.0) -> np.ndarray:
    """Per candidate set, the mean over view directions of the trace of the fit's position
    variance at ``point_m`` (3,) per unit marker noise (m^2 / m^2), all at once.

    ``markers_m`` (S, K, 3): S candidate sets of K markers; ``seen`` (S, D, K) bool: which
    are seen from each of D directions. A direction that sees fewer than three (or three
    in a line) counts ``unseen_m2``: the body is not tracked from there."""
    weights = seen.astype(float)  # (S, D, K)
    count = weights.sum(axis=-1)  # (S, D)
    safe = np.maximum(count, 1.0)
    first = np.einsum("sdk,ski->sdi", weights, markers_m)
    centroid = first / safe[..., None]
    squares = np.einsum("sdk,ski,skj->sdij", weights, markers_m, markers_m)
    scatter = squares - count[..., None, None] * np.einsum("sdi,sdj->sdij", centroid, centroid)
    inertia = np.trace(scatter, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - scatter
    ok = (count >= MIN_FIT_MARKERS) & (np.linalg.det(inertia) > 1e-12 * np.trace(inertia, axis1=-2, axis2=-1) ** 3)
    inverse = np.linalg.inv(np.where(ok[..., None, None], inertia, np.eye(3)))
    lever = skew(np.asarray(point_m, float) - centroid)
    variance = 3.0 / safe + np.trace(lever @ inverse @ np.swapaxes(lever, -1, -2), axis1=-2, axis2=-1)
    return np.where(ok, variance, unseen_m2).mean(axis=-1)


def marker_sigma(residual_rms_m: np.ndarray, used: np.ndarray) -> float | None:
    """The marker noise (m, 1-sigma per axis) from fits' RMS residuals (N,) over ``used``
    (N,) markers each: the median of ``K rms^2 / median(chi2(3K - 6))`` over the fits, a
    median so that the fits a ghost marker entered barely move it. None without a fit of
    more than three markers (three leave 3 degrees of freedom; all fits count)."""
    from scipy.stats import chi2
    residual_rms_m, used = np.asarray(residual_rms_m, float), np.asarray(used, int)
    keep = np.isfinite(residual_rms_m) & (used >= MIN_FIT_MARKERS)
    if not np.any(keep):
        return None
    dof = 3 * used[keep] - 6
    return float(np.sqrt(np.median(used[keep] * residual_rms_m[keep] ** 2 / chi2.median(dof))))


@dataclass(frozen=True)
class ExpectedAccuracy:
    """What motion capture should give of a target's origin (m, rad; 1-sigma): its own
    markers' fit (median over the mock-up's attitudes under a ring of cameras), the camera
    body's pointing, and the total 3D RMS at each of ``ranges_m`` (camera to target)."""

    fit_position_m: float
    fit_rotation_rad: float
    untracked_share: float
    pointing_rad: float
    ranges_m: tuple[float, ...]
    total_m: tuple[float, ...]


def expected_accuracy(markers_m: np.ndarray, normals: np.ndarray, origin_m: np.ndarray, marker_sigma_m: float,
                      camera_markers_m: np.ndarray, camera_marker_sigma_m: float, scale_sigma: float,
                      calibration_distance_m: float, ranges_m: tuple[float, ...]) -> ExpectedAccuracy:
    """The target body's fit (markers (M, 3) and their normals (M, 3) in T at mock-up
    scale, noise ``marker_sigma_m``) at ``origin_m`` (3,), over the attitudes of
    ``stages.common.markers``; the camera body's (``camera_markers_m`` (C, 3), all seen)
    rotation, which turns the line of sight (2/3 of its variance is across it); and the
    wand's scale error beyond the calibration's distance (``fusion.with_scale_error``)."""
    from stages.common.markers import seen_from_room, up_directions  # the choice's own view model

    seen = seen_from_room(np.asarray(normals, float), up_directions())
    fits = [fit_covariance(markers_m[seen[:, d]], origin_m) for d in range(seen.shape[1])]
    finite = [f for f in fits if np.all(np.isfinite(f.point))]
    position = float(np.sqrt(np.median([np.trace(f.point) for f in finite]))) * marker_sigma_m if finite else np.inf
    rotation = float(np.sqrt(np.median([np.trace(f.rotation) for f in finite]))) * marker_sigma_m if finite else np.inf
    camera = fit_covariance(camera_markers_m, np.zeros(3)).scaled(camera_marker_sigma_m)
    pointing = float(np.sqrt(np.trace(camera.rotation)))
    total = tuple(float(np.sqrt(position**2 + 2 / 3 * (r * pointing) ** 2
                                + (scale_sigma * max(r - calibration_distance_m, 0.0)) ** 2)) for r in ranges_m)
    return ExpectedAccuracy(position, rotation, 1 - len(finite) / len(fits), pointing, tuple(ranges_m), total)
