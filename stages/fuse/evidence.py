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
differences (``Var(d^2) = 2 E(d^2)^2`` for a normal ``d``), the differences taken as
Student-t so that a ghost marker does not decide, with a weak prior at 1 for each (``PRIOR_DOF``
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

import functools
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.stats import norm

#: degrees of freedom of each factor's prior at 1 (weak: two captures' worth)
PRIOR_DOF = 2.0
#: degrees of freedom of the Student-t the differences are taken to follow (heavy tails:
#: ghost markers, a fit of three markers)
TAIL_DOF = 4.0
_ITERATIONS = 200


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
    by reweighted least squares with the prior (module docstring), the differences taken
    as Student-t (``TAIL_DOF``) rather than normal: each square is weighted down by how far
    it lies beyond what the factors expect of it (the EM algorithm of Lange, Little and
    Taylor, JASA 84(408), 1989), so that a ghost marker's 250 mm counts as a few sigma."""
    # the prior as PRIOR_DOF pseudo-captures of each source alone at its median variance,
    # each showing its factor at 1: weighted as captures are, it holds as much as they do
    prior = np.diag([np.median(robots_m2), np.median(vicon_m2)])
    design = np.concatenate([np.stack([robots_m2, vicon_m2], axis=1), prior])
    counts = np.concatenate([np.ones(len(squares)), np.full(2, PRIOR_DOF)])
    # iterated on the Student-t scale, which is ``consistency`` times the variance of
    # normal differences; the prior's pseudo-captures are on that scale too
    consistency = _normal_consistency()
    factors = np.full(2, consistency)
    for _ in range(_ITERATIONS):
        expected = np.maximum(design[:len(squares)] @ factors, 1e-30)
        weight = (TAIL_DOF + 1.0) / (TAIL_DOF + squares / expected)  # the E-step's expected precision
        updated = _reweighted(design, np.concatenate([weight * squares, consistency * np.diag(prior)]), counts,
                              factors)
        if np.allclose(updated, factors, rtol=1e-6, atol=1e-12):
            break
        factors = updated
    return float(updated[0] / consistency), float(updated[1] / consistency)


@functools.cache
def _normal_consistency() -> float:
    """``c``: the Student-t scale's fixed point on normal differences of unit variance,
    ``c = E[(nu + 1) z^2 / (nu + z^2 / c)]`` (the M-step's mean with the E-step's weights):
    the scale divided by it is the variance, so that the factors are 1 where the sigmas hold."""
    def excess(c: float) -> float:
        mean = quad(lambda z: (TAIL_DOF + 1) * z**2 / (TAIL_DOF + z**2 / c) * norm.pdf(z), -np.inf, np.inf)[0]
        return mean - c

    return float(brentq(excess, 0.05, 1.0))


def _reweighted(design: np.ndarray, squares: np.ndarray, counts: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """One weighted least-squares step (2,): weights ``counts / (2 E^2)`` at ``factors``."""
    weights = counts / (2.0 * np.maximum(design @ factors, 1e-30) ** 2)
    normal = design.T @ (design * weights[:, None])
    return np.maximum(np.linalg.solve(normal, design.T @ (squares * weights)), 1e-6)


def source_evidence(differences: np.ndarray, robots_m2: np.ndarray, vicon_m2: np.ndarray) -> SourceEvidence:
    """From the two-source captures' differences (N, 3) (motion capture minus robots, m),
    the robots' and motion capture's predicted variances (N, 3) m^2 per camera axis. The
    differences are taken about their median: a session offset is another matter
    (``session.session_offset``)."""
    centred = differences - np.median(differences, axis=0)
    factors = np.array([two_components(centred[:, a] ** 2, robots_m2[:, a], vicon_m2[:, a]) for a in range(3)])
    return SourceEvidence(factors[:, 0], factors[:, 1], factors[:, 0] * np.median(robots_m2, axis=0),
                          factors[:, 1] * np.median(vicon_m2, axis=0))
