"""The fuse stage's configuration: section [fuse], each key with its unit and
meaning (``speedplus keys fuse``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from core.config.params import ConfigError, param

if TYPE_CHECKING:
    from core.config.model import Config


@dataclass(frozen=True)
class FuseConfig:
    """The fuse stage: motion-capture rejection and Bayesian fusion."""

    rejection_k: float = param(1.96, "motion capture is rejected beyond this many sigmas in any component "
                                     "(the paper: 1.96, a 95% interval)", "1")
    sigma_scale: Literal["dataset", "calibration"] = param(
        "dataset", "dataset: scale the calibrated sigmas by how much the two sources disagree on the dataset "
        "captures themselves (robust a posteriori variance factor; the dataset's poses are farther and more "
        "varied than the calibration's); calibration: use the calibrated sigmas as they are (the paper)", "")
    min_scale_samples: int = param(
        10, "two-source dataset captures needed to estimate the variance factor robustly and test the sources' "
        "consistency; fewer: each source's sigma widened to its calibration's cross-validated error with a "
        "Student-t allowance, and the factor from the few captures with a weak prior", "count")
    inconsistent_axes: Literal["fall_back", "fuse"] = param(
        "fall_back", "on a position axis where the two sources disagree on the dataset captures beyond their "
        "sigmas (the variance factor fails a 95% test), fall_back: keep only the better source there: the one "
        "whose error its own measurements at the captures predict the smaller (the robots' arms at each "
        "configuration, motion capture's marker fit at each capture); fuse: fuse it anyway, both sigmas scaled", "")
    session_offset: Literal["on", "off"] = param(
        "on", "on: before fusing, remove from the source whose sigma on an axis is larger the median by which it "
        "differs there from the other over the session's two-source captures: at the dataset's range each "
        "source errs mostly by one offset its calibration at close range could not see (rail and wand scale, "
        "extrapolated offsets), and fusing that would let the larger one's pull the better; only the "
        "capture-to-capture errors are then fused, and the variance factor is measured on them "
        "(docs/architecture.md section 6); off: fuse as measured (the paper)", "")
    sigma_doubt: float = param(
        2.0, "on a position axis kept from one source (fuse.inconsistent_axes = fall_back), how far either "
        "source's calibrated sigma may be off at the dataset's range: the log of a source's true over calibrated "
        "sigma is normal a priori, of standard deviation ln(sigma_doubt), with the calibrated variance as its "
        "prior mean; the session's excess over both sigmas is split between the sources by how likely each "
        "share puts them off, and the kept source's sigma is scaled by its own share, not by the common factor "
        "(stages/fuse/kept_axes.py)", "1")
    vicon_scale_sigma: float = param(
        3e-4, "motion capture: 1-sigma scale error of its wand calibration (Vicon: 0.15 mm on the 500 mm wand, "
        "sub-mm volume accuracy; Merriaux et al., Sensors 17(7) 1591, 2017). The calibration absorbs it at its "
        "own distance; beyond it the error grows along the line of sight: 1 mm at 4 m. 0: none", "1")
    lost_motion_rad: tuple[float, float, float, float, float, float] = param(
        (2.9e-4, 2.9e-4, 2.9e-4, 5.8e-4, 5.8e-4, 5.8e-4),
        "the arms' gearbox lost motion (backlash plus hysteresis) of A1-A6, as the data sheet rates it, a "
        "maximum (RV reducers of the main axes: 1 arcmin; wrist: about 2 arcmin), for the joints whose flank the "
        "calibration did not model: a joint below calibrate.backlash_preload_nm whose last move is unknown (the "
        "session's first capture, captures without times) or whose lost motion was not fitted "
        "(calibrate.arm_prior_lost_motion_rad = 0). With a unit's lost motion uniform on 50-100% of the rating, "
        "it adds 7/12 (rating / 2)^2 to its angle's variance, propagated to the robots' pose at each dataset "
        "capture (with calibrated arms); 0: none", "rad")

    def check(self, config: Config) -> None:
        """Lost motion and scale sigma of at least 0; a sigma doubt in (1, 5]."""
        if min(*self.lost_motion_rad, self.vicon_scale_sigma) < 0:
            raise ConfigError("fuse.lost_motion_rad/vicon_scale_sigma: expected values of at least 0")
        if not 1.0 < self.sigma_doubt <= 5.0:
            raise ConfigError(f"fuse.sigma_doubt: expected a factor above 1 and at most 5, got {self.sigma_doubt}")


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"fuse": FuseConfig}
