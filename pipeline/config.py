"""Typed configuration: one frozen dataclass per section, every field documented with its unit.

Resolution order: dataclass defaults, then the profile shipped in ``pipeline/profiles``
(``smoke``, ``default``, ``paper``), then ``--config FILE``, then ``--set section.key=value``.
The resolved configuration is written to ``W/config.toml``. Units follow docs/architecture.md section 3:
metres and radians (field names end in ``_m``, ``_rad``, ``_px``; quaternions ``_q`` are
Hamilton ``(w, x, y, z)``).
"""

from __future__ import annotations

import difflib
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
import tomli_w

from manifests.schema import DOMAINS, MOUNTS
from pipeline.errors import InputError

PROFILES = ("smoke", "default", "paper")


class ConfigError(InputError):
    """Bad configuration; the message names the key (and the file) at fault."""


def param(default: Any, help: str, unit: str = "") -> Any:  # noqa: A002 - "help" reads best at call sites
    """A documented field: ``help`` becomes CLI/TOML documentation, ``unit`` is shown with it."""
    return field(default=default, metadata={"help": help, "unit": unit})


def resize_camera_matrix(camera_matrix: np.ndarray, scale_x: float, scale_y: float) -> np.ndarray:
    """K (3, 3) of an image resized by ``scale_x``, ``scale_y``. With pixel centres at integer
    coordinates a resize by s maps x to (x + 0.5) s - 0.5, which is what the principal point gets."""
    k = np.asarray(camera_matrix, dtype=float)
    return np.array([
        [k[0, 0] * scale_x, k[0, 1] * scale_x, (k[0, 2] + 0.5) * scale_x - 0.5],
        [k[1, 0] * scale_y, k[1, 1] * scale_y, (k[1, 2] + 0.5) * scale_y - 0.5],
        [0.0, 0.0, 1.0],
    ])


# --------------------------------------------------------------------------------- sections
@dataclass(frozen=True)
class RunConfig:
    """How stages execute (not part of any stage fingerprint: it never changes results)."""

    part_rows: int = param(16, "rows per Parquet part; a crash loses at most one part of work", "rows")
    workers: int = param(2, "worker processes of the local engine (spawned; each loads its renderer once)", "count")
    worker_max_tasks: int = param(
        60, "samples a worker processes before it is replaced (bounds the renderer's memory growth)", "count")
    engine: Literal["local", "ray"] = param(
        "local", "where render runs its samples: local (spawned processes) or ray (a Ray "
        "cluster, one renderer actor per worker); same seed, same pixels", "")
    ray_address: str = param("", "Ray cluster to join (e.g. ray://host:10001); empty: start a local one", "")


@dataclass(frozen=True)
class CameraConfig:
    """The testbed camera. Defaults: the SPEED+ camera (docs/architecture.md section 5), scaled to the
    profile resolution so that the field of view is unchanged."""

    reference_width_px: int = param(1920, "width at which fx, fy, cx, cy are given", "px")
    pixel_pitch_m: float = param(5.86e-6, "pixel pitch at the reference resolution (Sony IMX174: 5.86 um)", "m")
    reference_height_px: int = param(1200, "height at which fx, fy, cx, cy are given", "px")
    fx_px: float = param(2988.5795, "focal length x at the reference resolution (SPEED+ camera.json)", "px")
    fy_px: float = param(2988.3401, "focal length y at the reference resolution (SPEED+ camera.json)", "px")
    cx_px: float = param(960.0, "principal point x at the reference resolution", "px")
    cy_px: float = param(600.0, "principal point y at the reference resolution", "px")
    dist: tuple[float, float, float, float, float] = param(
        (-0.22383017, 0.51409797, -0.00066500, -0.00021405, -0.13124227),
        "OpenCV distortion (k1, k2, p1, p2, k3) of the SPEED+ camera; scale-free", "1")
    width_px: int = param(960, "image width of this run", "px")
    height_px: int = param(600, "image height of this run", "px")

    @property
    def scale(self) -> float:
        return self.width_px / self.reference_width_px

    def camera_matrix(self) -> np.ndarray:
        """K (3, 3) at ``width_px x height_px``: the reference K resized (``resize_camera_matrix``)."""
        reference = np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])
        return resize_camera_matrix(reference, self.scale, self.scale)

    def dist_coeffs(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=float)


@dataclass(frozen=True)
class TestbedConfig:
    """Geometry of the TRON-like room (frame K: x along the rail, y across, z up, origin on
    the floor in a corner). Nominal values: what the lab believes; the virtual testbed's
    true values differ from them."""

    __test__ = False  # not a pytest test class despite the name

    room_m: tuple[float, float, float] = param((8.0, 3.0, 3.0), "room size x, y, z (TRON: 8 x 3 x 3 m)", "m")
    robot_model: str = param("KR16-2", "KUKA arm model of both robots (see stages/common/kinematics.py)")
    target_base_m: tuple[float, float, float] = param(
        (0.6, 1.5, 0.0), "position of the floor-mounted target robot's base in K", "m")
    target_base_yaw_rad: float = param(0.0, "rotation of the target robot's base about K's z", "rad")
    rail_origin_m: tuple[float, float, float] = param(
        (1.7, 1.5, 3.0), "camera robot base position in K at rail position 0 (hanging, A1 axis down)", "m")
    rail_length_m: float = param(5.9, "usable rail travel along K's x (TRON: about 6 m)", "m")
    target_presentation_m: tuple[tuple[float, float, float], ...] = param(
        ((1.55, 1.5, 1.25), (1.35, 1.5, 1.0)),
        "candidate positions in K where the target robot presents the model's origin", "m")
    mockup_scale: float = param(0.5, "mock-up size / real Tango size (TRON: half scale)", "1")
    camee_from_cam_q: tuple[float, float, float, float] = param(
        (1.0, 0.0, 0.0, 0.0), "nominal rotation of the camera in the camera flange frame C_K", "1")
    camee_from_cam_t_m: tuple[float, float, float] = param(
        (0.0, 0.0, 0.12), "nominal camera position in the flange frame (lens 12 cm out along flange z)", "m")
    mount_target_from_targetee_q: tuple[float, float, float, float] = param(
        (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)),
        "nominal rotation of the target flange in T for the minus_x mount (flange z along +x of T); "
        "the plus_x mount is this rotated 180 deg about T's z", "1")
    mount_target_from_targetee_t_m: tuple[float, float, float] = param(
        (-0.305, 0.0, 0.08), "nominal flange position in T for the minus_x mount: 12 cm stand-off "
        "from the -x face of the half-scale model", "m")
    light_box_centres_m: tuple[tuple[float, float, float], ...] = param(
        ((0.5, 0.02, 1.3), (1.3, 0.02, 1.3), (2.1, 0.02, 1.3), (2.9, 0.02, 1.3),
         (0.5, 2.98, 1.3), (1.3, 2.98, 1.3), (2.1, 2.98, 1.3), (2.9, 2.98, 1.3),
         (0.02, 0.9, 1.3), (0.02, 2.1, 1.3)),
        "centres of the 10 Earth-albedo light boxes on the walls around the model (TRON: 10 boxes)", "m")
    light_box_size_m: tuple[float, float] = param((0.6, 0.6), "light box diffuser width, height", "m")
    light_box_aim_m: tuple[float, float, float] = param(
        (1.5, 1.5, 1.15), "point every light box faces (the model's working volume)", "m")
    sun_lamp_position_m: tuple[float, float, float] = param(
        (3.2, 0.25, 1.9), "sun lamp (metal-halide arc lamp) position in K", "m")
    board_squares: tuple[int, int] = param((11, 11), "ChArUco board squares x, y (TRON: 11 x 11)", "count")
    board_square_m: float = param(0.030, "ChArUco square side (TRON: 30 mm)", "m")
    board_marker_m: float = param(0.022, "ArUco marker side inside a square", "m")
    board_dictionary: str = param("DICT_5X5_100", "cv2.aruco predefined dictionary of the board")
    target_from_board_q: tuple[float, float, float, float] = param(
        (0.0, 1.0, 0.0, 0.0), "board frame (OpenCV ChArUco: origin at a corner, z into the board) in T: "
        "board z along -z of T, i.e. lying on the solar panel facing out", "1")
    target_from_board_t_m: tuple[float, float, float] = param(
        (-0.165, 0.165, 0.16375), "board origin in T: board centred on the half-scale solar panel "
        "(z = 0.3215 * 0.5 m) on a 3 mm plate", "m")


@dataclass(frozen=True)
class PlanConfig:
    """The plan stage: which relative poses to capture and how the robots realise them."""

    seed: int = param(2021, "random seed of the plan; same seed, same plan", "")
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
    dataset_range_m: tuple[float, float] = param(
        (6.5, 9.5), "camera-to-target distance range, FULL scale (paper: at least 6.5 m)", "m")
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


@dataclass(frozen=True)
class AcquireConfig:
    """The acquire stage: which testbed backend produces the captures."""

    backend: Literal["virtual", "replay"] = param(
        "virtual", "virtual (embedded digital twin) or replay (recorded session on disk)", "")
    format: Literal["session", "handeye", "tabb"] = param(
        "session", "replay format: session (a TRON-like logger's folder), handeye (images and a "
        "pose file described by dataset.toml) or tabb (Tabb's robot-world/hand-eye folders, a "
        "preset of handeye); see README", "")
    source: str = param("", "replay: the recorded session directory", "")


@dataclass(frozen=True)
class VirtualConfig:
    """Error sources of the virtual testbed; each default's source is in its help text.
    The hidden truth drawn from them is written to W/truth.json."""

    seed: int = param(11, "random seed of the hidden truth and of all measurement noise", "")
    link_length_sigma_m: float = param(
        0.0003, "1-sigma error of each true arm dimension vs the data sheet (uncalibrated KUKA arms: "
        "absolute accuracy of a few mm with 0.05 mm repeatability)", "m")
    joint_offset_sigma_rad: float = param(
        0.0006, "1-sigma true zero offset of each joint encoder (0.034 deg: about 1 mm at full reach)", "rad")
    base_position_sigma_m: float = param(0.0005, "1-sigma error of each robot base position in K", "m")
    base_rotation_sigma_rad: float = param(0.0002, "1-sigma error of each robot base orientation in K", "rad")
    repeatability_rad: float = param(
        1.5e-5, "1-sigma joint positioning noise (KR 16-2 data sheet: pose repeatability +-0.05 mm)", "rad")
    rail_scale_sigma: float = param(1e-4, "1-sigma scale error of the rail position encoder", "1")
    rail_noise_m: float = param(5e-5, "1-sigma rail positioning noise", "m")
    camera_fixture_sigma_m: float = param(0.003, "1-sigma true camera offset from its nominal fixture", "m")
    camera_fixture_sigma_rad: float = param(0.01, "1-sigma true camera rotation from its nominal fixture", "rad")
    model_fixture_sigma_m: float = param(0.003, "1-sigma true model offset from each nominal mount", "m")
    model_fixture_sigma_rad: float = param(0.01, "1-sigma true model rotation from each nominal mount", "rad")
    model_mass_kg: float = param(4.0, "mass of the half-scale mock-up (gravity moment on its fixture)", "kg")
    model_compliance_rad_per_nm: float = param(
        1e-3, "fixture tilt per unit gravity moment; the paper blames its KUKA-only rotation error (0.64 deg) "
        "on the model tilting on its fixture", "rad/(N m)")
    vicon_camera_height_m: float = param(2.8, "height of the 12 motion-capture cameras on the walls", "m")
    vicon_fov_rad: float = param(1.35, "full field of view of a motion-capture camera (Vicon Vero: 77 deg)", "rad")
    vicon_max_range_m: float = param(9.0, "farthest marker a motion-capture camera resolves", "m")
    vicon_marker_sigma_m: float = param(
        0.0003, "1-sigma marker position noise seen by two cameras (Vicon systems: sub-millimetre); "
        "scales with sqrt(2 / cameras)", "m")
    vicon_model_noise_factor: float = param(
        2.0, "marker noise on the mock-up relative to the camera's markers: its reflective foil and panels "
        "blur the marker images (the paper blames 'the reflective surfaces of the RSO model')", "1")
    vicon_ghost_rate: float = param(
        0.04, "probability that a tracked rigid body includes one ghost or mislabelled marker", "1")
    vicon_ghost_offset_m: tuple[float, float] = param((0.005, 0.03), "range of a ghost marker's displacement", "m")
    vicon_link_radius_m: float = param(0.09, "radius of the robot links as seen by motion capture", "m")
    vicon_world_from_world_q: tuple[float, float, float, float] = param(
        (0.7071067811865476, 0.0, 0.0, 0.7071067811865476),
        "motion-capture world V in K (set by the Vicon wand calibration; unrelated to K)", "1")
    vicon_world_from_world_t_m: tuple[float, float, float] = param(
        (1.2, -3.4, 0.05), "origin of K in V", "m")
    camera_markers_m: tuple[tuple[float, float, float], ...] = param(
        ((0.12, 0.08, 0.02), (-0.12, 0.09, 0.04), (0.10, -0.11, 0.10), (-0.11, -0.10, 0.13), (0.0, 0.13, 0.18)),
        "camera rigid-body markers in the camera flange frame (5 markers on a plate around the camera, "
        "spread about 25 cm so that the camera's pointing is tracked to about 0.05 deg)", "m")
    target_markers_rel: tuple[tuple[float, float, float], ...] = param(
        ((0.9, 0.8, 1.02), (-0.9, 0.85, 1.02), (0.85, -0.9, 1.02), (1.03, 0.2, 0.5), (-1.03, -0.3, 0.3),
         (0.2, 1.03, 0.2)),
        "model markers as fractions of the half extents of the body box about its centre (6 markers)", "1")
    spp: int = param(16, "Mitsuba samples per pixel of a capture", "count")
    max_depth: int = param(4, "Mitsuba path length (4: direct light and two interreflections)", "count")
    full_well_e: float = param(32513.0, "sensor full-well capacity (Sony IMX174 of the Grasshopper3 GS3-U3-23S6M)",
                               "e-")
    read_noise_e: float = param(6.8, "sensor read noise (IMX174, EMVA 1288 data)", "e-")
    gamma: float = param(1.0, "output gamma: 1 is linear, as machine-vision cameras deliver by default", "1")
    exposure_lightbox: float = param(5.0, "exposure scale (radiance to full well) under light boxes", "1")
    exposure_sunlamp: float = param(0.12, "exposure scale under the sun lamp", "1")
    exposure_ambient: float = param(2.5, "exposure scale under the room's ambient light (calibration)", "1")
    light_box_radiance: float = param(6.0, "radiance of an active light box (relative units)", "1")
    sun_lamp_radiance: float = param(4.0e4, "radiance of the sun lamp's arc (relative units)", "1")
    sun_lamp_radius_m: float = param(0.04, "radius of the sun lamp's emitting sphere", "m")
    ambient_radiance: float = param(2.5, "radiance of the ceiling panels used for calibration", "1")
    glare_strength: float = param(0.6, "veiling glare of the sun lamp relative to full scale at its image point",
                                  "1")


@dataclass(frozen=True)
class CalibrateConfig:
    """The calibrate stage: pattern detection, intrinsics, PnP and RWHE per source."""

    intrinsics: Literal["auto", "fixed", "estimate"] = param(
        "auto", "fixed (the session's camera), estimate (cv2.calibrateCamera), or auto: "
        "fixed when the session knows the camera", "")
    min_corners: int = param(6, "pattern corners an image needs to be used", "count")
    solver: Literal["shah", "frobenius", "reprojection"] = param(
        "frobenius", "shah (closed form), frobenius (Shah, then the paper's LM; the most accurate "
        "against the virtual truth, see README), or reprojection (then also the "
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
    arm_prior_rail_scale: float = param(1e-3, "prior 1-sigma of the rail encoder's scale error", "1")
    max_intrinsics_rms_px: float = param(
        2.0, "an estimated camera whose reprojection RMS over the kept images exceeds this is refused: corners of "
        "one printed pattern fit a real camera to 0.1-0.5 px (Tabb's DS1 and Ali's KUKA set: see README)", "px")
    motion_angle_floor_rad: float = param(
        math.radians(1.0), "an image is rejected when its camera motions' rotation angles differ from the robot's "
        "by more than this and by more than median + outlier_k robust sigmas (median over its pairs; a flipped "
        "corner order is off by tens of degrees, a good image by a few hundredths)", "rad")
    motion_pitch_floor_m: float = param(
        0.01, "the same for the pitch (translation along the screw axis) of the motions; good real data: 1-2 mm",
        "m")
    max_scale_error: float = param(
        0.03, "the camera's motions may differ from the robot's by at most this relative scale (a wrong square "
        "size or length unit scales them; a robot's own scale error is about 1e-4)", "1")
    max_rotation_error_rad: float = param(
        math.radians(5.0), "a calibration whose cross-validated E_R exceeds this is refused as absurd: robots and "
        "PnP err by tenths of a degree; 5 deg means the data do not fit the model", "rad")
    max_reprojection_fraction: float = param(
        0.02, "a calibration whose cross-validated E_p exceeds this fraction of the image diagonal is refused as "
        "absurd (about 45 px at 1920 x 1200; real calibrations: 1-5 px)", "1")


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
        10, "two-source dataset captures needed to estimate the variance factor (else the calibrated sigmas)",
        "count")


@dataclass(frozen=True)
class LabelConfig:
    """The label stage: SPEED+ labels of the dataset captures."""

    filename_template: str = param("{sample_id}.png", "image file name of a label in exports", "")


@dataclass(frozen=True)
class RenderConfig:
    """The render stage: Mitsuba 3 synthetic twins of the labels, and the training set."""

    set: Literal["twin", "train"] = param(
        "twin", "what to render: twin (one per label) or train (the synthetic training set)", "")
    seed: int = param(7, "random seed of the training poses, lights and of every image's Monte-Carlo noise", "")
    spp: int = param(64, "samples per pixel", "count")
    max_depth: int = param(4, "path length of the path tracer (3: direct light and one bounce)", "count")
    irradiance: float = param(
        3.0, "irradiance of the directional light on the model; the synthetic images' exposure is fixed, "
        "so 3.0 puts a sunlit white radiator near saturation", "W/m^2")
    train_count: int = param(1000, "images of the training set (render --set train --count N)", "count")
    train_distance_m: tuple[float, float] = param(
        (3.0, 10.0), "camera-to-target distance of training images, full scale (SPEED+ synthetic: a few "
        "metres to about 10 m)", "m")
    train_irradiance: tuple[float, float] = param(
        (1.0, 6.0), "training images: range of the light's irradiance (log-uniform)", "W/m^2")
    train_earth_fraction: float = param(
        0.5, "share of training images with the Earth behind the target", "1")
    train_resolution_scale: float = param(
        1.0, "training images: camera resolution times this (intrinsics scaled with it)", "1")
    margin_px: float = param(
        10.0, "training images: the target's bounding sphere stays this far inside the image when it fits", "px")
    train_spp: int = param(16, "training images: samples per pixel", "count")


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
    seed: int = param(0, "seed of initialisation, shuffling and augmentation", "")
    threads: int = param(2, "torch threads", "count")


@dataclass(frozen=True)
class EvaluateConfig:
    """The evaluate stage: an ONNX model scored on twins and testbed images."""

    model: str = param("models/reference.onnx", "ONNX model following the contract of stages/common/pose_model.py; "
                       "relative paths: from the current directory, else from the repository", "")
    batch_size: int = param(16, "images per inference call", "count")
    threads: int = param(2, "ONNX Runtime intra-op threads", "count")
    ransac_fraction: float = param(
        0.01, "RANSAC inlier threshold of keypoint PnP, as a fraction of the image width", "1")


@dataclass(frozen=True)
class Config:
    """The whole configuration of a run."""

    profile: str = "default"
    run: RunConfig = field(default_factory=RunConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    testbed: TestbedConfig = field(default_factory=TestbedConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)
    acquire: AcquireConfig = field(default_factory=AcquireConfig)
    virtual: VirtualConfig = field(default_factory=VirtualConfig)
    calibrate: CalibrateConfig = field(default_factory=CalibrateConfig)
    fuse: FuseConfig = field(default_factory=FuseConfig)
    label: LabelConfig = field(default_factory=LabelConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)

    def section(self, name: str) -> Any:
        return getattr(self, name)


#: section name -> its dataclass, read off ``Config`` (every field but ``profile``)
SECTION_TYPES: dict[str, type] = {name: hint for name, hint in typing.get_type_hints(Config).items()
                                  if name != "profile"}


# ---------------------------------------------------------------------------- validation
def _coerce(value: Any, annotation: Any, key: str) -> Any:
    """``value`` (from TOML or --set) as ``annotation``; ConfigError naming ``key`` if not."""
    origin = typing.get_origin(annotation)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    if origin is Literal:
        choices = typing.get_args(annotation)
        if value not in choices:
            listed = ", ".join(str(c) for c in choices[:-1]) + f" or {choices[-1]}"
            raise ConfigError(f"{key}: expected {listed}, got {value!r}")
        return value
    if origin is tuple:
        args = typing.get_args(annotation)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], key) for v in value)
        if len(value) != len(args):
            raise ConfigError(f"{key}: expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(v, a, key) for v, a in zip(value, args, strict=True))
    if origin in (types.UnionType, typing.Union):
        raise ConfigError(f"{key}: union types are not supported in configuration")
    raise ConfigError(f"{key}: unsupported type {annotation!r}")


def _unknown(key: str, known: list[str]) -> ConfigError:
    close = difflib.get_close_matches(key, known, n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    return ConfigError(f"unknown configuration key {key!r}{hint}")


def _apply(config: Config, updates: dict[str, Any], source: str) -> Config:
    known_keys = [f"{s}.{f.name}" for s, t in SECTION_TYPES.items() for f in fields(t)]
    changes: dict[str, Any] = {}
    for section_name, values in updates.items():
        if section_name == "profile":
            continue
        if section_name not in SECTION_TYPES:
            raise ConfigError(f"{source}: " + str(_unknown(section_name, list(SECTION_TYPES))))
        if not isinstance(values, dict):
            raise ConfigError(f"{source}: {section_name!r} must be a table of keys")
        section_type = SECTION_TYPES[section_name]
        hints = typing.get_type_hints(section_type)
        field_names = {f.name for f in fields(section_type)}
        coerced = {}
        for name, value in values.items():
            key = f"{section_name}.{name}"
            if name not in field_names:
                raise ConfigError(f"{source}: " + str(_unknown(key, known_keys)))
            try:
                coerced[name] = _coerce(value, hints[name], key)
            except ConfigError as error:
                raise ConfigError(f"{source}: {error}") from None
        changes[section_name] = replace(getattr(config, section_name), **coerced)
    return replace(config, **changes)


def _check(config: Config) -> Config:
    """Cross-field rules that types cannot express."""
    c, p = config.camera, config.plan
    if c.width_px <= 0 or c.height_px <= 0:
        raise ConfigError("camera.width_px/height_px: must be positive")
    if abs(c.width_px / c.reference_width_px - c.height_px / c.reference_height_px) > 1e-9:
        raise ConfigError(
            f"camera.width_px/height_px: {c.width_px}x{c.height_px} does not have the aspect of the reference "
            f"{c.reference_width_px}x{c.reference_height_px}; intrinsics can only be scaled uniformly")
    for key, low, high in (("plan.calibration_distance_m", *p.calibration_distance_m),
                           ("plan.dataset_range_m", *p.dataset_range_m)):
        if not 0 < low <= high:
            raise ConfigError(f"{key}: expected 0 < min <= max, got ({low}, {high})")
    if p.n_calibration < 0 or p.n_dataset < 0:
        raise ConfigError("plan.n_calibration/n_dataset: must not be negative")
    if not set(p.lights) <= set(DOMAINS) or not p.lights:
        raise ConfigError(f"plan.lights: expected a non-empty subset of lightbox, sunlamp, got {p.lights}")
    if not set(p.calibration_mounts) <= set(MOUNTS) or not p.calibration_mounts:
        raise ConfigError(f"plan.calibration_mounts: expected minus_x and/or plus_x, got {p.calibration_mounts}")
    low, high = p.light_boxes_per_sample
    if not 1 <= low <= high <= p.n_light_boxes:
        raise ConfigError(f"plan.light_boxes_per_sample: expected 1 <= min <= max <= {p.n_light_boxes}")
    if not 0 <= p.calibration_max_tilt_rad < math.pi / 2:
        raise ConfigError("plan.calibration_max_tilt_rad: expected [0, pi/2)")
    if config.acquire.backend == "replay" and not config.acquire.source:
        raise ConfigError("acquire.source: the replay backend needs the recorded session directory")
    if config.run.workers < 1 or config.run.worker_max_tasks < 1:
        raise ConfigError("run.workers/worker_max_tasks: must be at least 1")
    if not 0 <= config.virtual.vicon_ghost_rate <= 1:
        raise ConfigError("virtual.vicon_ghost_rate: expected a probability in [0, 1]")
    if config.calibrate.folds < 2:
        raise ConfigError("calibrate.folds: at least 2")
    if min(config.calibrate.arm_prior_joint_rad, config.calibrate.arm_prior_length_m, config.calibrate.arm_prior_base_m,
           config.calibrate.arm_prior_base_rad, config.calibrate.arm_prior_rail_scale) <= 0:
        raise ConfigError("calibrate.arm_prior_*: expected positive sigmas")
    if not math.isclose(float(np.linalg.norm(config.calibrate.world_up)), 1.0, rel_tol=1e-6):
        raise ConfigError(f"calibrate.world_up: expected a unit vector, got {config.calibrate.world_up}")
    r = config.render
    if r.spp < 1 or r.train_spp < 1 or r.max_depth < 1 or r.train_count < 0:
        raise ConfigError("render.spp/max_depth: at least 1; render.train_count: not negative")
    if not 0 < r.train_distance_m[0] <= r.train_distance_m[1]:
        raise ConfigError(f"render.train_distance_m: expected 0 < min <= max, got {r.train_distance_m}")
    if not 0 < r.train_irradiance[0] <= r.train_irradiance[1]:
        raise ConfigError(f"render.train_irradiance: expected 0 < min <= max, got {r.train_irradiance}")
    if not 0 <= r.train_earth_fraction <= 1 or not 0 < r.train_resolution_scale <= 4:
        raise ConfigError("render.train_earth_fraction: expected [0, 1]; render.train_resolution_scale: (0, 4]")
    if config.run.part_rows < 1:
        raise ConfigError("run.part_rows: must be at least 1")
    for section, key in (("testbed", "camee_from_cam_q"), ("testbed", "mount_target_from_targetee_q"),
                         ("testbed", "target_from_board_q"), ("virtual", "vicon_world_from_world_q")):
        q = np.asarray(getattr(config.section(section), key))
        if abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise ConfigError(f"{section}.{key}: quaternion norm {np.linalg.norm(q):.6f} is not 1")
    return config


# -------------------------------------------------------------------------------- loading
def _read_toml(path: Path, label: str) -> dict[str, Any]:
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{label}: file not found") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{label}: not valid TOML ({error})") from None


def profile_path(profile: str) -> Path:
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}; choose one of {', '.join(PROFILES)}")
    return Path(str(resources.files("pipeline") / "profiles" / f"{profile}.toml"))


def parse_override(text: str) -> tuple[str, str, Any]:
    """``section.key=value`` (value in TOML syntax; bare words are strings)."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    dotted, raw = text.split("=", 1)
    section, key = dotted.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return section, key, value


def load_config(profile: str | None = None, config_file: str | Path | None = None,
                overrides: list[str] | tuple[str, ...] = ()) -> Config:
    """Resolve a configuration (see the module docstring for the order).

    Without ``profile``, the ``profile`` key of ``config_file`` (e.g. a workspace's
    ``config.toml``) picks the base profile; otherwise ``default``.
    """
    data = _read_toml(Path(config_file), str(config_file)) if config_file is not None else {}
    if profile is None:
        profile = data.get("profile", "default")
        if not isinstance(profile, str):
            raise ConfigError(f"{config_file}: profile must be a string, got {profile!r}")
    config = _apply(Config(profile=profile), _read_toml(profile_path(profile), f"profile {profile}"),
                    f"profile {profile}")
    if data:
        config = _apply(config, data, str(config_file))
    for text in overrides:
        section, key, value = parse_override(text)
        config = _apply(config, {section: {key: value}}, f"--set {text}")
    return _check(config)


def to_dict(config: Config) -> dict[str, Any]:
    """Plain TOML-able dictionary (tuples become lists)."""
    def plain(value: Any) -> Any:
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        return value

    out: dict[str, Any] = {"profile": config.profile}
    for name in SECTION_TYPES:
        section = getattr(config, name)
        out[name] = {f.name: plain(getattr(section, f.name)) for f in fields(section)}
    return out


def write_config(config: Config, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text("# resolved SPEED+ builder configuration (written by speedplus)\n"
                         + tomli_w.dumps(to_dict(config)))
    temporary.replace(path)
