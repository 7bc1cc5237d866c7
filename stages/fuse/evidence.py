"""Which source is the better on a position axis, from what the dataset session shows
(docs/architecture.md section 6): the fall-back's and the session offset's choice.

Two sources that disagree beyond their sigmas cannot say from one capture which of them
is off. Over a session they can, where their sigmas vary differently from capture to
capture: the variance of their difference at capture ``i`` is ``alpha a_i + beta b_i``
(``a_i``, ``b_i``: the robots' and motion capture's predicted variances there; ``alpha``,
``beta``: how far each source's errors exceed its prediction), and the squared
differences over the session determine both factors (variance component estimation:
Helmert 1907; Foerstner, Z. Vermessungswesen 104, 1979; Koch, Parameter Estimation and
Hypothesis Testing in Linear Models, 2nd ed., 1999, 3.6). Motion capture's ``b_i`` swings
with the markers its fit used (``marker_geometry``) and with the line of sight's lever,
the robots' ``a_i`` with their configuration: a motion capture that errs where its markers
are poorly placed shows in ``beta``, not in ``alpha``.

The factors are estimated by iteratively reweighted least squares on the squared
differences (``Var(d^2) = 2 E(d^2)^2`` for a normal ``d``), each capped at the 99.9% point so
that a ghost marker does not decide, with a weak prior at 1 for each (``PRIOR_DOF``
degrees of freedom: the propagated sigmas hold until the session shows otherwise). Each
source's expected squared error on the session is then its factor times its median
predicted variance, and the source with the smaller one is the better: a Bayes decision
under squared loss. Where the captures cannot separate the two (their sigmas swing
together), the estimate stays near the prior, and the propagated sigmas decide: the
robots' from their calibrated arms and joints at each configuration, motion capture's
from its fit's geometry at each capture with the marker noise its own residuals show. A
smaller sigma claimed once at the calibration, as before, no longer decides alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

#: degrees of freedom of each factor's prior at 1 (weak: two captures' worth)
PRIOR_DOF = 2.0
_ITERATIONS = 30


@dataclass(frozen=True)
class SourceEvidence:
    """Per camera axis (3,): each source's variance factor as the session shows it and its
    expected squared error on the session (m^2), and the better source ("kuka"/"vicon")."""

    robots_factor: np.ndarray
    vicon_factor: np.ndarray
    robots_m2: np.ndarray
    vicon_m2: np.ndarray

    @property
    def better(self) -> np.ndarray:
        return np.where(self.robots_m2 <= self.vicon_m2, "kuka", "vicon")

    def words(self) -> str:
        return "expected error robots/motion capture (mm), their factors: " + ", ".join(
            f"{a} {np.sqrt(k) * 1000:.2f}/{np.sqrt(v) * 1000:.2f} ({fk:.2f}/{fv:.2f})"
            for a, k, v, fk, fv in zip("xyz", self.robots_m2, self.vicon_m2, self.robots_factor, self.vicon_factor,
                                       strict=True))


def two_components(squares: np.ndarray, robots_m2: np.ndarray, vicon_m2: np.ndarray) -> tuple[float, float]:
    """``(alpha, beta)`` >= 0 of ``E(squares) = alpha robots_m2 + beta vicon_m2`` (all (N,)),
    by reweighted least squares with the prior (module docstring): first on the squares as
    they are, then twice more with each capped at the 99.9% point of what the fit expects
    of it (a cap from the start, at the prior, would hold the factors down)."""
    # the prior as PRIOR_DOF pseudo-captures of each source alone at its median variance,
    # each showing its factor at 1: weighted as captures are, it holds as much as they do
    prior = np.diag([np.median(robots_m2), np.median(vicon_m2)])
    design = np.concatenate([np.stack([robots_m2, vicon_m2], axis=1), prior])
    counts = np.concatenate([np.ones(len(squares)), np.full(2, PRIOR_DOF)])
    factors = np.ones(2)
    for cap in (np.inf, chi2.ppf(0.999, 1), chi2.ppf(0.999, 1)):
        capped = np.minimum(squares, cap * np.maximum(design[:len(squares)] @ factors, 1e-30))
        factors = _reweighted(design, np.concatenate([capped, np.diag(prior)]), counts, factors)
    return float(factors[0]), float(factors[1])


def _reweighted(design: np.ndarray, squares: np.ndarray, counts: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """The factors (2,) that rounds of weights ``counts / (2 E^2)`` converge to."""
    for _ in range(_ITERATIONS):
        weights = counts / (2.0 * np.maximum(design @ factors, 1e-30) ** 2)
        normal = design.T @ (design * weights[:, None])
        updated = np.maximum(np.linalg.solve(normal, design.T @ (squares * weights)), 1e-6)
        if np.allclose(updated, factors, rtol=1e-9, atol=1e-12):
            return updated
        factors = updated
    return factors


def source_evidence(differences: np.ndarray, robots_m2: np.ndarray, vicon_m2: np.ndarray) -> SourceEvidence:
    """From the two-source captures' differences (N, 3) (motion capture minus robots, m),
    the robots' and motion capture's predicted variances (N, 3) m^2 per camera axis. The
    differences are taken about their median: a session offset is another matter
    (``session.session_offset``)."""
    centred = differences - np.median(differences, axis=0)
    factors = np.array([two_components(centred[:, a] ** 2, robots_m2[:, a], vicon_m2[:, a]) for a in range(3)])
    return SourceEvidence(factors[:, 0], factors[:, 1], factors[:, 0] * np.median(robots_m2, axis=0),
                          factors[:, 1] * np.median(vicon_m2, axis=0))
