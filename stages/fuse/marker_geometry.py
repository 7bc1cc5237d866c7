"""Motion capture's sigma at each capture from what its markers could measure there
(docs/architecture.md section 6; the fit's covariance: ``stages.common.marker_fit``).

The calibrated sigma of motion capture was measured at the calibration's captures, with
the markers the system saw there. At a dataset capture it may see three markers in a row
on one side of a bus whose panels reach half a metre further: its rigid-body fit, and the
pose it gives of the target's origin, then err by far more than at the calibration. So
each capture's sigma is split in two:

- the fit's own covariance at that capture: the markers it used (``vicon_targetrb_used``),
  their layout on the mock-up (declared or chosen, ``stages.common.markers``), the marker
  noise measured from the session's fit residuals (``marker_sigma``) and the lever from
  them to the target's origin, turned into the camera's axes by the capture's attitude;
- the rest of the calibrated sigma (the camera body's fit, the system's calibration, the
  offsets): the calibrated variance less the fit's mean variance over the calibration
  captures, never below ``REST_FLOOR`` of it, grown to the capture as before.

A recording that does not say which markers each fit used (a replay of an older export)
keeps the calibrated sigma as it is, and fuse says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from manifests import Workspace
from manifests.sidecars import read_markers
from stages.common.fusion import Sigma
from stages.common.marker_fit import fit_covariance, marker_sigma
from stages.common.markers import markers
from stages.common.sources import measured_b
from stages.common.target import Target

if TYPE_CHECKING:
    from stages.fuse.stage import SourceModel

#: the calibrated variance's share kept for what is not the target body's fit, at least
REST_FLOOR = 0.1


@dataclass(frozen=True)
class FitVariance:
    """A capture's target-body fit: position variance (3,) m^2 per camera axis at the
    target's origin, and the rotation's mean squared angle (rad^2)."""

    t_m2: np.ndarray
    r_rad2: float

    def add_to(self, sigma: Sigma) -> Sigma:
        return Sigma(np.sqrt(sigma.t_m**2 + self.t_m2), float(np.sqrt(sigma.r_rad**2 + self.r_rad2)),
                     sigma.pointing_rad)


@dataclass(frozen=True)
class MarkerGeometry:
    """The mock-up's markers (M, 3) in T at mock-up scale and the marker noise (m) the
    session's fits show."""

    markers_m: np.ndarray
    marker_sigma_m: float

    def variance(self, row: dict[str, Any], cam_from_target: np.ndarray) -> FitVariance | None:
        """The fit's variance at this capture (None: the capture does not say which markers
        it used); infinite when it used fewer than three, or three in a line."""
        used = row.get("vicon_targetrb_used")
        if used is None or any(i < 0 or i >= len(self.markers_m) for i in used):
            return None
        fit = fit_covariance(self.markers_m[list(used)], np.zeros(3)).scaled(self.marker_sigma_m)
        rotation = cam_from_target[:3, :3]
        return FitVariance(np.diag(rotation @ fit.point @ rotation.T).copy(), float(np.trace(fit.rotation)))

    def words(self) -> str:
        return f"marker noise {self.marker_sigma_m * 1000:.3f} mm from the fits' residuals"


def marker_geometry(markers_m: np.ndarray, rows: list[dict[str, Any]]) -> MarkerGeometry | None:
    """The geometry of the session's target-body fits, from every capture that says which
    markers it used and its residual; None when none does."""
    recorded = [r for r in rows if r.get("vicon_targetrb_used") is not None
                and r.get("vicon_targetrb_residual_m") is not None]
    if not recorded:
        return None
    sigma = marker_sigma(np.array([r["vicon_targetrb_residual_m"] for r in recorded]),
                         np.array([len(r["vicon_targetrb_used"]) for r in recorded]))
    return None if sigma is None else MarkerGeometry(np.asarray(markers_m, float), sigma)


def without_fit(sigma: Sigma, mean: FitVariance) -> Sigma:
    """``sigma`` (calibrated) less the fit's ``mean`` variance over the calibration
    captures: what of it is not the target body's fit, never below ``REST_FLOOR`` of it.
    The pointing is kept whole (all of the rotation where unknown): the target body's
    rotation error turns the target about itself and moves its origin by the lever, which
    the fit's position variance holds; it does not turn the line of sight."""
    t_m2 = np.maximum(sigma.t_m**2 - mean.t_m2, REST_FLOOR * sigma.t_m**2)
    r_rad2 = max(sigma.r_rad**2 - mean.r_rad2, REST_FLOOR * sigma.r_rad**2)
    pointing = sigma.r_rad if sigma.pointing_rad is None else sigma.pointing_rad
    return Sigma(np.sqrt(t_m2), float(np.sqrt(r_rad2)), float(pointing))


def mean_variance(variances: list[FitVariance | None]) -> FitVariance | None:
    """The mean of the finite fit variances (None when there is none)."""
    finite = [v for v in variances if v is not None and np.all(np.isfinite(v.t_m2)) and np.isfinite(v.r_rad2)]
    if not finite:
        return None
    return FitVariance(np.mean([v.t_m2 for v in finite], axis=0), float(np.mean([v.r_rad2 for v in finite])))


def with_marker_geometry(workspace: Workspace, captured: list[dict[str, Any]], target: Target,
                         kuka: SourceModel, vicon: SourceModel,
                         rejection: Sigma | None) -> tuple[MarkerGeometry | None, str, Sigma | None]:
    """The session's marker geometry (``marker_geometry``), with motion capture's calibrated
    sigma and the rejection sigma reduced by the fit's mean variance over the calibration
    captures (``without_fit``): the fit's own variance is added back capture by capture."""
    # where the markers were when the captures were made (acquire records it), else the target's
    layout = (np.array(read_markers(workspace).centres_m) if workspace.markers_path.exists()
              else markers(target).centres_m)
    geometry = marker_geometry(layout, captured)
    if geometry is None:
        return None, "not recorded (which markers each fit used): the calibrated sigma as it is", rejection
    calibration = []
    for row in captured:
        b = measured_b(row, "vicon")
        if row["session"] == "calibration" and b is not None and row["fixture"] in kuka.offsets.x:
            calibration.append(geometry.variance(row, kuka.estimate(measured_b(row, "kuka"), row)))
    mean = mean_variance(calibration)
    if mean is None:
        return geometry, f"{geometry.words()}; no calibration capture to take its share from the calibrated sigma", \
            rejection
    vicon.sigma = without_fit(vicon.sigma, mean)
    rejection = None if rejection is None else without_fit(rejection, mean)
    return geometry, (f"{geometry.words()}; its mean at the calibration x/y/z "
                      f"{'/'.join(f'{v:.2f}' for v in np.sqrt(mean.t_m2) * 1000)} mm taken from the calibrated "
                      "sigma, each capture's added"), rejection
