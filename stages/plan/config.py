"""The plan stage's configuration: sections [plan], [trajectory], each key with its unit and
meaning (``speedplus keys plan trajectory``), and the rules types cannot express
(``check``). ``SECTIONS``: what ``pipeline/config.py`` gathers (docs/architecture.md section 2)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, Literal

import numpy as np

from core.config.params import ConfigError, at_least, param
from manifests.schema import DOMAINS, MOUNTS

if TYPE_CHECKING:
    from core.config.model import Config

PlanMode = Literal["poses", "trajectory"]
TrajectoryPreset = Literal["vbar_hold_spin", "approach_tumble", "custom"]
TRAJECTORY_PRESETS: tuple[TrajectoryPreset, ...] = ("vbar_hold_spin", "approach_tumble", "custom")


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
    calibration_cover: float = param(
        0.25, "share of TRON's calibration poses taken with the target arm held at a dataset pose's configuration "
        "and mount, the camera brought to the board: calibration poses that load the arm as the dataset does, so "
        "calibrate's compliances are fitted where the labels need them, not extrapolated (stages/plan/covering.py); "
        "poses mode only; 0: none (the smoke profile: 16 poses cannot spare them)", "1")
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
    max_redraws: int = param(
        200, "unreachable relative poses redrawn per sample before giving up; on a facility folder with a static "
        "mount, the dataset's poses may take more: as many as the share of poses it presents (measured before "
        "planning) needs for all of them to be drawn at 99% (stages/plan/facility_plan.py dataset_redraws)", "count")
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
        if not 0 <= self.calibration_cover <= 1:
            raise ConfigError(f"plan.calibration_cover: expected a share in [0, 1], got {self.calibration_cover}")
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


#: this stage's sections: name -> dataclass
SECTIONS: dict[str, type] = {"plan": PlanConfig, "trajectory": TrajectoryConfig}
