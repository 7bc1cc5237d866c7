"""The calibrate stage's configuration: section [calibrate], each key with its unit and
meaning (``speedplus keys calibrate``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from core.config.params import ConfigError, at_least, param

if TYPE_CHECKING:
    from core.config.model import Config


@dataclass(frozen=True)
class CalibrateConfig:
    """The calibrate stage: pattern detection, intrinsics, PnP and RWHE per source."""

    intrinsics: Literal["auto", "fixed", "estimate"] = param(
        "auto", "fixed (the session's camera), estimate (cv2.calibrateCamera), or auto: "
        "fixed when the session knows the camera", "")
    min_corners: int = param(6, "pattern corners an image needs to be used", "count")
    solver: Literal["shah", "frobenius", "reprojection"] = param(
        "frobenius", "shah (closed form), frobenius (Shah, then the paper's LM; the most accurate "
        "against the virtual truth, see docs/accuracy.md), or reprojection (then also the "
        "pattern's reprojection error)", "")
    folds: int = param(5, "k of the k-fold cross-validation", "count")
    seed: int = param(0, "random assignment of samples to folds", "")
    min_samples: int = param(8, "usable calibration samples a source needs", "count")
    outlier_k: float = param(5.0, "a sample whose residual exceeds median + k robust sigmas is excluded", "1")
    min_rotation_spread_rad: float = param(
        math.radians(2.0), "least spread of the measured rotations about a second axis", "rad")
    fixture_compliance: Literal["auto", "on", "off"] = param(
        "auto", "estimate the model fixture's tilt under the model's weight with the robots' offsets: on, off, "
        "or auto (on when the target flange's attitude to gravity varies by calibrate.min_gravity_spread_rad)", "")
    min_gravity_spread_rad: float = param(
        math.radians(5.0), "least spread of the up direction in the target flange frame over the calibration "
        "captures for the fixture compliance to be estimated", "rad")
    world_up: tuple[float, float, float] = param(
        (0.0, 0.0, 1.0), "the up direction (against gravity) in the robot world K", "1")
    arm_kinematics: Literal["auto", "on", "off"] = param(
        "auto", "calibrate the arms themselves from their URDFs (joint zero offsets and frames, bases, rail scale, "
        "compliance) with the offsets: on, off, or auto (on when every calibration capture has the robots' encoder "
        "readings, and on a facility folder calibrate.min_arm_redundancy holds)", "")
    arm_prior_joint_rad: float = param(2e-3, "prior 1-sigma of a joint's zero offset (mastering tolerance)", "rad")
    arm_prior_length_m: float = param(2e-3, "prior 1-sigma of an arm dimension against the data sheet", "m")
    min_arm_redundancy: float = param(
        3.0, "under arm_kinematics = auto, a facility folder's robots (not TRON's own) are fitted only where the "
        "calibration captures give this many equations (six a capture) per fitted parameter; fewer and the fit "
        "follows the poses' noise (stages/calibrate/arm_models.py)", "1")
    arm_prior_frame_rad: float = param(
        2e-4, "prior 1-sigma of a joint frame's misalignment against a facility robot's URDF (machining and "
        "assembly: a tenth of the mastering tolerance; stages/common/robots/errors.py)", "rad")
    arm_prior_base_m: float = param(2e-3, "prior 1-sigma of a robot base's surveyed position", "m")
    arm_prior_base_rad: float = param(2e-3, "prior 1-sigma of a robot base's surveyed orientation", "rad")
    arm_prior_rail_scale: float = param(
        1e-4, "prior 1-sigma of the rail encoder's scale error: a rack's cumulative pitch error is tens of um per "
        "metre, and steel expands 1.2e-5 per K; the calibration's 1.2 m of rail travel barely constrains it, so at "
        "the dataset's 3-5 m this prior is most of the robots' depth sigma (docs/architecture.md section 6)", "1")
    joint_compliance: Literal["on", "off"] = param(
        "on", "with the arms' kinematics, also estimate each joint's gearbox compliance under gravity "
        "(stages/common/robots/errors.py)", "")
    fixture_anisotropy: Literal["on", "off"] = param(
        "on", "with the arms' kinematics and a compliant fixture, also estimate how much stiffer the fixture is "
        "about one axis than another (stages/common/rwhe.py fixture_tilt)", "")
    fixture_anisotropy_prior: float = param(
        0.5, "prior 1-sigma of each entry of a compliant fixture's anisotropy D_f (with the arms' kinematics): "
        "a bracket can be half again as stiff about one axis as about another", "1")
    link_mass_uncertainty: float = param(
        0.25, "relative 1-sigma of the URDF's link masses (a data sheet's or a CAD model's): under "
        "calibrate.lost_motion = auto a joint's lost motion is held where fewer than 8 calibration captures rest on "
        "the flank their last move chose beyond twice the torque error those masses allow (stages/common/robots/"
        "lost_motion.py loaded_flanks)", "1")
    fixture_play: Literal["auto", "on", "off"] = param(
        "auto", "with the arms' kinematics and a compliant fixture, also fit the fixture's play: micro-slip in its "
        "clamped joints holds its tilt back against the direction the tilt last changed in, which the captures' "
        "order gives (stages/common/rwhe.py fixture_lag). auto where the calibration captures show it (an F test "
        "at 1%, as for the lost motion), on always, off never", "")
    fixture_play_prior_rad: float = param(
        1e-3, "prior 1-sigma of a compliant fixture's play (zero mean): a few percent of a sag of a few tenths of "
        "a degree; bolted joints slip by some 5% of their elastic deflection (Gaul and Lenz, Acta Mechanica 125, "
        "1997)", "rad")
    arm_prior_compliance_rad_per_nm: float = param(
        3e-5, "prior 1-sigma of a joint's compliance (zero mean), and at most what winds the joint by "
        "arm_prior_joint_rad under its largest gravity torque: twice the compliance of an industrial wrist joint "
        "(stiffness of order 1e5-1e6 N m/rad; Dumas et al., Robotics and Computer-Integrated Manufacturing 27(4), "
        "2011; stages/common/robots/identification.py)", "rad/(N m)")
    pose_weights: Literal["pnp", "groups"] = param(
        "pnp", "how the arms' fit weighs each calibration pose's residual: pnp (by its covariance: the PnP "
        "pose's own from its corners plus one variance each for the rotations and translations the arms' model "
        "leaves, stages/common/pose_noise.py) or groups (rotations and translations as two independent groups, "
        "each of one variance: the smoke profile, docs/accuracy.md)", "")
    lost_motion: Literal["auto", "on", "off"] = param(
        "auto", "with the arms' kinematics, also fit each joint's lost motion on the flank its last move chose "
        "(stages/common/robots/errors.py): auto where the calibration captures show it (an F test at 1% of the "
        "fit with it against the fit without; a model with parameters the data do not need carries their noise "
        "to the dataset's poses), on always, off never", "")
    arm_prior_lost_motion_rad: float = param(
        2.9e-4, "prior 1-sigma of a joint's lost motion (gearbox backlash plus hysteresis, zero mean), fitted where "
        "the captures' times give the order of the moves and so the flank each joint rests on "
        "(stages/common/robots/errors.py): RV reducers of main axes are rated 1 arcmin at most, wrist gears "
        "about 2 (Nabtesco RV-N data sheet); at TRON's default profile 1 arcmin fitted better than 2 with lost "
        "motion (0.86 against 0.93 mm on the dataset, bench unmodelled) and without (0.65 against 0.66); 0: not "
        "fitted (fuse then takes fuse.lost_motion_rad as noise)", "rad")
    backlash_preload_nm: float = param(
        15.0, "a joint whose gravity torque (the lab's nominal mass model) exceeds this rests on its loaded flank "
        "whatever its last move. RV reducers' lost motion is specified within +-3% of the rated torque: 15 N m for "
        "a 500 N m main axis", "N m")
    max_intrinsics_rms_px: float = param(
        2.0, "an estimated camera whose reprojection RMS over the kept images exceeds this is refused: corners of "
        "one printed pattern fit a real camera to 0.1-0.5 px (Tabb's DS1 and Ali's KUKA set: see "
        "docs/accuracy.md)", "px")
    motion_angle_floor_rad: float = param(
        math.radians(1.0), "an image is rejected when its camera motions' rotation angles differ from the robot's "
        "by more than this and by more than median + outlier_k robust sigmas (median over its pairs; a flipped "
        "corner order is off by tens of degrees, a good image by a few hundredths)", "rad")
    motion_pitch_floor_m: float = param(
        0.01, "the same for the pitch (translation along the screw axis) of the motions; good real data: 1-2 mm",
        "m")
    max_scale_error: float = param(
        0.03, "the camera's motions may differ from the robot's by at most this relative scale, beyond twice the "
        "scale's standard error (a wrong square size or length unit scales them all; a robot's own scale error is "
        "about 1e-4, and arms that err by millimetres blur the ratio of centimetre pitches)", "1")
    max_rotation_error_rad: float = param(
        math.radians(5.0), "a calibration whose cross-validated E_R exceeds this is refused as absurd: robots and "
        "PnP err by tenths of a degree; 5 deg means the data do not fit the model", "rad")
    max_reprojection_fraction: float = param(
        0.02, "a calibration whose cross-validated E_p exceeds this fraction of the image diagonal is refused as "
        "absurd (about 45 px at 1920 x 1200; real calibrations: 1-5 px)", "1")

    def check(self, config: Config) -> None:
        """At least two folds, positive prior sigmas, a unit up vector."""
        at_least("calibrate", self, {"folds": 2})
        if self.min_arm_redundancy < 1:
            raise ConfigError("calibrate.min_arm_redundancy: expected at least 1 equation per parameter")
        if min(self.arm_prior_joint_rad, self.arm_prior_length_m, self.arm_prior_frame_rad, self.arm_prior_base_m,
               self.arm_prior_base_rad, self.arm_prior_rail_scale, self.arm_prior_compliance_rad_per_nm) <= 0:
            raise ConfigError("calibrate.arm_prior_*: expected positive sigmas")
        if not (self.arm_prior_lost_motion_rad >= 0 and 0 <= self.backlash_preload_nm < math.inf):
            raise ConfigError("calibrate.arm_prior_lost_motion_rad/backlash_preload_nm: expected finite values of at "
                              "least 0")
        if not 0 <= self.link_mass_uncertainty < math.inf:
            raise ConfigError("calibrate.link_mass_uncertainty: expected a finite value of at least 0")
        if not 0 < self.fixture_play_prior_rad < math.inf:
            raise ConfigError("calibrate.fixture_play_prior_rad: expected a positive, finite sigma")
        if self.fixture_anisotropy_prior <= 0:
            raise ConfigError("calibrate.fixture_anisotropy_prior: expected a positive sigma")
        if not math.isclose(float(np.linalg.norm(self.world_up)), 1.0, rel_tol=1e-6):
            raise ConfigError(f"calibrate.world_up: expected a unit vector, got {self.world_up}")


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"calibrate": CalibrateConfig}
