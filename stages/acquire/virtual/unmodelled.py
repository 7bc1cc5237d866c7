"""The virtual facility's errors that ``calibrate`` and ``fuse`` do not model
(docs/architecture.md section 5, "modelled and unmodelled errors"): joint elasticity, gearbox backlash,
thermal drift, the motion-capture system's own calibration, a change of the camera's
intrinsics between the sessions, and a mount that is more than a first-order sag.

Each source is switched by ``virtual.unmodelled`` and draws its hidden parameters from its
own random stream (``virtual.seed``, ``virtual.unmodelled_seed``, the source's code), so
turning one off leaves every other draw of the facility unchanged; a source that is off
contributes exactly nothing (zero, identity, the configured camera).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.config import Config
from stages.acquire.virtual.room import room_of
from stages.common import geometry as g
from stages.common.statics import LinkMasses, link_masses

SOURCE_CODES = {"elasticity": 1, "backlash": 2, "thermal": 3, "mocap_calibration": 4, "intrinsics_drift": 5,
                "mount": 6}
ROBOTS = ("camera", "target")


@dataclass(frozen=True)
class Unmodelled:
    """One facility's hidden unmodelled parameters (units in the field comments)."""

    stiffness_nm_per_rad: dict[str, np.ndarray]  # per robot (6,); inf: rigid
    masses: dict[str, LinkMasses]  # per robot, true
    camera_payload_kg: float
    lost_motion_rad: dict[str, np.ndarray]  # per robot (6,)
    start_direction: dict[str, np.ndarray]  # per robot (6,), +-1: each joint's last move before the session
    backlash_preload_nm: float
    thermal_rise_k: float  # steady-state warming; 0: off
    thermal_start_k: dict[str, float]  # per session
    room_change_k: float  # dataset session minus calibration session
    vicon_scale: float  # reported / true distances in V
    vicon_camera_errors: np.ndarray  # (C, 3) per camera (room.room_of): rotation vectors turning its rays, rad
    vicon_reflection_bias_m: float
    camera_by_session: dict[str, Any]  # CameraConfig per session
    mount_compliance: np.ndarray  # (3, 3) fixture compliance shape in the flange frame (identity: isotropic)
    remount: dict[str, np.ndarray]  # per mount (4, 4): the dataset session's change of the model's fixture

    def to_json(self) -> dict[str, Any]:
        """The record kept in W/truth.json (for benchmarks; stages never read it)."""
        def plain(value: Any) -> Any:
            if isinstance(value, np.ndarray):
                return np.where(np.isfinite(value), value, -1.0).tolist()  # -1: rigid (JSON has no inf)
            if isinstance(value, dict):
                return {k: plain(v) for k, v in value.items()}
            if dataclasses.is_dataclass(value):
                return plain(dataclasses.asdict(value))
            return value
        return {field.name: plain(getattr(self, field.name)) for field in dataclasses.fields(self)}


def _rng(config: Config, source: str) -> np.random.Generator:
    v = config.virtual
    return np.random.default_rng([v.seed, v.unmodelled_seed, 0x0DE1, SOURCE_CODES[source]])


def _spread(rng: np.random.Generator, sigma: float, shape: int | tuple[int, ...]) -> np.ndarray:
    return np.exp(rng.normal(0.0, sigma, shape))  # log-normal: a stiffness or mass stays positive


def draw_unmodelled(config: Config) -> Unmodelled:
    """This facility's unmodelled parameters; identical for the same seeds and switches."""
    v, camera = config.virtual, config.camera
    on = set(v.unmodelled)
    nominal = link_masses(config.testbed.robot_model)

    stiffness = {robot: np.full(6, np.inf) for robot in ROBOTS}
    masses = {robot: nominal for robot in ROBOTS}
    if "elasticity" in on:
        rng = _rng(config, "elasticity")
        for robot in ROBOTS:
            stiffness[robot] = np.asarray(v.joint_stiffness_nm_per_rad) * _spread(rng, v.stiffness_spread, 6)
            masses[robot] = nominal.scaled(_spread(rng, v.stiffness_spread, 3))

    lost = {robot: np.zeros(6) for robot in ROBOTS}
    start = {robot: np.ones(6) for robot in ROBOTS}
    if "backlash" in on:
        rng = _rng(config, "backlash")
        for robot in ROBOTS:
            lost[robot] = np.asarray(v.lost_motion_rad) * rng.uniform(0.5, 1.0, 6)
            start[robot] = rng.choice([-1.0, 1.0], 6)

    rise, starts, room = 0.0, {"calibration": 0.0, "dataset": 0.0}, 0.0
    if "thermal" in on:
        rng = _rng(config, "thermal")
        rise = v.thermal_rise_k * float(_spread(rng, 0.2, ()))
        starts = {"calibration": 0.0, "dataset": min(v.thermal_dataset_start_k * float(_spread(rng, 0.2, ())), rise)}
        room = float(rng.normal(0.0, v.room_change_k))

    cameras_count = room_of(config).mocap_cameras
    scale, ray_errors, reflection = 1.0, np.zeros((cameras_count, 3)), 0.0
    if "mocap_calibration" in on:
        rng = _rng(config, "mocap_calibration")
        scale = 1.0 + float(rng.normal(0.0, v.vicon_scale_sigma))
        ray_errors = rng.normal(0.0, v.vicon_camera_ray_sigma_rad, (cameras_count, 3))
        reflection = v.vicon_reflection_bias_m

    cameras = {"calibration": camera, "dataset": camera}
    if "intrinsics_drift" in on:
        rng = _rng(config, "intrinsics_drift")
        focal = 1.0 + float(rng.normal(0.0, v.focal_change_sigma))
        shift = rng.normal(0.0, v.principal_point_change_sigma_px, 2)
        cameras["dataset"] = dataclasses.replace(camera, fx_px=camera.fx_px * focal, fy_px=camera.fy_px * focal,
                                                 cx_px=camera.cx_px + float(shift[0]),
                                                 cy_px=camera.cy_px + float(shift[1]))

    compliance = np.eye(3)
    remount = {mount: np.eye(4) for mount in ("minus_x", "plus_x")}
    if "mount" in on:
        rng = _rng(config, "mount")
        axes = g.rotvec_to_matrix(rng.normal(0.0, 1.0, 3))
        compliance = axes @ np.diag(_spread(rng, v.mount_anisotropy, 3)) @ axes.T
        remount = {mount: g.make_transform(g.rotvec_to_matrix(rng.normal(0.0, v.remount_sigma_rad, 3)),
                                           rng.normal(0.0, v.remount_sigma_m, 3)) for mount in remount}

    return Unmodelled(stiffness, masses, config.testbed.camera_payload_kg, lost, start, v.backlash_preload_nm, rise,
                      starts, room, scale, ray_errors, reflection, cameras, compliance, remount)
