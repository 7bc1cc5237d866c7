"""Bayesian fusion of pose estimates and the motion-capture rejection test (the paper's
"Data Fusion" section: Park, Bosse and D'Amico, "Robotic Testbed for Rendezvous and Optical
Navigation: Multi-Source Calibration and Machine Learning Use Cases", AAS/AIAA
Astrodynamics Specialist Conference, 2021), shared by calibrate (Table 1) and fuse (the
dataset). The rotation mean is the chordal L2 mean (Hartley, Trumpf, Dai and Li,
"Rotation Averaging", IJCV 103, 2013).

Positions fuse per camera axis by inverse variance; rotations by the weighted chordal mean
with the paper's weights ``w_K = s_V^2 / (s_K^2 + s_V^2)``; the fused variance is
``(s_1^-2 + s_2^-2)^-1``. Sigmas are 1-sigma: ``sigma_t_m`` (3,) per camera axis, metres;
``sigma_r_rad`` the rotation angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from manifests.sidecars import SigmaRecord
from stages.common import geometry as g

REJECTION_K = 1.96
#: one-sided level of the test that two sources disagree on an axis beyond their sigmas
CONSISTENCY_LEVEL = 0.95
#: medians of chi-square variables with 1 and 3 degrees of freedom: a robust scale of a
#: normal component (|r| / 0.6745) and of an isotropic rotation's squared angle
_CHI2_1_MEDIAN = 0.454936
_CHI2_3_MEDIAN = 2.365974


@dataclass(frozen=True)
class Sigma:
    t_m: np.ndarray  # (3,)
    r_rad: float
    pointing_rad: float | None = None  # the part of r_rad that turns the line of sight (None: all of it)

    def to_record(self) -> SigmaRecord:
        return SigmaRecord(tuple(float(v) for v in self.t_m), float(self.r_rad),
                           None if self.pointing_rad is None else float(self.pointing_rad))

    @classmethod
    def from_record(cls, record: SigmaRecord) -> Sigma:
        return cls(np.array(record.t_m), record.r_rad, record.pointing_rad)


def lever_sq(t: np.ndarray) -> np.ndarray:
    """Per camera axis, ``|t|^2 - t_i^2`` (m^2) of positions (..., 3): how much a rotation of
    the line of sight moves a target at ``t`` along that axis (``d t = d theta x t``)."""
    t = np.asarray(t, dtype=float)
    return np.sum(t**2, axis=-1, keepdims=True) - t**2


def at_position(sigma: Sigma, t: np.ndarray, calibration_lever_sq: np.ndarray) -> Sigma:
    """Sigma of a pose whose target is at ``t`` (3,) in the camera frame, from a sigma measured
    on calibration samples whose mean ``lever_sq`` was ``calibration_lever_sq`` (3,).

    A rotation error ``d`` of the line of sight (RMS angle ``sigma.pointing_rad``; all of
    ``r_rad`` when unknown, which is conservative) moves the target by ``d x t``. Taken as
    isotropic, each component of ``d`` has variance ``s^2 / 3``, so along axis i the
    variance grows by ``s^2 / 3 (lever_sq(t)_i - lever_sq(calibration)_i)``.
    Distance-independent errors keep their calibrated size."""
    pointing = sigma.r_rad if sigma.pointing_rad is None else sigma.pointing_rad
    grow = pointing**2 / 3 * np.maximum(lever_sq(t) - np.asarray(calibration_lever_sq), 0.0)
    return Sigma(np.sqrt(sigma.t_m**2 + grow), sigma.r_rad, sigma.pointing_rad)


def with_scale_error(sigma: Sigma, t: np.ndarray, calibration_distance_m: float, scale_sigma: float) -> Sigma:
    """``sigma`` of a source whose distances err by one common scale factor (1-sigma
    ``scale_sigma``, e.g. a motion-capture system's wand calibration), for a target at ``t``
    (3,) in the camera frame. The calibration's offsets absorbed the error at its own
    distance ``calibration_distance_m``; beyond it the error is ``s (|t| - d_cal)`` along the
    line of sight, ``s t_i (1 - d_cal / |t|)`` on axis i."""
    t = np.asarray(t, dtype=float)
    grow = (scale_sigma * t * (1.0 - calibration_distance_m / np.linalg.norm(t))) ** 2
    return Sigma(np.sqrt(sigma.t_m**2 + grow), sigma.r_rad, sigma.pointing_rad)


def sigma_between(estimates: np.ndarray, references: np.ndarray) -> Sigma:
    """The paper's variances of ``estimates`` about ``references`` (N, 4, 4): per camera axis
    ``sum (t - t_ref)^2 / (N - 1)``, and the same of the rotation angle.

    Also the pointing share of the rotation error: a rotation ``d`` of the line of sight
    moves the target by ``d x t``, one of the target about itself does not. Regressing the
    translation errors on ``d x t`` gives the share ``a`` (0..1) of the rotation variance
    that turns the line of sight: ``pointing = sqrt(a) * sigma_r``."""
    n = len(estimates)
    if n < 2:
        raise ValueError("variances need at least two samples")
    dt = estimates[:, :3, 3] - references[:, :3, 3]
    angle = g.angular_distance(estimates[:, :3, :3], references[:, :3, :3])
    rotation_error = g.matrix_to_rotvec(estimates[:, :3, :3] @ np.swapaxes(references[:, :3, :3], -1, -2))
    lever = np.cross(rotation_error, references[:, :3, 3])
    share = float(np.clip(np.sum(lever * dt) / max(np.sum(lever * lever), 1e-30), 0.0, 1.0))
    sigma_r = float(np.sqrt(np.sum(angle**2) / (n - 1)))
    return Sigma(np.sqrt(np.sum(dt**2, axis=0) / (n - 1)), sigma_r, float(np.sqrt(share) * sigma_r))


@dataclass(frozen=True)
class VarianceFactor:
    """A posteriori scale of the calibrated sigmas on the dataset captures, common to both
    sources: per camera axis ``t`` (3,) and for the rotation angle ``r``, from ``samples``
    two-source captures."""

    t: np.ndarray
    r: float
    samples: int

    def scale(self, sigma: Sigma) -> Sigma:
        pointing = None if sigma.pointing_rad is None else sigma.pointing_rad * self.r
        return Sigma(sigma.t_m * self.t, sigma.r_rad * self.r, pointing)

    def to_json(self) -> dict:
        return {"t": [float(v) for v in self.t], "r": float(self.r), "samples": self.samples}

    def inconsistent(self) -> np.ndarray:
        """Per camera axis (3,) bool: the sources disagree beyond their sigmas, i.e. the
        factor exceeds what two consistent sources show on this many captures."""
        if self.samples == 0:
            return np.zeros(3, bool)
        return self.t > consistency_bound(self.samples)


UNIT_FACTOR = VarianceFactor(np.ones(3), 1.0, 0)


def consistency_bound(samples: int, level: float = CONSISTENCY_LEVEL) -> float:
    """The position factor of ``variance_factor`` that two sources whose sigmas hold exceed
    with probability ``1 - level`` on ``samples`` captures. The factor is
    ``sqrt(median(r^2) / median(chi2_1))`` of normalised disagreements ``r``; the sample
    median is at most the order statistic ``k = n // 2 + 1`` (the upper of the two middle
    ones when n is even), whose CDF value is Beta(k, n + 1 - k)."""
    from scipy.stats import beta, chi2
    k = samples // 2 + 1
    quantile = chi2.ppf(beta.ppf(level, k, samples + 1 - k), 1)
    return float(np.sqrt(quantile / _CHI2_1_MEDIAN))


def variance_factor(pose_a: np.ndarray, pose_b: np.ndarray, sigma_difference: list[Sigma]) -> VarianceFactor:
    """How much larger two independent sources' disagreement on these captures (poses
    (N, 4, 4)) is than the calibrated sigma of their difference (per capture) says.

    The difference's variance is ``s_a^2 + s_b^2``: which source grew cannot be told
    without a third, so the factor is common to both (variance component estimation with
    one component). Medians, not means: a ghost marker or a mislabelled body must not
    inflate it much (a fifth of them move it by about a third: a test flags consistent
    sources more often then, and the fall-back costs only sigma). Only inflation (>= 1): a
    short session cannot show the sources better than their calibration."""
    difference = pose_b[:, :3, 3] - pose_a[:, :3, 3]
    normalised = difference / np.stack([s.t_m for s in sigma_difference])
    t = np.maximum(np.sqrt(np.median(normalised**2, axis=0) / _CHI2_1_MEDIAN), 1.0)
    # sigma_r is the RMS angle; an isotropic error's squared angle is that times chi2_3 / 3
    angle = g.angular_distance(pose_b[:, :3, :3], pose_a[:, :3, :3])
    ratio = (angle / np.array([s.r_rad for s in sigma_difference])) ** 2
    r = max(float(np.sqrt(np.median(ratio) / (_CHI2_3_MEDIAN / 3))), 1.0)
    return VarianceFactor(t, r, len(pose_a))


def without_reference_noise(sigma: Sigma, reference_var_t: np.ndarray, reference_var_r: float,
                            floor: float = 0.1) -> Sigma:
    """A source's sigma measured against a noisy reference (PnP), with the reference's own
    mean variance (per axis ``reference_var_t`` (3,) m^2, angle ``reference_var_r`` rad^2)
    removed: ``s^2 = s_measured^2 - s_reference^2``. Differences of independent errors add
    their variances; without this a source far better than PnP would be credited with
    PnP's noise and under-weighted in the fusion. ``floor``: the variance never drops
    below that fraction of the measured one (a few dozen samples estimate both roughly)."""
    var_t = np.maximum(sigma.t_m**2 - np.asarray(reference_var_t), floor * sigma.t_m**2)
    var_r = max(sigma.r_rad**2 - reference_var_r, floor * sigma.r_rad**2)
    share = 1.0 if sigma.pointing_rad is None else (sigma.pointing_rad / max(sigma.r_rad, 1e-300)) ** 2
    r = float(np.sqrt(var_r))
    return Sigma(np.sqrt(var_t), r, None if sigma.pointing_rad is None else float(np.sqrt(share) * r))


def fuse(pose_a: np.ndarray, sigma_a: Sigma, pose_b: np.ndarray, sigma_b: Sigma) -> tuple[np.ndarray, Sigma]:
    """Fused ``cam_from_target`` (4, 4) of two estimates (4, 4) and its sigma."""
    var_a, var_b = sigma_a.t_m**2, sigma_b.t_m**2
    t = (var_b * pose_a[:3, 3] + var_a * pose_b[:3, 3]) / (var_a + var_b)
    rvar_a, rvar_b = sigma_a.r_rad**2, sigma_b.r_rad**2
    weights = np.array([rvar_b, rvar_a]) / (rvar_a + rvar_b)
    rotation = g.chordal_mean(np.stack([pose_a[:3, :3], pose_b[:3, :3]]), weights)
    fused = Sigma(np.sqrt(var_a * var_b / (var_a + var_b)), float(np.sqrt(rvar_a * rvar_b / (rvar_a + rvar_b))))
    return g.make_transform(rotation, t), fused


def rejection_reason(pose_kuka: np.ndarray, pose_vicon: np.ndarray | None, sigma: Sigma,
                     k: float = REJECTION_K) -> str | None:
    """Why motion capture is rejected against the robots' estimate, or None to accept:
    missing, or beyond ``k`` sigma (strictly) in any position component or in angle."""
    if pose_vicon is None:
        return "not tracked"
    if not np.all(np.isfinite(pose_vicon)):
        return "non-finite pose"
    difference = np.abs(pose_vicon[:3, 3] - pose_kuka[:3, 3])
    for axis, name in enumerate("xyz"):
        if difference[axis] > k * sigma.t_m[axis]:
            return (f"{name} differs by {difference[axis] * 1000:.2f} mm > {k} sigma "
                    f"({k * sigma.t_m[axis] * 1000:.2f} mm)")
    angle = float(g.angular_distance(pose_vicon[:3, :3], pose_kuka[:3, :3]))
    if angle > k * sigma.r_rad:
        return (f"rotation differs by {np.degrees(angle):.3f} deg > {k} sigma "
                f"({np.degrees(k * sigma.r_rad):.3f} deg)")
    return None
