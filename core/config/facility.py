"""Configuration of the facility: how stages execute, the camera, the testbed's geometry and
lights, and the virtual testbed's error model (units: docs/architecture.md section 3)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from core.config.params import ConfigError, at_least, param, unit_quaternion
from core.facilities import TRON_FOLDER
from manifests.facility import read_facility_spec

if TYPE_CHECKING:
    from core.config.model import Config

UnmodelledSource = Literal["elasticity", "backlash", "thermal", "mocap_calibration", "intrinsics_drift", "mount"]
#: every error source of the virtual testbed that calibrate and fuse do not model
UNMODELLED_SOURCES: tuple[UnmodelledSource, ...] = (
    "elasticity", "backlash", "thermal", "mocap_calibration", "intrinsics_drift", "mount")


def resize_camera_matrix(camera_matrix: np.ndarray, scale_x: float, scale_y: float) -> np.ndarray:
    """K (3, 3) of an image resized by ``scale_x``, ``scale_y``. With pixel centres at integer
    coordinates a resize by s maps x to (x + 0.5) s - 0.5, which is what the principal point gets."""
    k = np.asarray(camera_matrix, dtype=float)
    return np.array([
        [k[0, 0] * scale_x, k[0, 1] * scale_x, (k[0, 2] + 0.5) * scale_x - 0.5],
        [k[1, 0] * scale_y, k[1, 1] * scale_y, (k[1, 2] + 0.5) * scale_y - 0.5],
        [0.0, 0.0, 1.0],
    ])



#: TRON's room (core/facilities/tron/facility.toml), where the geometry defaults below come from
TRON = read_facility_spec(TRON_FOLDER)
_CAMERA_ROBOT, _TARGET_ROBOT = TRON.carrier("camera"), TRON.carrier("target")


def stratified_grid(spp: int) -> tuple[int, int]:
    """The rows and the samples per pixel Mitsuba's ``multijitter`` sampler takes when asked
    for ``spp``: floor(sqrt(spp)) rows of as many columns as reach ``spp``, so a count that
    does not fill its grid (10, 32) is rounded up (12, 35)."""
    rows = max(1, math.isqrt(spp))
    return rows, rows * -(-spp // rows)


@dataclass(frozen=True)
class RunConfig:
    """How stages execute (not part of any stage fingerprint: it never changes results)."""

    part_rows: int = param(16, "rows per Parquet part; a crash loses at most one part of work", "rows")
    workers: int = param(
        2, "workers of the engine: local processes (each loads its renderer once), or Ray actors (at most "
        "this many; 0: as many as the cluster's free CPUs allow)", "count")
    worker_max_tasks: int = param(
        60, "samples a worker processes before it is replaced (bounds the renderer's memory growth)", "count")
    engine: Literal["local", "ray"] = param(
        "local", "where acquire (virtual), render and evaluate run their samples: local (spawned processes) or "
        "ray (a Ray cluster, one actor per worker, no shared filesystem needed); same seed, same bytes", "")
    ray_address: str = param(
        "", "Ray cluster to join (auto, or host:6379 of its head node); empty: start a local one", "")
    worker_cpus: int = param(1, "CPUs each Ray worker reserves; its renderer uses that many threads", "count")
    start_timeout_s: float = param(
        600.0, "how long a Ray worker may take to start (placement, code upload, Mitsuba) before the engine "
        "gives up on it", "s")

    def check(self, config: Config) -> None:
        """Counts of at least one (workers: 0 for as many as the cores) and a positive timeout."""
        at_least("run", self, {"workers": 0, "worker_max_tasks": 1, "worker_cpus": 1, "part_rows": 1})
        if not self.start_timeout_s > 0:
            raise ConfigError("run.start_timeout_s: expected a positive number of seconds")


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
    sensor: Literal["mono", "colour"] = param(
        "mono", "mono: one grey channel (SPEED+'s IMX174, and so the twins and the training images: "
        "stages/common/tone.py); colour: RGB (replayed recordings only: the virtual testbed is mono)", "")
    gamma: float = param(1.0, "output gamma of the camera: 1 is linear, as machine-vision cameras deliver by "
                         "default; the virtual testbed's sensor and the rendered images use it", "1")

    @property
    def scale(self) -> float:
        return self.width_px / self.reference_width_px

    def camera_matrix(self) -> np.ndarray:
        """K (3, 3) at ``width_px x height_px``: the reference K resized (``resize_camera_matrix``)."""
        reference = np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])
        return resize_camera_matrix(reference, self.scale, self.scale)

    def dist_coeffs(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=float)

    def check(self, config: Config) -> None:
        """A size of the reference's aspect, an output gamma, and a mono sensor on the virtual testbed."""
        at_least("camera", self, {"width_px": 1, "height_px": 1})
        if abs(self.width_px / self.reference_width_px - self.height_px / self.reference_height_px) > 1e-9:
            raise ConfigError(
                f"camera.width_px/height_px: {self.width_px}x{self.height_px} does not have the aspect of the "
                f"reference {self.reference_width_px}x{self.reference_height_px}; intrinsics can only be scaled "
                "uniformly")
        if config.acquire.backend == "virtual" and self.sensor == "colour":
            raise ConfigError("camera.sensor: the virtual testbed's camera is mono (an IMX174); colour is for "
                              "replayed recordings (acquire.backend = replay)")
        if not 0.2 <= self.gamma <= 5.0:
            raise ConfigError(f"camera.gamma: {self.gamma} is not an output gamma (0.2-5; 1 is linear)")


@dataclass(frozen=True)
class TargetConfig:
    """The object the dataset is of: a target folder (``DIR/target.toml`` beside its mesh;
    docs/user-guide.md, "Your own target"). ``plan`` copies it into ``W/target/``, which every later
    stage reads; its content's digest is in their fingerprints."""

    path: str = param("", "the target folder (DIR holding target.toml); empty: the built-in Tango", "")

    def check(self, config: Config) -> None:
        """Nothing beyond the types: the folder itself is read and checked by the plan."""


@dataclass(frozen=True)
class FacilityConfig:
    """The room, robots, rails and mounts the plan is made for and the virtual testbed rehearses: a facility folder
    (``DIR/facility.toml`` beside its robots' URDFs; docs/user-guide.md, "Your own facility").
    Its content's digest is in the fingerprints of the stages it changes (the plan, the
    robot programs)."""

    path: str = param(
        "", "the facility folder (DIR holding facility.toml); empty: TRON, as [testbed] describes it (plan, the "
        "virtual testbed, calibrate's arm model and the robot programs follow it)", "")

    def check(self, config: Config) -> None:
        """The folder's ``[camera]``, where it has one, is the configuration's ``[camera]``:
        the same sensor kind, size and pixel pitch (the intrinsics are ``[camera]``'s alone).
        The rest of the folder is read and checked by the commands that use it."""
        if not self.path or not (Path(self.path) / "facility.toml").is_file():
            return  # no folder there: the command that reads it says so, naming the file
        stated = read_facility_spec(Path(self.path)).camera
        if stated is None:
            return
        camera = config.camera
        where = Path(self.path) / "facility.toml"
        for key, folder, configured, setting in (
                ("sensor", stated.sensor, camera.sensor, "camera.sensor"),
                ("size_px", list(stated.size_px), [camera.reference_width_px, camera.reference_height_px],
                 "camera.reference_width_px and camera.reference_height_px"),
                ("pixel_pitch", stated.pixel_pitch_m, camera.pixel_pitch_m, "camera.pixel_pitch_m")):
            same = (np.isclose(folder, configured, rtol=1e-6) if key == "pixel_pitch" else folder == configured)
            if not same:
                raise ConfigError(f"{where}: key camera.{key} is {folder}, but the configuration's {setting} "
                                  f"{'is' if key != 'size_px' else 'are'} {configured}; set [camera] to the "
                                  "facility's camera (its intrinsics too), or mend the folder")


@dataclass(frozen=True)
class TestbedConfig:
    """Geometry of the TRON-like room (frame K: x along the rail, y across, z up, origin on
    the floor in a corner). Nominal values: what the lab believes; the virtual testbed's
    true values differ from them. The defaults of the room, bases, rail, camera fixture,
    payload and lights are TRON's facility folder's (``TRON``)."""

    __test__ = False  # not a pytest test class despite the name

    room_m: tuple[float, float, float] = param(TRON.room_m, "room size x, y, z (TRON: 8 x 3 x 3 m)", "m")
    robot_model: str = param("KR16-2", "KUKA arm model of both robots (see stages/common/kinematics.py)")
    target_base_m: tuple[float, float, float] = param(
        _TARGET_ROBOT.world_from_base.t, "position of the floor-mounted target robot's base in K", "m")
    target_base_yaw_rad: float = param(
        2 * math.atan2(_TARGET_ROBOT.world_from_base.q[3], _TARGET_ROBOT.world_from_base.q[0]),
        "rotation of the target robot's base about K's z", "rad")
    rail_origin_m: tuple[float, float, float] = param(
        _CAMERA_ROBOT.world_from_base.t, "camera robot base position in K at rail position 0 (hanging, A1 axis "
        "down)", "m")
    rail_length_m: float = param(_CAMERA_ROBOT.rail.travel_m[1] - _CAMERA_ROBOT.rail.travel_m[0],
                                 "usable rail travel along K's x (TRON: about 6 m)", "m")
    target_presentation_m: tuple[tuple[float, float, float], ...] = param(
        ((1.55, 1.5, 1.25), (1.35, 1.5, 1.0)),
        "candidate positions in K where the target robot presents the model's origin", "m")
    camera_payload_kg: float = param(
        _CAMERA_ROBOT.payload_kg, "weighed camera, lens and marker plate on the camera flange", "kg")
    camee_from_cam_q: tuple[float, float, float, float] = param(
        _CAMERA_ROBOT.flange_from_tool.q, "nominal rotation of the camera in the camera flange frame C_K", "1")
    camee_from_cam_t_m: tuple[float, float, float] = param(
        _CAMERA_ROBOT.flange_from_tool.t, "nominal camera position in the flange frame (lens 12 cm out along "
        "flange z)", "m")
    light_box_centres_m: tuple[tuple[float, float, float], ...] = param(
        tuple(box.centre_m for box in TRON.light_boxes),
        "centres of the 10 Earth-albedo light boxes on the walls around the model (TRON: 10 boxes)", "m")
    light_box_size_m: tuple[float, float] = param(TRON.light_boxes[0].size_m, "light box diffuser width, height",
                                                  "m")
    light_box_aim_m: tuple[float, float, float] = param(
        TRON.light_boxes[0].aim_m, "point every light box faces (the model's working volume)", "m")
    sun_lamp_position_m: tuple[float, float, float] = param(
        TRON.sun_lamp.position_m, "sun lamp (metal-halide arc lamp) position in K", "m")
    board_squares: tuple[int, int] = param((11, 11), "ChArUco board squares x, y (TRON: 11 x 11)", "count")
    board_square_m: float = param(0.030, "ChArUco square side (TRON: 30 mm)", "m")
    board_marker_m: float = param(0.022, "ArUco marker side inside a square", "m")
    board_dictionary: str = param("DICT_5X5_100", "cv2.aruco predefined dictionary of the board")

    def check(self, config: Config) -> None:
        """Unit quaternions."""
        unit_quaternion("testbed.camee_from_cam_q", self.camee_from_cam_q)


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
    model_compliance_rad_per_nm: float = param(
        1e-3, "fixture tilt per unit gravity moment; the paper blames its KUKA-only rotation error (0.64 deg) "
        "on the model tilting on its fixture", "rad/(N m)")
    vicon_camera_height_m: float = param(
        TRON.motion_capture.cameras[0][0][2], "height of the 12 motion-capture cameras on the walls", "m")
    vicon_fov_rad: float = param(1.35, "full field of view of a motion-capture camera (Vicon Vero: 77 deg)", "rad")
    vicon_max_range_m: float = param(9.0, "farthest marker a motion-capture camera resolves", "m")
    vicon_marker_sigma_m: float = param(
        TRON.motion_capture.marker_sigma_m, "1-sigma marker position noise seen by two cameras (Vicon systems: "
        "sub-millimetre); scales with sqrt(2 / cameras)", "m")
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
    spp: int = param(
        9, "Mitsuba samples per pixel of a capture, stratified on a jittered grid of floor(sqrt(spp)) rows: a count "
        "that fills its grid (4, 6, 8, 9, 12, 16, ...; docs/architecture.md section 5)", "count")
    max_depth: int = param(4, "Mitsuba path length (4: direct light and two interreflections)", "count")
    rr_depth: int = param(
        1, "path length from which Mitsuba's Russian roulette may end a path (unbiased: a survivor's weight is "
        "divided by its survival chance); paths that reach the black curtains carry almost nothing", "count")
    full_well_e: float = param(32513.0, "sensor full-well capacity (Sony IMX174 of the Grasshopper3 GS3-U3-23S6M)",
                               "e-")
    read_noise_e: float = param(6.8, "sensor read noise (IMX174, EMVA 1288 data)", "e-")
    exposure_lightbox: float = param(5.0, "exposure scale (radiance to full well) under light boxes", "1")
    exposure_sunlamp: float = param(0.12, "exposure scale under the sun lamp", "1")
    exposure_ambient: float = param(2.5, "exposure scale under the room's ambient light (calibration)", "1")
    light_box_radiance: float = param(6.0, "radiance of an active light box (relative units)", "1")
    sun_lamp_radiance: float = param(4.0e4, "radiance of the sun lamp's arc (relative units)", "1")
    sun_lamp_radius_m: float = param(TRON.sun_lamp.radius_m, "radius of the sun lamp's emitting sphere", "m")
    ambient_radiance: float = param(2.5, "radiance of the ceiling panels used for calibration", "1")
    glare_strength: float = param(0.6, "veiling glare of the sun lamp relative to full scale at its image point",
                                  "1")

    # Errors outside the calibration's model (docs/architecture.md section 5, "modelled and unmodelled errors").
    unmodelled: tuple[UnmodelledSource, ...] = param(
        UNMODELLED_SOURCES, "error sources outside calibrate's and fuse's model that are switched on; each draws "
        "from its own random stream (virtual.seed, virtual.unmodelled_seed, its name), so switching one off leaves "
        "the others' draws unchanged", "")
    unmodelled_seed: int = param(0, "extra seed of the unmodelled error sources", "")
    joint_stiffness_nm_per_rad: tuple[float, float, float, float, float, float] = param(
        (5.0e5, 5.0e5, 2.5e5, 6.0e4, 6.0e4, 3.0e4),
        "elasticity: torsional stiffness of A1-A6 (gearbox and shaft windup). Identified KR-class joints are "
        "of order 1e6 N m/rad on a KR 240 (Dumas et al., Robotics and Computer-Integrated Manufacturing 27(4), "
        "2011); a KR 16 carries 1/15 of its payload; A2's spring balancer is folded into A2's value", "N m/rad")
    stiffness_spread: float = param(
        0.25, "elasticity: 1-sigma relative spread of each true joint stiffness and link mass around its default "
        "(and the lab's nominal link masses, stages/common/statics.py)", "1")
    lost_motion_rad: tuple[float, float, float, float, float, float] = param(
        (2.9e-4, 2.9e-4, 2.9e-4, 5.8e-4, 5.8e-4, 5.8e-4),
        "backlash: gearbox lost motion (backlash plus hysteresis) of A1-A6; RV cycloidal reducers of the main "
        "axes: 1 arcmin max (Nabtesco RV-N data sheet), wrist gears about 2 arcmin; each true value is drawn "
        "between half and all of it", "rad")
    backlash_preload_nm: float = param(
        15.0, "backlash: a joint whose gravity torque exceeds this rests on its loaded flank, whatever the direction "
        "of its last move", "N m")
    speed_override: float = param(
        0.2, "thermal: programmed speed override of the lab's moves (KR 16 axis speeds: 156-335 deg/s)", "1")
    rail_speed_m_s: float = param(0.3, "thermal: rail speed at that override", "m/s")
    settle_s: float = param(2.0, "thermal: wait after a move for vibration to decay", "s")
    expose_s: float = param(1.5, "thermal: exposure, motion-capture averaging and image transfer", "s")
    light_change_s: float = param(45.0, "thermal: time to change the light set-up between captures", "s")
    thermal_rise_k: float = param(
        5.0, "thermal: steady-state warming of the arms' structure in operation (industrial robots warm by "
        "several kelvin and drift by a few tenths of a mm over hours: Heisel, Richter, Wurst, CIRP Annals "
        "46(1), 1997; Gong, Yuan, Ni, Int. J. Machine Tools and Manufacture 40(14), 2000)", "K")
    thermal_time_constant_s: float = param(3600.0, "thermal: time constant of the arms' warm-up", "s")
    thermal_dataset_start_k: float = param(
        3.0, "thermal: warming of the arms when the dataset session starts; calibration starts cold (0 K)", "K")
    link_expansion_per_k: float = param(2.3e-5, "thermal: expansion of the arms' cast-aluminium links", "1/K")
    rail_expansion_per_k: float = param(1.15e-5, "thermal: expansion of the steel rail", "1/K")
    room_change_k: float = param(1.0, "thermal: 1-sigma room temperature change between the two sessions", "K")
    vicon_scale_sigma: float = param(
        3e-4, "motion capture: 1-sigma scale error of the wand calibration (0.15 mm on the 500 mm wand; Vicon "
        "reports sub-mm volume accuracy, Merriaux et al., Sensors 17(7) 1591, 2017)", "1")
    vicon_camera_ray_sigma_rad: float = param(
        1.5e-4, "motion capture: 1-sigma residual pointing error of each camera after the wand calibration "
        "(about 0.2 px of a 2048 px, 77 deg camera; Eichelberger et al., J. Biomechanics 49(10), 2016)", "rad")
    vicon_reflection_bias_m: float = param(
        5e-4, "motion capture: shift of a marker's image centroid towards the reflective surface it sits on, "
        "when seen obliquely (its mirror image merges with it); 7 mm markers", "m")
    focal_change_sigma: float = param(
        1e-4, "camera intrinsics: 1-sigma relative focal length change between the two sessions' temperatures "
        "(Smith and Cope, ISPRS Archives 38(5), 2010; Handel, ISPRS Archives 36(5), 2007)", "1")
    principal_point_change_sigma_px: float = param(
        0.3, "camera intrinsics: 1-sigma principal point shift between the two sessions, at the reference "
        "resolution", "px")
    mount_anisotropy: float = param(
        0.3, "mount: 1-sigma log-ratio of the fixture's bending and torsion stiffness about its three axes "
        "(a bracket is stiffer in one plane than the other; the first-order sag model assumes one)", "1")
    mount_play_rad: float = param(
        4e-4, "mount: micro-slip of the fixture's clamped joints: its tilt lags its elastic value by up to this, "
        "against the direction the tilt last changed in (hysteresis of bolted joints: Gaul and Lenz, Acta "
        "Mechanica 125, 1997; the width is an estimate, some 5% of the 0.5 deg sag)", "rad")
    remount_sigma_m: float = param(5e-5, "mount: 1-sigma position change of the model when it is remounted "
                                   "between the sessions (dowel-pinned plate)", "m")
    remount_sigma_rad: float = param(1e-4, "mount: 1-sigma rotation change at the remount", "rad")

    def check(self, config: Config) -> None:
        """Renderer counts of at least one, a sample count that fills its grid, a ghost rate that is
        a probability, unit quaternions."""
        at_least("virtual", self, {"spp": 1, "max_depth": 1, "rr_depth": 1})
        rows, filled = stratified_grid(self.spp)
        if filled != self.spp:
            raise ConfigError(f"virtual.spp: {self.spp} does not fill the sampler's grid of {rows} rows (it would "
                              f"render {filled}); use {rows * (self.spp // rows)} or {filled}")
        if not 0 <= self.vicon_ghost_rate <= 1:
            raise ConfigError(f"virtual.vicon_ghost_rate: expected a probability in [0, 1], got "
                              f"{self.vicon_ghost_rate}")
        unit_quaternion("virtual.vicon_world_from_world_q", self.vicon_world_from_world_q)
