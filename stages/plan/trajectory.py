"""Rendezvous sequences (plan.mode = trajectory): frames that follow relative orbital motion
and the target's torque-free attitude, placed in the room frame after frame.

Per sequence: the chief's orbit (exact Keplerian, ``orbits.two_body``) gives the RTN frame,
the sun's direction and the shadow; D'Amico's ROE model gives the servicer's position in
RTN; Euler's equations give the target's attitude; the camera points at the target's
centre of mass with a constant error and a jitter. ``cam_from_target`` follows, at mock-up
scale, and the room placement (``reconfigure``, or a facility folder's robots) realises
it. A frame the robots cannot reach, or whose target leaves the image, refuses the whole
plan with the count and the frames: a sequence is never thinned silently.

The presets scale with the plan's distance range (full scale, ``dataset_range``), so that
any target's sequences fit the room its poses fit.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from core.config import Config
from manifests import sample_ids
from manifests.facility import StaticSpec
from manifests.sidecars import SequenceRecord
from stages.common import geometry as g
from stages.common import layout
from stages.common.attitude import MassProperties, shell_mass_properties, torque_free
from stages.common.orbits import Elements, RoeModel, rtn_from_eci, two_body
from stages.common.robots.facility import Facility
from stages.common.sun import in_shadow, parse_epoch, sun_eci
from stages.common.target import Target
from stages.plan.facility_plan import light_box_centres, planned_facility, reconfigure_on
from stages.plan.poses import PlanningError, dataset_range, mount_away_from
from stages.plan.reconfigure import reconfigure

ATTITUDE_MODEL = "torque-free rigid body: Euler's equations, DOP853, rtol 1e-13"
SUN_MODEL = "Astronomical Almanac low-precision sun (0.01 deg), mean equator and equinox of date; cylindrical shadow"
#: the plan's columns that only a sequence's rows fill
SEQUENCE_COLUMNS = ("sequence_id", "frame", "time_s", "rtn_servicer_m", "eci_from_target_q", "eci_from_cam_q",
                    "sun_eci", "in_eclipse", "light_from_sun_rad")
#: random streams: (seed, this code, sequence index)
_STREAM = 2


@dataclass(frozen=True)
class Frames:
    """One sequence propagated: per frame (N of them) the quantities of the plan's columns.
    Positions full scale (m), ECI of ``stages/common/sun.py``."""

    times_s: np.ndarray  # (N,)
    rtn_servicer_m: np.ndarray  # (N, 3) camera relative to the target's centre of mass, chief RTN
    eci_from_target_q: np.ndarray  # (N, 4)
    eci_from_cam_q: np.ndarray  # (N, 4)
    sun_eci: np.ndarray  # (N, 3)
    earth_eci: np.ndarray  # (N, 3) unit vector from the target to the Earth's centre
    in_eclipse: np.ndarray  # (N,) bool
    cam_from_target_m: np.ndarray  # (N, 4, 4) FULL scale


def chief_elements(config: Config) -> Elements:
    t = config.trajectory
    return Elements(t.chief_a_m, t.chief_e, t.chief_i_rad, t.chief_raan_rad, t.chief_argp_rad,
                    t.chief_mean_anomaly_rad)


def mass_properties(config: Config, target: Target) -> tuple[MassProperties, str]:
    """The target's mass properties and their source ("declared" or "mesh shell")."""
    t = config.trajectory
    shell = shell_mass_properties(target, t.mass_kg)
    if not t.inertia_kgm2:
        return shell, "mesh shell"
    ixx, iyy, izz, ixy, ixz, iyz = t.inertia_kgm2
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], float)
    return MassProperties(t.mass_kg, shell.centre_of_mass_m, inertia), "declared"


def preset_motion(config: Config, target: Target, preset: str, masses: MassProperties
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(roe_m (6,), the initial body rate (3,) rad/s) of a preset (module docstring)."""
    t = config.trajectory
    if preset == "custom":
        return np.asarray(t.roe_m, float), np.asarray(t.spin_rad_s, float)
    chosen = dataset_range(config.plan, target, config.testbed)
    low, high = chosen.low_m, chosen.high_m
    middle, span = 0.5 * (low + high), high - low
    _, axes = masses.principal_axes()  # columns: minor, intermediate, major
    if preset == "vbar_hold_spin":
        # a hold behind the target on the v-bar, circled by a small passively safe e/i ellipse
        roe_m = np.array([0.0, -middle, 0.0, 0.05 * middle, 0.0, 0.05 * middle])
        return roe_m, t.spin_rate_rad_s * axes[:, 2]
    # approach_tumble: a lower orbit drifts the servicer forwards from the far end of the range
    roe_m = np.array([-0.05 * middle, -(low + 0.9 * span), 0.0, 0.03 * middle, 0.0, 0.03 * middle])
    return roe_m, t.spin_rate_rad_s * (0.8 * axes[:, 2] + 0.6 * axes[:, 0])


def _camera_attitude(toward_target_eci: np.ndarray, normal_eci: np.ndarray, radial_eci: np.ndarray,
                     tilts_rad: np.ndarray) -> np.ndarray:
    """``eci_from_cam`` rotations (N, 3, 3): boresight on the target, image down along the
    orbit normal (radial where they align), tilted by ``tilts_rad`` (N, 2) about the camera's x, y."""
    hint = np.where(np.abs(np.einsum("ni,ni->n", toward_target_eci, normal_eci))[:, None] < 0.99,
                    -normal_eci, radial_eci)
    eci_from_aim = g.look_at_rotation(toward_target_eci, -hint)
    tilt = np.concatenate([tilts_rad, np.zeros((len(tilts_rad), 1))], axis=1)
    return eci_from_aim @ g.rotvec_to_matrix(tilt)


def propagate(config: Config, roe_m: np.ndarray, omega0: np.ndarray, eci_from_target_q0: np.ndarray,
              tilts_rad: np.ndarray, masses: MassProperties) -> Frames:
    """A sequence's frames (module docstring); ``tilts_rad`` (N, 2): pointing error per frame."""
    t = config.trajectory
    chief = chief_elements(config)
    times = np.arange(t.frames) * t.cam_step_s
    chief_r, chief_v = two_body(chief, times)
    rtn_from = rtn_from_eci(chief_r, chief_v)  # (N, 3, 3)
    rtn = RoeModel(chief, roe_m / chief.a_m).rtn_m(times)
    servicer_offset = np.einsum("nji,nj->ni", rtn_from, rtn)  # ECI, camera minus target centre of mass
    eci_from_target_q, _ = torque_free(masses.inertia_kgm2, eci_from_target_q0, omega0, times)
    eci_from_target = g.quat_to_matrix(eci_from_target_q)
    toward = -servicer_offset / np.linalg.norm(servicer_offset, axis=1, keepdims=True)
    eci_from_cam = _camera_attitude(toward, rtn_from[:, 2], rtn_from[:, 0], tilts_rad)
    origin_from_cam = -servicer_offset - eci_from_target @ masses.centre_of_mass_m  # body origin minus camera
    cam_from_target = g.make_transform(np.swapaxes(eci_from_cam, 1, 2) @ eci_from_target,
                                       np.einsum("nji,nj->ni", eci_from_cam, origin_from_cam))
    sun = sun_eci(parse_epoch(t.epoch_utc), times)
    return Frames(times, rtn, eci_from_target_q, g.matrix_to_quat(eci_from_cam), sun,
                  -chief_r / np.linalg.norm(chief_r, axis=1, keepdims=True), in_shadow(chief_r, sun), cam_from_target)


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    cosine = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.arccos(np.clip(cosine, -1.0, 1.0)))


def frame_light(config: Config, world_from_target: np.ndarray, centre_world: np.ndarray,
                target_from_eci: np.ndarray, sun: np.ndarray, earth: np.ndarray, eclipse: bool,
                lights: RoomLights) -> tuple[str, list[int], float]:
    """(light, active light boxes, angle of the testbed light from the true sun, rad): the sun
    lamp when the frame is sunlit and the lamp stands within ``sunlamp_tolerance_rad`` of the
    sun's direction, else the light boxes on the Earth's side."""
    rotation = world_from_target[:3, :3] @ target_from_eci
    sun_world, earth_world = rotation @ sun, rotation @ earth
    wanted = config.plan.lights
    lamp_error = np.pi if lights.sun_lamp_m is None else _angle(lights.sun_lamp_m - centre_world, sun_world)
    if "lightbox" not in wanted or ("sunlamp" in wanted and not eclipse
                                    and lamp_error <= config.trajectory.sunlamp_tolerance_rad):
        return "sunlamp", [], lamp_error
    directions = lights.box_centres_m - centre_world
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    order = np.argsort(-(directions @ earth_world), kind="stable")
    low, high = config.plan.light_boxes_per_sample
    facing = int(np.sum(directions @ earth_world > 0))
    boxes = sorted(int(i) for i in order[:min(high, max(low, facing))])
    return "lightbox", boxes, _angle(directions[boxes].mean(axis=0), sun_world)


@dataclass(frozen=True)
class RoomLights:
    """Where the room's lights stand in K (m): the sun lamp's centre (None: none) and the
    light boxes' centres (B, 3)."""

    sun_lamp_m: np.ndarray | None
    box_centres_m: np.ndarray

    @classmethod
    def of(cls, config: Config, facility: Facility | None) -> RoomLights:
        if facility is None:
            return cls(np.asarray(config.testbed.sun_lamp_position_m, float),
                       np.asarray(config.testbed.light_box_centres_m, float))
        lamp = facility.spec.sun_lamp
        return cls(None if lamp is None else np.asarray(lamp.position_m, float), light_box_centres(facility))


def sequence_record(config: Config, sequence_id: str, preset: str, first_sample_id: str, roe_m: np.ndarray,
                    omega0: np.ndarray, q0: np.ndarray, bias: np.ndarray, masses: MassProperties, source: str
                    ) -> SequenceRecord:
    t = config.trajectory
    chief = chief_elements(config)
    return SequenceRecord(
        sequence_id, preset, t.epoch_utc, t.frames, t.cam_step_s, first_sample_id, chief.to_json(),
        tuple(float(v) for v in roe_m / chief.a_m), tuple(float(v) for v in roe_m), masses.mass_kg,
        tuple(float(v) for v in masses.centre_of_mass_m),
        tuple(tuple(float(v) for v in row) for row in masses.inertia_kgm2),
        source, tuple(float(v) for v in omega0), tuple(float(v) for v in q0), tuple(float(v) for v in bias),
        RoeModel.NAME, ATTITUDE_MODEL, SUN_MODEL)


def unplaceable(frames: list[int], why: str, sequence_id: str) -> PlanningError:
    listed = ", ".join(str(f) for f in frames[:8]) + (f" and {len(frames) - 8} more" if len(frames) > 8 else "")
    return PlanningError(f"trajectory.presets: sequence {sequence_id}: {len(frames)} frame(s) {why} (frames "
                         f"{listed}); the sequence is refused, not thinned: shorten trajectory.frames or "
                         "trajectory.cam_step_s, move it with trajectory.roe_m (custom) or plan.dataset_range_*, "
                         "or widen testbed.rail_* and plan.sight_*")


def _placed(config: Config, target: Target, frames: Frames, sequence_id: str, first_index: int, redraws: int,
            every: bool, rng: np.random.Generator) -> tuple[list[dict], list[int], list[int]]:
    """(rows, frames outside the image, frames out of reach) of a propagated sequence; stops
    at the first frame that cannot be placed unless ``every``. On a facility folder each
    frame is placed as the plan's poses are (``facility_plan.reconfigure_on``, drawing from
    ``rng``); TRON's room keeps its grid search, nearest the frame before."""
    scale, camera = target.mockup_scale, config.camera
    facility = planned_facility(config)
    fixture = layout.camee_from_cam(config.testbed) if facility is None else facility.fixture("camera")
    lights = RoomLights.of(config, facility)
    rows, outside, unreachable, previous = [], [], [], None
    for k in range(config.trajectory.frames):
        if (outside or unreachable) and not every:
            break
        cam_from_target = frames.cam_from_target_m[k].copy()
        cam_from_target[:3, 3] *= scale
        pixels = g.project(cam_from_target, target.keypoints_m * scale, camera.camera_matrix(), camera.dist_coeffs())
        depth = g.apply(cam_from_target, target.keypoints_m * scale)[:, 2]
        if not (np.all(depth > 0) and np.all((pixels >= 0) & (pixels <= [camera.width_px - 1, camera.height_px - 1]))):
            outside.append(k)
            continue
        mount = mount_away_from(cam_from_target)
        if facility is None:
            commands = reconfigure(cam_from_target, mount, config.plan, config.testbed, target, require_far_side=True,
                                   previous=previous)
        else:
            if isinstance(facility.holder("target"), StaticSpec):
                mount = config.plan.calibration_mounts[0]  # mounted once on its stand
            commands = reconfigure_on(facility, cam_from_target, mount, target, config.plan.seed, rng,
                                      config.plan.joint_limit_margin_rad, Counter())
        if commands is None:
            unreachable.append(k)
            continue
        previous = commands
        world_from_target = commands.world_from_camee @ fixture @ cam_from_target
        centre = g.apply(world_from_target, (target.centre_m * scale)[None])[0]
        target_from_eci = g.quat_to_matrix(frames.eci_from_target_q[k]).T
        light, boxes, light_error = frame_light(config, world_from_target, centre, target_from_eci,
                                                frames.sun_eci[k], frames.earth_eci[k], bool(frames.in_eclipse[k]),
                                                lights)
        rows.append({
            "sample_id": sample_ids.make("dataset", first_index + k), "session": "dataset",
            **g.pose_columns("cam_from_target", cam_from_target),
            "view": target.view_of(g.invert(cam_from_target)[:3, 3], scale), "light": light, "light_boxes": boxes,
            "mount": mount, "rail_m": commands.rail_m, "camera_joints_rad": commands.camera_joints_rad,
            "target_joints_rad": commands.target_joints_rad,
            **g.pose_columns("world_from_camee", commands.world_from_camee),
            **g.pose_columns("world_from_targetee", commands.world_from_targetee),
            "reachable": True, "redraws": redraws, "sequence_id": sequence_id, "frame": k,
            "time_s": float(frames.times_s[k]), "rtn_servicer_m": frames.rtn_servicer_m[k],
            "eci_from_target_q": frames.eci_from_target_q[k], "eci_from_cam_q": frames.eci_from_cam_q[k],
            "sun_eci": frames.sun_eci[k], "in_eclipse": bool(frames.in_eclipse[k]), "light_from_sun_rad": light_error,
        })
    return rows, outside, unreachable


def sequence_rows(config: Config, target: Target, index: int, preset: str, first_index: int
                  ) -> tuple[list[dict], SequenceRecord]:
    """The plan rows of the index-th sequence (dataset samples ``first_index`` on) and its record.

    A sequence with a frame that cannot be placed is re-planned from another draw of the
    target's initial attitude and the camera's pointing error (``redraws`` counts them, in
    every row), up to ``trajectory.max_replans`` times, then refused with every such frame."""
    sequence_id = preset
    masses, source = mass_properties(config, target)
    roe_m, omega0 = preset_motion(config, target, preset, masses)
    t = config.trajectory
    for attempt in range(t.max_replans + 1):
        rng = np.random.default_rng([config.plan.seed, _STREAM, index, attempt])
        q0 = g.random_quats(rng, 1)[0]
        bias = rng.normal(0.0, t.pointing_sigma_rad, 2)
        tilts = bias + rng.normal(0.0, t.jitter_sigma_rad, (t.frames, 2))
        frames = propagate(config, roe_m, omega0, q0, tilts, masses)
        rows, outside, unreachable = _placed(config, target, frames, sequence_id, first_index, attempt,
                                             attempt == t.max_replans, rng)
        if not outside and not unreachable:
            record = sequence_record(config, sequence_id, preset, sample_ids.make("dataset", first_index), roe_m,
                                     omega0, q0, bias, masses, source)
            return rows, record
    tried = f" in each of {t.max_replans + 1} draws of its initial attitude (the last shown)"
    if outside:
        raise unplaceable(outside, f"put the target's keypoints outside the image{tried}", sequence_id)
    raise unplaceable(unreachable, f"cannot be reached by the robots in this room{tried}", sequence_id)
