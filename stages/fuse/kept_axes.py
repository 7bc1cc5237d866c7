"""Each source's own factor on an axis kept from one source (docs/architecture.md section 6).

The session's variance factor ``f`` (``variance_factor``) measures how much the two sources'
differences exceed their predicted variance ``d^2`` (the calibration's difference sigma grown
to each capture, about ``s_k^2 + s_v^2``). On a fused axis
it scales both alike: the sources passed the consistency test there, so the excess is small
and how it splits barely moves the fused label. On an axis kept from one source
(``axis_sources``) the sources failed it, and the kept source's sigma is the label's. Scaled
by ``f`` it would carry the other source's excess too: on a session whose motion capture errs
twice its marker model at 4 m (``s_v`` eight times the robots'), ``f = 1.9`` made the kept
robots' sigmas twice their errors.

Which source erred cannot be told from the differences alone (``session.better_source``),
but how far each explanation puts a source off its calibrated sigma can. Each source's true
standard deviation is ``a s`` with ``ln a`` normal, of standard deviation ``ln(doubt)``
(``fuse.sigma_doubt``) and mean ``-ln(doubt)^2``, so that the prior expectation of ``a^2`` is
1: without evidence the calibrated variance is the expected one. The measured ``f^2`` is the
median of ``N`` squared normalised differences over its median under the model, so
``ln f^2`` is normal about ``ln rho``, ``rho = (a_k^2 s_k^2 + a_v^2 s_v^2) / d^2``,
with standard deviation ``1 / (2 p(m) m sqrt(N))`` (the sample median's asymptotic variance;
``m`` the chi-square(1) median, ``p`` its density; 0.336 at 48 captures), censored at
``f = 1``, where the factor is floored. Each source's factor is the square root of its
posterior mean ``a^2`` on a grid, never below 1 (the factor's own rule: a session never
shows a source better than its calibration). Gelman et al., Bayesian Data Analysis, 3rd ed.,
section 5.3 (a hierarchical variance's posterior by grid).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: grid points per log-factor: from the prior's 5 standard deviations below its centre to 5 above
#: where its ``a^2`` weighs most (``+ln(doubt)^2``), or past the factor that would put the
#: whole excess on the source with the smaller sigma
_GRID = 361


@dataclass(frozen=True)
class SourceFactors:
    """Per camera axis (3,) the factor that scales each source's own sigma: the session's
    common factor on a fused axis, each source's expected share of the excess on an axis
    kept from one source (``expected_factors``)."""

    kuka_t: np.ndarray
    vicon_t: np.ndarray

    @classmethod
    def common(cls, t: np.ndarray) -> SourceFactors:
        return cls(np.asarray(t, float).copy(), np.asarray(t, float).copy())

    def of(self, source: str) -> np.ndarray:
        """The factors (3,) of ``source`` ("kuka" or "vicon")."""
        return self.kuka_t if source == "kuka" else self.vicon_t


def expected_factors(factor: float, samples: int, sigma_kuka: float, sigma_vicon: float, sigma_difference: float,
                     doubt: float) -> tuple[float, float]:
    """(robots', motion capture's) factors on one axis: the square root of each source's
    posterior mean ``a^2`` given the measured ``factor`` on ``samples`` captures, the sources'
    predicted errors ``sigma_kuka``, ``sigma_vicon`` and the difference's ``sigma_difference``
    that the factor was measured against (m, any common unit), each at least 1. ``doubt``
    (> 1): ``exp`` of one prior standard deviation of a source's log factor. Where nothing
    can be split (no captures, a zero or non-finite sigma), both take the common factor."""
    from scipy.stats import chi2, norm
    common = max(float(factor), 1.0)
    values = (factor, sigma_kuka, sigma_vicon, sigma_difference)
    if samples < 1 or not all(np.isfinite(values)) or min(sigma_kuka, sigma_vicon, sigma_difference) <= 0:
        return common, common
    spread = np.log(doubt)
    centre = -spread**2
    whole = 0.5 * np.log(common**2 * sigma_difference**2 / min(sigma_kuka, sigma_vicon) ** 2)
    grid = np.linspace(centre - 5 * spread, max(spread**2 + 5 * spread, whole + 2 * spread), _GRID)
    log_k, log_v = np.meshgrid(grid, grid, indexing="ij")
    prior = norm.logpdf(log_k, centre, spread) + norm.logpdf(log_v, centre, spread)
    rho = (np.exp(2 * log_k) * sigma_kuka**2 + np.exp(2 * log_v) * sigma_vicon**2) / sigma_difference**2
    median = chi2.ppf(0.5, 1)
    sd = 1.0 / (2.0 * chi2.pdf(median, 1) * median * np.sqrt(samples))
    # a floored factor says only that the excess is at most what the median shows
    likelihood = (norm.logcdf(-np.log(rho) / sd) if factor <= 1.0
                  else norm.logpdf(np.log(factor**2), np.log(rho), sd))
    log_posterior = prior + likelihood
    weight = np.exp(log_posterior - log_posterior.max())
    weight /= weight.sum()
    return (max(float(np.sqrt(np.sum(weight * np.exp(2 * log_k)))), 1.0),
            max(float(np.sqrt(np.sum(weight * np.exp(2 * log_v)))), 1.0))


def source_factors(factor_t: np.ndarray, samples: int, sources: tuple[str, str, str], predicted_kuka: np.ndarray,
                   predicted_vicon: np.ndarray, predicted_difference: np.ndarray, doubt: float) -> SourceFactors:
    """Each source's factors (``SourceFactors``) on a session whose common factor is
    ``factor_t`` (3,), measured on ``samples`` captures against ``predicted_difference`` (3,)
    m, with ``sources`` per axis (``AXIS_SOURCES``) and each source's predicted error (3,) m."""
    kuka_t, vicon_t = np.asarray(factor_t, float).copy(), np.asarray(factor_t, float).copy()
    for axis, source in enumerate(sources):
        if source != "fused":
            kuka_t[axis], vicon_t[axis] = expected_factors(
                float(factor_t[axis]), samples, float(predicted_kuka[axis]), float(predicted_vicon[axis]),
                float(predicted_difference[axis]), doubt)
    return SourceFactors(kuka_t, vicon_t)
