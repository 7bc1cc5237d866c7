"""The sigmas of a session too short to measure its own variance factor (docs/architecture.md
section 6): fewer two-source captures than ``fuse.min_scale_samples``, or one source only.

The calibrated sigma of a source is the spread of its in-sample residuals against PnP: the
residuals of a fit to the very samples it measures them on. With few calibration samples
and many parameters (the arms' kinematics, the offsets, the fixtures' compliance) the fit
follows their noise, and the residuals are far smaller than the error at a capture it did
not see. The calibration's cross-validation measured exactly that error: each fold is
predicted by a fit without it. So, where the dataset cannot measure the factor, each
source's sigma is scaled by the ratio of its cross-validated to its in-sample RMS error
(never below 1; both sources by the larger of the two ratios, so that the fusion's weights
stay the calibration's: a fit that follows its samples more says little of which source
errs more at the dataset's range), position and rotation apart (the whole rotation error
then taken to turn the line of sight: the share that does was regressed on the same
in-sample residuals; the arms' parameter covariance, fitted on the same samples, and
motion capture's marker fit by the position's), and by a Student-t allowance for the few
samples behind it: ``t(0.975, n - 1) / z(0.975)``, the widening that keeps 1.96 sigma a 95%
interval when the variance is estimated from ``n`` samples. A longer session measures
its factor on its own captures instead (``session.session_factor``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from manifests.sidecars import Metrics
from stages.common.fusion import Sigma

if TYPE_CHECKING:
    from stages.fuse.marker_geometry import MarkerGeometry
    from stages.fuse.stage import SourceModel


def _rms(metric: list[float]) -> float:
    """RMS of Table 1's ``[mean, std]`` of an error."""
    return float(np.hypot(metric[0], metric[1]))


@dataclass(frozen=True)
class Widening:
    """How much wider a source's sigma is than its calibration says: position and rotation
    (each ratio times the Student-t allowance), and how, in words."""

    position: float
    rotation: float
    words: str

    def of(self, sigma: Sigma) -> Sigma:
        """``sigma`` widened; the share of its rotation that turns the line of sight was
        regressed on the same in-sample residuals, so all of it is taken (conservative,
        ``fusion.at_position``)."""
        return Sigma(sigma.t_m * self.position, sigma.r_rad * self.rotation, None)


def cross_validated(metrics: Metrics, samples: int) -> Widening:
    """A source's widening to what its calibration's cross-validation measured (module
    docstring), from its Table 1 ``metrics``; ``samples``: those the calibration used."""
    from scipy.stats import norm
    from scipy.stats import t as student_t
    cross, inside, record = metrics.cross_validated, metrics.in_sample, metrics.cross_validation
    if cross is None or not record.judged:
        ratio_t = ratio_r = 1.0
        basis, count = "no judged cross-validation: in-sample", samples
    else:
        ratio_t = max(_rms(cross.E_T_m) / max(_rms(inside.E_T_m), 1e-12), 1.0)
        ratio_r = max(_rms(cross.E_R_rad) / max(_rms(inside.E_R_rad), 1e-12), 1.0)
        basis, count = "cross-validated / in-sample", record.samples
    allowance = float(student_t.ppf(0.975, count - 1) / norm.ppf(0.975)) if count >= 2 else 1.0
    return Widening(ratio_t * allowance, ratio_r * allowance,
                    f"{basis} position x{ratio_t:.2f}, rotation x{ratio_r:.2f}, Student-t on {count} samples "
                    f"x{allowance:.2f}")


def widened_for_short_session(kuka: SourceModel, vicon: SourceModel | None, rejection: Sigma | None,
                              geometry: MarkerGeometry | None) -> tuple[Sigma | None, MarkerGeometry | None, str]:
    """Both sources' calibrated sigmas (and the arms' parameter covariance and motion
    capture's marker fit; not the rejection test's sigma) widened by the larger of their
    cross-validated widenings (``cross_validated``): which of two sources overfits its
    calibration more says nothing of which errs more at the dataset's range, so the
    weights of the fusion stay what they were."""
    sources = {"robots": kuka} if vicon is None else {"robots": kuka, "motion capture": vicon}
    each = {name: cross_validated(source.metrics, source.samples) for name, source in sources.items()}
    common = Widening(max(w.position for w in each.values()), max(w.rotation for w in each.values()),
                      "; ".join(f"{name} {w.words}" for name, w in each.items()))
    for source in sources.values():
        source.sigma = common.of(source.sigma)
        source.parameter_scale = common.position
    # the rejection test keeps the calibrated sigmas: widened, it would let a motion
    # capture that errs by a centimetre into labels whose robots were the better
    if geometry is not None:
        geometry = dataclasses.replace(geometry, marker_sigma_m=geometry.marker_sigma_m * common.position)
    return rejection, geometry, (f"; too short a session to measure the factor, so both sigmas are widened by "
                                 f"the larger of the sources' (position x{common.position:.2f}, rotation "
                                 f"x{common.rotation:.2f}): {common.words}")
