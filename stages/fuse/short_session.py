"""The sigmas of a session too short to measure its own variance factor (docs/architecture.md
section 6): fewer two-source captures than ``fuse.min_scale_samples``, or one source only.

The calibrated sigma of a source is the spread of its in-sample residuals against PnP: the
residuals of a fit to the very samples it measures them on. With few calibration samples
and many parameters (the arms' kinematics, the offsets, the fixtures' compliance) the fit
follows their noise, and the residuals are far smaller than the error at a capture it did
not see. The calibration's cross-validation measured exactly that error: each fold is
predicted by a fit without it. So, where the dataset cannot measure the factor, each
source's sigma is scaled by the ratio of its cross-validated to its in-sample RMS error
(never below 1), position and rotation apart (the whole rotation error then taken to turn
the line of sight: the share that does was regressed on the same in-sample residuals; the
arms' parameter covariance, fitted on the same samples, by the position's), and by a
Student-t allowance for the few
samples behind it: ``t(0.975, n - 1) / z(0.975)``, the widening that keeps 1.96 sigma a 95%
interval when the variance is estimated from ``n`` samples. A longer session measures
its factor on its own captures instead (``session.session_factor``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.stats import norm
from scipy.stats import t as student_t

from stages.common.fusion import Sigma

if TYPE_CHECKING:
    from stages.fuse import SourceModel


def _rms(metric: list[float]) -> float:
    """RMS of Table 1's ``[mean, std]`` of an error."""
    return float(np.hypot(metric[0], metric[1]))


def cross_validated(sigma: Sigma, metrics: dict[str, Any], samples: int) -> tuple[Sigma, str, float]:
    """``sigma`` (calibrated, in-sample) widened to what the calibration's cross-validation
    measured (module docstring), how, in words, and the position's widening (its ratio
    times the allowance: the arms' parameter covariance, fitted on the same samples, is as
    much too narrow); ``samples``: those the calibration used."""
    cross, inside, record = metrics.get("cross_validated"), metrics["in_sample"], metrics.get("cross_validation", {})
    if cross is None or not record.get("judged", False):
        ratio_t = ratio_r = 1.0
        basis, count = "no judged cross-validation: in-sample", samples
    else:
        ratio_t = max(_rms(cross["E_T_m"]) / max(_rms(inside["E_T_m"]), 1e-12), 1.0)
        ratio_r = max(_rms(cross["E_R_rad"]) / max(_rms(inside["E_R_rad"]), 1e-12), 1.0)
        basis, count = "cross-validated / in-sample", int(record.get("samples", samples))
    allowance = float(student_t.ppf(0.975, count - 1) / norm.ppf(0.975)) if count >= 2 else 1.0
    # the share of the rotation error that turns the line of sight was regressed on the same
    # in-sample residuals; unknown here, all of it is taken (``fusion.at_position``: conservative)
    widened = Sigma(sigma.t_m * ratio_t * allowance, sigma.r_rad * ratio_r * allowance, None)
    return widened, (f"{basis} position x{ratio_t:.2f}, rotation x{ratio_r:.2f}, Student-t on {count} samples "
                     f"x{allowance:.2f}"), ratio_t * allowance


def widened_rejection(rejection: Sigma, before: dict[str, Sigma], after: dict[str, Sigma]) -> Sigma:
    """The rejection sigma (of the two sources' difference) widened as the sources' sigmas
    were: the difference's variance is the sum of theirs."""
    t_before = sum(s.t_m**2 for s in before.values())
    t_after = sum(s.t_m**2 for s in after.values())
    r_before = sum(s.r_rad**2 for s in before.values())
    r_after = sum(s.r_rad**2 for s in after.values())
    ratio_t = np.sqrt(t_after / np.maximum(t_before, 1e-30))
    ratio_r = float(np.sqrt(r_after / max(r_before, 1e-30)))
    pointing = None if rejection.pointing_rad is None else rejection.pointing_rad * ratio_r
    return Sigma(rejection.t_m * ratio_t, rejection.r_rad * ratio_r, pointing)


def widened_for_short_session(kuka: SourceModel, vicon: SourceModel | None,
                              rejection: Sigma | None) -> tuple[Sigma | None, str]:
    """Each source's calibrated sigma widened to its cross-validated error
    (``short_session.cross_validated``), and the rejection sigma with them."""
    sources = {"robots": kuka} if vicon is None else {"robots": kuka, "motion capture": vicon}
    before = {name: source.sigma for name, source in sources.items()}
    words = []
    for name, source in sources.items():
        source.sigma, how, source.parameter_scale = cross_validated(source.sigma, source.metrics, source.samples)
        words.append(f"{name} {how}")
    if rejection is not None:
        rejection = widened_rejection(rejection, before, {name: s.sigma for name, s in sources.items()})
    return rejection, f"; too short a session to measure the factor, so the sigmas are widened: {'; '.join(words)}"
