"""What to render: one ``RenderJob`` per image, for the twins (from the labels, with the
light aligned to the testbed's) or for the training set (a seeded pose and light sampler).

Jobs are plain data, built in the main process and sent to the renderers of any engine;
every random choice is made here or seeded by the job, so an image depends on its job only.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.config import Config
from manifests import Workspace, read_manifest, read_marker
from manifests.sidecars import read_calibration, read_trajectories
from manifests.workspace import GROUND_TRUTH_TEMPLATE, MASK_TEMPLATE, RENDER_TEMPLATE
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common.cameras import train_camera
from stages.common.json_arrays import matrix
from stages.common.orbits import Elements, rtn_from_eci, two_body
from stages.common.target import Target
from stages.common.workspace_target import apparent_size_ratio, planned_target, workspace_target

SET_DIRECTORIES = {"twin": "twins", "train": "train"}
NEAR_CLIP_M = 0.05


@dataclass(frozen=True)
class RenderJob:
    """One image: pose (full scale), light, seed and where it goes."""

    sample_id: str
    set: str
    q_vbs2tango_true: tuple[float, ...]  # (4,) rotation of cam_from_target
    r_Vo2To_vbs_true: tuple[float, ...]  # noqa: N815 - SPEED+'s name; (3,) m, cam_from_target, full scale
    light_dir_cam: tuple[float, ...]  # (3,) unit, target towards the light, camera frame
    irradiance: float  # W/m^2
    earth: bool
    seed: int  # uint32 Monte-Carlo seed; also seeds the Earth background
    #: a sequence's frame: the Earth where the orbit puts it (else, with ``earth``, a random one):
    #: its centre (3,) m and surface rotation ``cam_from_planet`` (9,) in the camera frame, and
    #: the true sun's direction (3,) that lights it
    earth_centre_cam_m: tuple[float, ...] | None = None
    cam_from_planet: tuple[float, ...] | None = None
    sun_dir_cam: tuple[float, ...] | None = None

    @property
    def image_path(self) -> str:
        return RENDER_TEMPLATE.format(set=SET_DIRECTORIES[self.set], sample_id=self.sample_id)

    @property
    def mask_path(self) -> str:
        return MASK_TEMPLATE.format(set=SET_DIRECTORIES[self.set], sample_id=self.sample_id)

    @property
    def ground_truth_path(self) -> str:
        return GROUND_TRUTH_TEMPLATE.format(set=SET_DIRECTORIES[self.set], sample_id=self.sample_id)

    def cam_from_target(self) -> np.ndarray:
        return g.transform_from_qt(self.q_vbs2tango_true, self.r_Vo2To_vbs_true)


def image_seed(seed: int, set_name: str, sample_id: str) -> int:
    """A stable uint32 seed per image (no dependence on order, engine or worker)."""
    digest = hashlib.sha256(f"{seed}/{set_name}/{sample_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


def unrenderable_reason(q: Any, t: Any, radius_m: float) -> str | None:
    """Why a pose cannot be rendered, or None: q must be a finite unit quaternion, t finite
    with the whole model (its bounding sphere of ``radius_m``, full scale) in front of the camera."""
    q, t = np.asarray(q, float), np.asarray(t, float)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        return "quaternion is not 4 finite numbers"
    if abs(np.linalg.norm(q) - 1.0) > 1e-6:
        return f"quaternion is not unit (norm {np.linalg.norm(q):.6f})"
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        return "translation is not 3 finite numbers"
    if t[2] <= 0:
        return f"target behind the camera (z = {t[2]:.3f} m)"
    if t[2] - radius_m <= NEAR_CLIP_M:
        return f"target too close: its bounding sphere crosses the camera plane (z = {t[2]:.3f} m)"
    return None


# ------------------------------------------------------------------------------- twins
def _world_from_cam(workspace: Workspace) -> dict[str, np.ndarray]:
    """Camera poses in the robot world K per dataset capture: KUKA telemetry composed with
    the calibrated camera offset (the light positions are known in K)."""
    cam_from_camee = matrix(read_calibration(workspace).kuka.cam_from_offset)
    captures = read_manifest(workspace, "captures").to_pylist()
    return {row["sample_id"]: g.transform_from_qt(row["kuka_world_from_camee_q"], row["kuka_world_from_camee_t"])
            @ g.invert(cam_from_camee) for row in captures}


def light_position(config: Config, light: str, boxes: list[int]) -> np.ndarray:
    """Where the testbed light of a sample is, in K (m): the sun lamp, or the centroid of the
    active light boxes (equal radiance, so equal weights)."""
    testbed = config.testbed
    if light == "sunlamp":
        return np.asarray(testbed.sun_lamp_position_m, float)
    centres = np.asarray(testbed.light_box_centres_m, float)
    active = [b for b in boxes if 0 <= b < len(centres)] or list(range(len(centres)))
    return centres[active].mean(axis=0)


def twin_jobs(config: Config, workspace: Workspace) -> tuple[list[RenderJob], list[dict[str, str]]]:
    """A job per label, and the labels that cannot be rendered with their reasons."""
    target = workspace_target(config, workspace)
    scale = target.mockup_scale
    world_from_cam = _world_from_cam(workspace)
    plan = ({r["sample_id"]: r for r in read_manifest(workspace, "plan").to_pylist()}
            if read_marker(workspace, "plan") is not None else {})
    sequences = ({s.sequence_id: s for s in read_trajectories(workspace).sequences}
                 if config.plan.mode == "trajectory" else {})
    # unvalidated read: a bad row is rejected with its reason, the valid ones still render
    labels = sorted(read_manifest(workspace, "labels", validate=False).to_pylist(), key=lambda r: r["sample_id"])
    jobs, rejected = [], []
    for label in labels:
        sample_id = label["sample_id"]
        reason = unrenderable_reason(label["q_vbs2tango_true"], label["r_Vo2To_vbs_true"], target.radius_m)
        if reason is None and sample_id not in world_from_cam:
            reason = "no capture with this sample_id (camera position unknown)"
        if reason is not None:
            rejected.append({"sample_id": sample_id, "reason": reason})
            continue
        q = g.quat_normalize(label["q_vbs2tango_true"])
        cam_from_target = g.transform_from_qt(q, np.asarray(label["r_Vo2To_vbs_true"]) * scale)
        row = plan.get(sample_id, {})
        light = row.get("light") or label["domain"]
        world_from_target = world_from_cam[sample_id] @ cam_from_target
        towards = light_position(config, light, list(row.get("light_boxes") or [])) - world_from_target[:3, 3]
        direction = g.invert(world_from_cam[sample_id])[:3, :3] @ (towards / np.linalg.norm(towards))
        earth = orbital_earth(row, sequences) if row.get("sequence_id") is not None else {}
        jobs.append(RenderJob(sample_id, "twin", tuple(q), tuple(label["r_Vo2To_vbs_true"]), tuple(direction),
                              config.render.irradiance, bool(earth), image_seed(config.render.seed, "twin", sample_id),
                              **earth))
    return jobs, rejected


#: the Earth's rotation rate (rad/s, sidereal)
EARTH_RATE_RAD_S = 7.2921159e-5


def orbital_earth(row: dict[str, Any], sequences: dict[str, Any]) -> dict[str, tuple[float, ...]]:
    """A sequence frame's Earth in its camera frame: the chief's orbit places it, the
    camera's attitude turns it, the planet spins from its pose at the epoch."""
    sequence = sequences[row["sequence_id"]]
    chief = Elements(**sequence.chief)
    position, velocity = two_body(chief, [row["time_s"]])
    rtn_from = rtn_from_eci(position, velocity)[0]
    cam_from_eci = g.quat_to_matrix(row["eci_from_cam_q"]).T
    camera_eci = position[0] + rtn_from.T @ np.asarray(row["rtn_servicer_m"], float)
    spin = g.axis_angle_matrix("z", EARTH_RATE_RAD_S * row["time_s"])
    return {"earth_centre_cam_m": tuple(float(v) for v in cam_from_eci @ -camera_eci),
            "cam_from_planet": tuple(float(v) for v in (cam_from_eci @ spin).ravel()),
            "sun_dir_cam": tuple(float(v) for v in cam_from_eci @ np.asarray(row["sun_eci"], float))}


# --------------------------------------------------------------------------- training set
#: SPEED+'s synthetic images of Tango: a few metres to about 10 m (full scale)
SPEEDPLUS_TRAIN_DISTANCE_M = (3.0, 10.0)


def train_jobs(config: Config, target: Target | None = None) -> list[RenderJob]:
    """``render.train_count`` jobs of ``target`` (default: the configured one):
    SO(3)-uniform attitudes, distances uniform where ``render.train_distance_m`` and
    ``render.train_distance_diameters`` (times the target's diameter) both hold, the target's
    centre uniform over the image where its bounding sphere fits, light directions uniform
    over the half-sphere facing the camera, log-uniform irradiance, the Earth behind the
    target in ``render.train_earth_fraction``."""
    r = config.render
    target = planned_target(config) if target is None else target
    metres = r.train_distance_m or tuple(d * apparent_size_ratio(target) for d in SPEEDPLUS_TRAIN_DISTANCE_M)
    low = max(metres[0], r.train_distance_diameters[0] * target.diameter_m)
    high = min(metres[1], r.train_distance_diameters[1] * target.diameter_m)
    if not 0 < low <= high:
        raise InputError(f"render.train_distance_m={list(r.train_distance_m)} and render.train_distance_diameters="
                         f"{list(r.train_distance_diameters)} (x {target.diameter_m:.3g} m, the target's diameter) "
                         "leave no distance; open one of them")
    camera = train_camera(config)
    rng = np.random.default_rng([r.seed, 0x7A1])
    quats = g.random_quats(rng, r.train_count)
    jobs = []
    k_inv = np.linalg.inv(camera.camera_matrix)
    for index in range(r.train_count):
        distance = rng.uniform(low, high)
        radius_px = target.radius_m / distance * camera.camera_matrix[0, 0] + r.margin_px
        lows = np.array([radius_px, radius_px])
        highs = np.array([camera.width - 1 - radius_px, camera.height - 1 - radius_px])
        centre_px = np.where(lows < highs, rng.uniform(np.minimum(lows, highs), np.maximum(lows, highs)),
                             [(camera.width - 1) / 2, (camera.height - 1) / 2])
        ray = k_inv @ np.array([centre_px[0], centre_px[1], 1.0])
        centre_cam = ray / np.linalg.norm(ray) * distance
        q = quats[index]
        # the body centre (not the body origin) goes to the sampled point
        t = centre_cam - g.quat_to_matrix(q) @ target.centre_m
        light = rng.normal(size=3)
        light /= np.linalg.norm(light)
        if light @ centre_cam > 0:  # keep the lit side towards the camera, as SPEED+'s synthetic images do
            light = -light
        irradiance = math.exp(rng.uniform(math.log(r.train_irradiance[0]), math.log(r.train_irradiance[1])))
        earth = bool(rng.random() < r.train_earth_fraction)
        sample_id = f"trn{index:06d}"
        jobs.append(RenderJob(sample_id, "train", tuple(q), tuple(t), tuple(light), irradiance, earth,
                              image_seed(r.seed, "train", sample_id)))
    return jobs
