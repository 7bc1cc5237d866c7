"""Configuration of the stages, one section each (docs/architecture.md section 2)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import PurePosixPath
from typing import TYPE_CHECKING, Literal, get_args

import numpy as np

from core.config.params import ConfigError, at_least, param
from manifests.schema import DOMAINS, MOUNTS

if TYPE_CHECKING:
    from core.config.model import Config

ExportSet = Literal["testbed", "twins", "train"]
ExportFormat = Literal["speedplus", "bop", "shirt", "robot", "session"]
EXPORT_FORMATS: tuple[str, ...] = get_args(ExportFormat)
PlanMode = Literal["poses", "trajectory"]
TrajectoryPreset = Literal["vbar_hold_spin", "approach_tumble", "custom"]
TRAJECTORY_PRESETS: tuple[TrajectoryPreset, ...] = ("vbar_hold_spin", "approach_tumble", "custom")
#: the reference models: ``plain`` (photometric jitter) and ``augmented`` (the robust recipe of
#: stages/reference/augment.py), named reference and reference_augmented
ReferenceVariant = Literal["plain", "augmented", "detector"]


@dataclass(frozen=True)
class PlanConfig:
    """The plan stage: which relative poses to capture and how the robots realise them."""

    seed: int = param(2021, "random seed of the plan; same seed, same plan", "")
    mode: PlanMode = param(
        "poses", "poses (independent samples, SPEED+) or trajectory (rendezvous sequences following orbital and "
        "attitude dynamics, the [trajectory] section; they replace plan.n_dataset)", "")
    n_calibration: int = param(64, "calibration-session captures (TRON: 64)", "count")
    n_dataset: int = param(48, "dataset-session captures, balanced over view x light", "count")
    calibration_distance_m: tuple[float, float] = param(
        (0.70, 0.80), "camera-to-board-centre distance range (TRON: about 0.75 m)", "m")
    calibration_max_tilt_rad: float = param(
        math.radians(45.0), "largest angle between the boresight and the board normal (TRON: 45 deg)", "rad")
    calibration_aim_jitter_m: float = param(
        0.04, "the camera aims at a point this far (at most) from the board centre, in the board plane", "m")
    calibration_min_corner_fraction: float = param(
        0.5, "share of the board's inner corners that must project inside the image", "1")
    calibration_mounts: tuple[str, ...] = param(
        MOUNTS, "model fixtures calibrated, alternated over calibration captures "
        "(each dataset capture uses the one away from the camera)", "")
    dataset_range_m: tuple[float, ...] = param(
        (), "camera-to-target distance range, FULL scale, [min, max]; empty: SPEED+'s (6.5-9.5 m for Tango, paper: "
        "at least 6.5 m), for another target the same apparent size (4.75-6.94 of its diameters), clipped to what "
        "the room holds; the distance is drawn uniformly where this and plan.dataset_range_diameters both hold", "m")
    dataset_range_diameters: tuple[float, float] = param(
        (0.0, 1e9), "the range in units of the target's diameter (its largest extent; Tango: 1.37 m), which "
        "narrows plan.dataset_range_m; with plan.dataset_range_m empty, it narrows SPEED+'s", "1")
    image_margin_px: float = param(
        10.0, "the target's bounding sphere stays this far inside the image edges", "px")
    lights: tuple[str, ...] = param(DOMAINS, "light set-ups of the dataset session", "")
    n_light_boxes: int = param(10, "Earth-albedo light boxes in the room (TRON: 10)", "count")
    light_boxes_per_sample: tuple[int, int] = param((1, 3), "active light boxes per lightbox capture", "count")
    max_redraws: int = param(200, "unreachable relative poses redrawn per sample before giving up", "count")
    sight_elevations_rad: tuple[float, ...] = param(
        tuple(math.radians(a) for a in (5.0, 15.0, 25.0, 40.0, 55.0)),
        "candidate elevations of the camera above the model (line-of-sight angle below horizontal)", "rad")
    sight_azimuths_rad: tuple[float, ...] = param(
        tuple(math.radians(a) for a in (0.0, -25.0, 25.0)),
        "candidate azimuths of the camera about the rail axis (0: camera further along +x)", "rad")
    rail_offsets_m: tuple[float, ...] = param(
        (-0.9, -0.5, 0.5, 0.9), "candidate x offsets of the camera robot base from its flange", "m")
    wall_clearance_m: float = param(
        0.3, "the camera and both flanges stay this far from the walls, floor and ceiling", "m")
    camera_roll_candidates: int = param(
        12, "camera rolls about the line of sight tried when searching robot configurations", "count")
    joint_limit_margin_rad: float = param(
        math.radians(3.0), "commanded joints keep this distance from the data-sheet limits", "rad")

    def check(self, config: Config) -> None:
        """Ranges of 0 <= min <= max, counts, the lights, mounts and light boxes that exist."""
        if len(self.dataset_range_m) not in (0, 2):
            raise ConfigError(f"plan.dataset_range_m: expected [] (SPEED+'s, in the target's diameters) or "
                              f"[min, max], got {list(self.dataset_range_m)}")
        for key, low, high in (("plan.calibration_distance_m", *self.calibration_distance_m),
                               *((("plan.dataset_range_m", *self.dataset_range_m),) if self.dataset_range_m else ()),
                               ("plan.dataset_range_diameters", *self.dataset_range_diameters)):
            if not 0 <= low <= high or (key == "plan.calibration_distance_m" and low == 0) or high == 0:
                raise ConfigError(f"{key}: expected 0 <= min <= max (max > 0), got ({low}, {high})")
        at_least("plan", self, {"n_calibration": 0, "n_dataset": 0})
        if not set(self.lights) <= set(DOMAINS) or not self.lights:
            raise ConfigError(f"plan.lights: expected a non-empty subset of lightbox, sunlamp, got {self.lights}")
        if not set(self.calibration_mounts) <= set(MOUNTS) or not self.calibration_mounts:
            raise ConfigError(f"plan.calibration_mounts: expected minus_x and/or plus_x, got "
                              f"{self.calibration_mounts}")
        low, high = self.light_boxes_per_sample
        if not 1 <= low <= high <= self.n_light_boxes:
            raise ConfigError(f"plan.light_boxes_per_sample: expected 1 <= min <= max <= {self.n_light_boxes}")
        if not 0 <= self.calibration_max_tilt_rad < math.pi / 2:
            raise ConfigError(f"plan.calibration_max_tilt_rad: expected [0, pi/2), got "
                              f"{self.calibration_max_tilt_rad}")


@dataclass(frozen=True)
class TrajectoryConfig:
    """plan.mode = trajectory: rendezvous sequences of the target (the chief) seen from a
    servicer (the deputy) that carries the camera. Relative motion in D'Amico's
    quasi-nonsingular relative orbital elements (stages/common/orbits.py), torque-free
    attitude (stages/common/attitude.py), the sun from the epoch (stages/common/sun.py)."""

    presets: tuple[TrajectoryPreset, ...] = param(
        TRAJECTORY_PRESETS[:2], "sequences to plan, in order: vbar_hold_spin (an along-track hold at mid range, the "
        "target spinning about its major principal axis), approach_tumble (a slow natural-drift approach from the "
        "far end of the range, the target tumbling about two principal axes), custom (trajectory.roe_m and "
        "trajectory.spin_rad_s); the presets scale with plan.dataset_range_*", "")
    frames: int = param(24, "frames per sequence", "count")
    cam_step_s: float = param(5.0, "time between frames (SHIRT: 5 s)", "s")
    epoch_utc: str = param("2026-03-20T06:00:00Z", "the sequences' epoch, ISO 8601 in UTC", "")
    chief_a_m: float = param(7_078_137.0, "the target's mean semi-major axis (700 km altitude)", "m")
    chief_e: float = param(0.001, "the target's mean eccentricity", "1")
    chief_i_rad: float = param(math.radians(98.19), "the target's inclination (sun-synchronous at 700 km)", "rad")
    chief_raan_rad: float = param(math.radians(20.0), "the target's right ascension of the ascending node", "rad")
    chief_argp_rad: float = param(math.radians(30.0), "the target's argument of perigee", "rad")
    chief_mean_anomaly_rad: float = param(
        math.radians(35.0), "the target's mean anomaly at the epoch (the paper profile's 20 minutes then enter the "
        "Earth's shadow)", "rad")
    roe_m: tuple[float, float, float, float, float, float] = param(
        (0.0, -8.0, 0.0, 0.4, 0.0, 0.4), "custom: the servicer's relative orbital elements times the target's "
        "semi-major axis, a (da, dlambda, dex, dey, dix, diy); dlambda < 0 puts the servicer behind", "m")
    spin_rad_s: tuple[float, float, float] = param(
        (0.0, 0.0, math.radians(1.0)), "custom: the target's initial angular velocity in its body frame T", "rad/s")
    spin_rate_rad_s: float = param(math.radians(1.0), "the presets' spin rate", "rad/s")
    mass_kg: float = param(40.0, "the target's full-scale mass (Tango: about 40 kg); scales its inertia", "kg")
    inertia_kgm2: tuple[float, ...] = param(
        (), "the target's inertia about its centre of mass in T, (Ixx, Iyy, Izz, Ixy, Ixz, Iyz); empty: a uniform "
        "shell over the mesh's surface, of trajectory.mass_kg", "kg m^2")
    pointing_sigma_rad: float = param(
        math.radians(0.3), "the camera's pointing error at the target's centre of mass, per axis, one draw per "
        "sequence", "rad")
    jitter_sigma_rad: float = param(math.radians(0.02), "the camera's pointing jitter, per axis and frame", "rad")
    max_replans: int = param(
        5, "a sequence with a frame the room cannot hold is planned again from another initial attitude this many "
        "times before it is refused (the plan's redraws column counts them)", "count")
    sunlamp_tolerance_rad: float = param(
        math.radians(30.0), "a sunlit frame is taken under the sun lamp when the lamp's direction at the model is "
        "this close to the true sun's, else under the light boxes on the Earth's side", "rad")

    def check(self, config: Config) -> None:
        """Where plan.mode = trajectory: an orbit above the Earth, a time scale, an inertia
        that a body can have (the message names the key)."""
        if config.plan.mode != "trajectory":
            return
        t = self
        if not t.presets or len(set(t.presets)) != len(t.presets):
            raise ConfigError(f"trajectory.presets: expected distinct presets, got {list(t.presets)}")
        at_least("trajectory", t, {"max_replans": 0, "frames": 1})
        if not t.cam_step_s > 0:
            raise ConfigError(f"trajectory.cam_step_s: expected a positive step (s), got {t.cam_step_s}")
        try:
            epoch = datetime.fromisoformat(t.epoch_utc.replace("Z", "+00:00"))
        except ValueError:
            epoch = None
        if epoch is None or epoch.tzinfo is None:
            raise ConfigError(f"trajectory.epoch_utc: {t.epoch_utc!r} is not an ISO 8601 time in UTC, "
                              "e.g. 2026-03-20T06:00:00Z")
        if not 0 <= t.chief_e < 1:
            raise ConfigError(f"trajectory.chief_e: expected an eccentricity in [0, 1), got {t.chief_e}")
        if t.chief_a_m * (1 - t.chief_e) <= 6_478_137.0:
            raise ConfigError(f"trajectory.chief_a_m: a perigee {t.chief_a_m * (1 - t.chief_e) / 1e3:.0f} km from the "
                              "Earth's centre is below 100 km altitude (the value is in metres)")
        if abs(math.sin(t.chief_i_rad)) < 1e-3:
            raise ConfigError("trajectory.chief_i_rad: an equatorial orbit has no node; the relative elements dix, diy "
                              "need an inclination away from 0 and pi")
        if t.mass_kg <= 0 or min(t.pointing_sigma_rad, t.jitter_sigma_rad) < 0:
            raise ConfigError("trajectory.mass_kg: positive; trajectory.pointing_sigma_rad/jitter_sigma_rad: at "
                              "least 0")
        if not 0 <= t.sunlamp_tolerance_rad <= math.pi:
            raise ConfigError(f"trajectory.sunlamp_tolerance_rad: expected an angle in [0, pi], got "
                              f"{t.sunlamp_tolerance_rad}")
        if t.inertia_kgm2:
            if len(t.inertia_kgm2) != 6:
                raise ConfigError("trajectory.inertia_kgm2: expected (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) or empty")
            ixx, iyy, izz, ixy, ixz, iyz = t.inertia_kgm2
            moments = np.linalg.eigvalsh(np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], float))
            if moments[0] <= 0 or moments[2] > moments[0] + moments[1] * (1 + 1e-9):
                raise ConfigError(f"trajectory.inertia_kgm2: principal moments {moments.round(6).tolist()} kg m^2 are "
                                  "not a rigid body's (all positive, the largest at most the sum of the others)")


@dataclass(frozen=True)
class AcquireConfig:
    """The acquire stage: which testbed backend produces the captures."""

    backend: Literal["virtual", "replay"] = param(
        "virtual", "virtual (embedded digital twin) or replay (recorded session on disk)", "")
    format: Literal["session", "handeye", "tabb"] = param(
        "session", "replay format: session (a TRON-like logger's folder), handeye (images and a "
        "pose file described by dataset.toml) or tabb (Tabb's robot-world/hand-eye folders, a "
        "preset of handeye); see docs/user-guide.md", "")
    source: str = param("", "replay: the recorded session directory", "")

    def check(self, config: Config) -> None:
        """A replay names its recording."""
        if self.backend == "replay" and not self.source:
            raise ConfigError("acquire.source: the replay backend needs the recorded session directory")


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
        "auto", "calibrate the arms themselves (joint offsets, link lengths, bases, rail scale) with the offsets: "
        "on, off, or auto (on when every calibration capture has the robots' encoder readings)", "")
    arm_prior_joint_rad: float = param(2e-3, "prior 1-sigma of a joint's zero offset (mastering tolerance)", "rad")
    arm_prior_length_m: float = param(2e-3, "prior 1-sigma of an arm dimension against the data sheet", "m")
    arm_prior_base_m: float = param(2e-3, "prior 1-sigma of a robot base's surveyed position", "m")
    arm_prior_base_rad: float = param(2e-3, "prior 1-sigma of a robot base's surveyed orientation", "rad")
    arm_prior_rail_scale: float = param(
        1e-4, "prior 1-sigma of the rail encoder's scale error: a rack's cumulative pitch error is tens of um per "
        "metre, and steel expands 1.2e-5 per K; the calibration's 1.2 m of rail travel barely constrains it, so at "
        "the dataset's 3-5 m this prior is most of the robots' depth sigma (docs/architecture.md section 6)", "1")
    joint_compliance: Literal["on", "off"] = param(
        "on", "with the arms' kinematics, also estimate the gearbox compliance of A2, A3 and A5 under gravity "
        "(stages/common/arms.py)", "")
    fixture_anisotropy: Literal["on", "off"] = param(
        "on", "with the arms' kinematics and a compliant fixture, also estimate how much stiffer the fixture is "
        "about one axis than another (stages/common/rwhe.py fixture_tilt)", "")
    fixture_anisotropy_prior: float = param(
        0.5, "prior 1-sigma of each entry of a compliant fixture's anisotropy D_f (with the arms' kinematics): "
        "a bracket can be half again as stiff about one axis as about another", "1")
    arm_prior_compliance_rad_per_nm: tuple[float, float, float] = param(
        (4e-6, 8e-6, 3e-5), "prior 1-sigma of the joint compliance of A2, A3 and A5 (zero mean): twice the "
        "compliance of KR-class joints (stiffness of order 1e5-1e6 N m/rad; Dumas et al., Robotics and "
        "Computer-Integrated Manufacturing 27(4), 2011)", "rad/(N m)")
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
        if min(self.arm_prior_joint_rad, self.arm_prior_length_m, self.arm_prior_base_m, self.arm_prior_base_rad,
               self.arm_prior_rail_scale, *self.arm_prior_compliance_rad_per_nm) <= 0:
            raise ConfigError("calibrate.arm_prior_*: expected positive sigmas")
        if self.fixture_anisotropy_prior <= 0:
            raise ConfigError("calibrate.fixture_anisotropy_prior: expected a positive sigma")
        if not math.isclose(float(np.linalg.norm(self.world_up)), 1.0, rel_tol=1e-6):
            raise ConfigError(f"calibrate.world_up: expected a unit vector, got {self.world_up}")


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
    vicon_scale_sigma: float = param(
        3e-4, "motion capture: 1-sigma scale error of its wand calibration (Vicon: 0.15 mm on the 500 mm wand, "
        "sub-mm volume accuracy; Merriaux et al., Sensors 17(7) 1591, 2017). The calibration absorbs it at its "
        "own distance; beyond it the error grows along the line of sight: 1 mm at 4 m. 0: none", "1")
    lost_motion_rad: tuple[float, float, float, float, float, float] = param(
        (2.9e-4, 2.9e-4, 2.9e-4, 5.8e-4, 5.8e-4, 5.8e-4),
        "the arms' gearbox lost motion (backlash plus hysteresis) of A1-A6, as the data sheet rates it, a "
        "maximum (RV reducers of the main axes: 1 arcmin; wrist: about 2 arcmin). A joint below "
        "fuse.backlash_preload_nm rests on the flank its last move left it on, which no calibration models: "
        "with a unit's lost motion uniform on 50-100% of the rating, it adds 7/12 (rating / 2)^2 to its angle's "
        "variance, propagated to the robots' pose at each dataset capture (with calibrated arms); 0: none", "rad")
    backlash_preload_nm: float = param(
        15.0, "a joint whose gravity torque (the lab's nominal mass model) exceeds this rests on its loaded flank "
        "whatever its last move, and gains no lost-motion variance. RV reducers' lost motion is specified "
        "within +-3% of the rated torque: 15 N m for a 500 N m main axis", "N m")

    def check(self, config: Config) -> None:
        """Lost motion, preload and scale sigma of at least 0."""
        if min(*self.lost_motion_rad, self.backlash_preload_nm, self.vicon_scale_sigma) < 0:
            raise ConfigError("fuse.lost_motion_rad/backlash_preload_nm/vicon_scale_sigma: expected values of at "
                              "least 0")


@dataclass(frozen=True)
class LabelConfig:
    """The label stage: SPEED+ labels of the dataset captures."""

    filename_template: str = param("{sample_id}.png", "image file name of a label in exports", "")

    def check(self, config: Config) -> None:
        """A file name template of {sample_id} that stays inside the export folder."""
        template = self.filename_template
        try:
            example = PurePosixPath(template.format(sample_id="img000000"))
        except (KeyError, IndexError, ValueError) as error:
            raise ConfigError(f"label.filename_template: {template!r} is not a template of {{sample_id}} "
                              f"({error})") from None
        if example.is_absolute() or ".." in example.parts or "\\" in template or "{sample_id}" not in template:
            raise ConfigError(f"label.filename_template: {template!r} must name a file inside the export folder "
                              "and contain {sample_id}")


@dataclass(frozen=True)
class RenderConfig:
    """The render stage: Mitsuba 3 synthetic twins of the labels, and the training set."""

    #: which set the stage makes now; each set's fingerprint holds the keys that shape it (``applies``)
    set: Literal["twin", "train"] = param(
        "twin", "what to render: twin (one per label) or train (the synthetic training set)", "")
    seed: int = param(7, "random seed of the training poses, lights and of every image's Monte-Carlo noise", "")
    spp: int = param(64, "twins: samples per pixel", "count", applies=("twin",))
    max_depth: int = param(4, "path length of the path tracer (3: direct light and one bounce)", "count")
    irradiance: float = param(
        3.0, "irradiance of the directional light on the model; the synthetic images' exposure is fixed, "
        "so 3.0 puts a sunlit white radiator near saturation", "W/m^2", applies=("twin",))
    train_count: int = param(
        1000, "images of the training set (render --set train --count N)", "count", applies=("train",))
    train_distance_m: tuple[float, ...] = param(
        (), "camera-to-target distance of training images, full scale, [min, max]; empty: SPEED+ synthetic's "
        "(3-10 m for Tango), for another target the same apparent size (2.19-7.3 of its diameters); drawn "
        "uniformly where this and render.train_distance_diameters both hold", "m", applies=("train",))
    train_distance_diameters: tuple[float, float] = param(
        (0.0, 1e9), "the same range in units of the target's diameter (Tango: 1.37 m), which narrows "
        "render.train_distance_m", "1", applies=("train",))
    train_irradiance: tuple[float, float] = param(
        (1.0, 6.0), "training images: range of the light's irradiance (log-uniform)", "W/m^2",
        applies=("train",))
    train_earth_fraction: float = param(
        0.5, "share of training images with the Earth behind the target", "1", applies=("train",))
    train_resolution_scale: float = param(
        1.0, "training images: camera resolution times this (intrinsics scaled with it)", "1",
        applies=("train",))
    margin_px: float = param(
        10.0, "training images: the target's bounding sphere stays this far inside the image when it fits", "px",
        applies=("train",))
    train_spp: int = param(16, "training images: samples per pixel", "count", applies=("train",))
    ground_truth: bool = param(
        True, "write each image's per-pixel ground truth (depth, normals, body coordinates, part index, linear "
        "radiance) as one EXR beside it (stages/common/ground_truth.py); off: PNG and mask only", "")

    def check(self, config: Config) -> None:
        """Renderer counts, the training set's ranges, irradiance, Earth share and scale."""
        at_least("render", self, {"spp": 1, "train_spp": 1, "max_depth": 1, "train_count": 0})
        if len(self.train_distance_m) not in (0, 2):
            raise ConfigError(f"render.train_distance_m: expected [] (SPEED+'s, in the target's diameters) or "
                              f"[min, max], got {list(self.train_distance_m)}")
        ranges = [("render.train_distance_m", self.train_distance_m)] if self.train_distance_m else []
        for key, (low, high) in [*ranges, ("render.train_distance_diameters", self.train_distance_diameters)]:
            if not 0 <= low <= high or high == 0:
                raise ConfigError(f"{key}: expected 0 <= min <= max (max > 0), got {(low, high)}")
        if not 0 < self.train_irradiance[0] <= self.train_irradiance[1]:
            raise ConfigError(f"render.train_irradiance: expected 0 < min <= max, got {self.train_irradiance}")
        if not 0 <= self.train_earth_fraction <= 1:
            raise ConfigError(f"render.train_earth_fraction: expected [0, 1], got {self.train_earth_fraction}")
        if not 0 < self.train_resolution_scale <= 4:
            raise ConfigError(f"render.train_resolution_scale: expected (0, 4], got {self.train_resolution_scale}")


@dataclass(frozen=True)
class ReferenceConfig:
    """speedplus train-reference: the recipe of the reference keypoint CNN (torch)."""

    images: int = param(3000, "training-set images rendered for it (90% train, 10% held out)", "count")
    resolution_scale: float = param(1.0, "training images: camera resolution times this", "1")
    input_width: int = param(192, "network input width (the crop around the target is resized to it)", "px")
    input_height: int = param(192, "network input height", "px")
    width: int = param(16, "channels of the network's first layer (the others are multiples)", "count")
    epochs: int = param(45, "passes over the training images", "count")
    batch_size: int = param(32, "images per optimiser step", "count")
    learning_rate: float = param(2e-3, "Adam's initial learning rate (cosine decay to 2% of it)", "1")
    heatmap_sigma: float = param(1.0, "standard deviation of the target Gaussians, in heatmap pixels", "px")
    heatmap_stride: Literal[2, 4] = param(4, "input pixels per heatmap pixel (2: heatmaps of half the input's "
                                          "resolution, 4: a quarter)", "px")
    wide_crops: float = param(0.0, "share of training crops taken wide (the box 1.2 to 6 times larger, shifted): "
                              "the model also finds a small target, as the self crop's first pass needs", "1")
    rotation: bool = param(True, "rotate every training crop by a random angle in the image plane (with a random "
                           "scale of 1 +- 0.15 and shift of +- 6%); off: scale and shift only", "")
    variants: tuple[ReferenceVariant, ...] = param(
        ("plain", "augmented", "detector"), "models to train: plain (photometric jitter: models/reference.onnx), "
        "augmented (style, texture, Earth backgrounds, glare, blur, noise: models/reference_augmented.onnx), "
        "detector (the target's pixels in the whole image, the start of the self crop: models/detector.onnx)", "")
    detector_input_width: int = param(
        192, "detector: the whole image is resized to this width (the height keeps the camera's aspect, in "
        "multiples of 16); the keypoint passes after it refine its box", "px")
    detector_epochs: int = param(15, "detector: passes over the training images", "count")
    seed: int = param(0, "seed of initialisation, shuffling and augmentation", "")
    threads: int = param(2, "torch threads", "count")
    max_steps: int = param(0, "stop after this many optimiser steps (a quick check of the recipe); 0: the "
                           "whole recipe", "count")

    def check(self, config: Config) -> None:
        """Nothing beyond the types."""


@dataclass(frozen=True)
class EvaluateConfig:
    """The evaluate stage: an ONNX model scored on twins and testbed images."""

    models: tuple[str, ...] = param(
        (), "ONNX models following the contract of stages/common/model_contract.py, each scored on every image; "
        "relative paths: from the current directory, else from the repository. Empty: the models train-reference "
        "made in this workspace (W/models/*.onnx), else, for the built-in Tango, the shipped reference models "
        "(models/reference.onnx, models/reference_augmented.onnx)", "")
    self_crop: bool = param(True, "a model of oracle_box crops is also scored on its own crop: the detector's box "
                            "(evaluate.detector) or its own search over windows, then two keypoint passes, each "
                            "around what the previous one found", "")
    detector: str = param(
        "auto", "what starts the self crop: auto (the detector train-reference made in this workspace, "
        "W/models/detector.onnx, else, for the built-in Tango, the shipped models/detector.onnx, else the search), "
        "an ONNX detector (the contract of stages/common/detector.py; relative paths as evaluate.models), or search "
        "(the keypoint model's own search over windows of the image)", "")
    batch_size: int = param(16, "images per inference call", "count")
    threads: int = param(0, "ONNX Runtime intra-op threads of each worker; 0: the worker's share of the cores (CPUs "
                         "/ run.workers; on Ray, the CPUs reserved for it). The scores do not depend on it", "count")
    ransac_fraction: float = param(
        0.01, "RANSAC inlier threshold of keypoint PnP, as a fraction of the image width", "1")
    turns: bool = param(True, "a model whose metadata asks for it (speedplus.turns=4) sees each crop at four "
                        "quarter turns and its heatmaps, turned back, are averaged; off: one pass", "")
    ransac_seed: int = param(0, "seed of the RANSAC draws that turn heatmaps into poses: the scores of another seed "
                             "show how much of a difference between models or runs is the draw's", "")
    ransac_seeds: int = param(4, "each image's final pass is decoded under this many RANSAC seeds (ransac_seed, "
                              "ransac_seed + 1, ...): a prediction's pose is the first's; Table 2's means average "
                              "them and its intervals draw among them, so that they hold the decoder's spread", "count")
    tracking_rotation_sigma_rad: float = param(
        math.radians(3.0), "plan.mode = trajectory, the tracking filter: a per-frame rotation's error, per axis", "rad")
    tracking_lateral_sigma: float = param(
        0.005, "the tracking filter: a per-frame position's error across the boresight, times the range", "1")
    tracking_depth_sigma: float = param(
        0.03, "the tracking filter: a per-frame position's error along the boresight, times the range", "1")
    tracking_angular_acceleration_sigma: float = param(
        3e-4, "the tracking filter's process noise on the body rate (a tumbling body's rate turns in its frame)",
        "rad/s^2")
    tracking_roe_walk: float = param(
        1e-3, "the tracking filter's random walk of the relative orbital elements (times a)", "m/s^0.5")
    tracking_gate_probability: float = param(
        0.999, "a measurement whose innovation is less likely than this under the filter's covariance is not used",
        "1")

    def check(self, config: Config) -> None:
        """Positive tracking sigmas, a gate probability, counts of at least one."""
        if min(self.tracking_rotation_sigma_rad, self.tracking_lateral_sigma, self.tracking_depth_sigma) <= 0 \
                or min(self.tracking_angular_acceleration_sigma, self.tracking_roe_walk) < 0:
            raise ConfigError("evaluate.tracking_*: the measurement sigmas must be positive, the process noises at "
                              "least 0")
        if not 0 < self.tracking_gate_probability < 1:
            raise ConfigError(f"evaluate.tracking_gate_probability: expected a probability in (0, 1), got "
                              f"{self.tracking_gate_probability}")
        at_least("evaluate", self, {"threads": 0, "batch_size": 1, "ransac_seed": 0, "ransac_seeds": 1})


@dataclass(frozen=True)
class ExportConfig:
    """speedplus export: the labels and testbed images in a layout other tools read."""

    format: ExportFormat = param(
        "speedplus", "speedplus (the layout the Stanford SPEED+ devkits read), bop (bop_toolkit's scenes; a "
        "trajectory plan's sequences are its scenes), shirt (SHIRT's sequences, plan.mode = trajectory) or robot "
        "(the plan as each robot's waypoints and controller program: KUKA KRL, URScript) or session (the captures "
        "in the layout of a lab's logger, which replay reads back)", "")
    out: str = param("", "export folder; empty: W/export/<format>", "")
    sets: tuple[ExportSet, ...] = param(
        ("testbed", "twins"), "image sets exported: testbed (the labelled captures), twins (their synthetic twins, "
        "from render) and train (the synthetic training set, from render --set train)", "")
    validation_fraction: float = param(
        0.2, "share of the training set in SPEED+'s synthetic/validation.json (SPEED+: 0.2), chosen by a hash of "
        "each sample_id: the same image stays on its side whatever else is rendered", "1")

    def check(self, config: Config) -> None:
        """A validation share, distinct sets, and SHIRT only of sequences and their test images."""
        if not 0.0 <= self.validation_fraction <= 1.0:
            raise ConfigError(f"export.validation_fraction: expected a share in [0, 1], got "
                              f"{self.validation_fraction}")
        if self.format == "shirt" and config.plan.mode != "trajectory":
            raise ConfigError(f"export.format: shirt exports rendezvous sequences, and plan.mode is "
                              f"{config.plan.mode!r} (independent poses): export them with speedplus or bop, or plan "
                              "sequences (plan.mode = \"trajectory\")")
        if self.format == "shirt" and "train" in self.sets:
            raise ConfigError(f"export.sets: {list(self.sets)}: shirt exports the sequences' testbed images and "
                              "twins, not the training set; drop train, or export it with speedplus or bop")
        if not self.sets or len(set(self.sets)) != len(self.sets):
            raise ConfigError(f"export.sets: expected distinct sets among testbed, twins, train, got {self.sets}")
