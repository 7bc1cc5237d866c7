"""The virtual testbed: robots with true and nominal kinematics, compliant fixtures, motion
capture, and a camera that photographs the room in Mitsuba at the TRUE pose. TRON's room
(``robots.py``), or a facility folder's (``facility.path``: ``rig.py``, ``room.py``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from core.config import Config
from manifests import Workspace, read_manifest, sample_ids
from manifests.sample_ids import SESSION_CODES
from manifests.sidecars import MarkersRecord, Session, SessionCamera, TruthRecord
from manifests.workspace import TRUTH_MAPS_TEMPLATE
from stages.acquire.backend import CaptureRecord
from stages.acquire.virtual import mocap, rig, robots
from stages.acquire.virtual.rig import Rig, draw_rig
from stages.acquire.virtual.room import room_of
from stages.acquire.virtual.sensor import Sensor, lens_camera
from stages.acquire.virtual.timeline import Moment, timeline
from stages.acquire.virtual.truth import Truth, draw_truth
from stages.common import geometry as g
from stages.common import ground_truth
from stages.common.arms import Payload
from stages.common.geometry import pose_columns
from stages.common.image_io import encode_png
from stages.common.kinematics import link_points
from stages.common.markers import markers, occluders
from stages.common.patterns import board_pattern
from stages.common.windows import film_window, image_window
from stages.common.workspace_target import workspace_target


class VirtualTestbed:
    """Implements ``stages.acquire.backend.Testbed``; the renderer loads on first capture."""

    def __init__(self, config: Config, workspace: Workspace, plan: list[dict[str, Any]] | None = None) -> None:
        self.config, self.workspace, self._plan = config, workspace, plan
        self.target = workspace_target(config, workspace)
        self.body = occluders(self.target)
        # chosen (where the target declares none) for this room's cameras at the plan's poses,
        # where there is a plan (the error models alone have none: a ring of cameras)
        planned = self._plan if self._plan is not None or workspace is None else self.samples()
        self.markers = markers(self.target, mocap.planned_sight(config, self.target, planned or [], self.body))
        self.payload = Payload.of(self.target)
        self.truth: Truth = draw_truth(config, self.target)
        self.rig: Rig | None = draw_rig(config) if config.facility.path else None
        self.room = room_of(config)
        cameras = self.truth.unmodelled.camera_by_session
        self.sensor = Sensor(cameras["calibration"], config.virtual)
        # the dataset session's camera may have drifted: same pinhole render, another lens map
        self.sensors = {"calibration": self.sensor,
                        "dataset": Sensor(cameras["dataset"], config.virtual, self.sensor.geometry)}
        self._scene = None
        self._surfaces = None
        self._points_m: np.ndarray | None = None  # every vertex (N, 3) of the full-scale target
        self._moments: dict[str, Moment] | None = None
        self.camera_markers_rb = g.apply(g.invert(self.truth.camee_from_camrb),
                                         np.asarray(config.virtual.camera_markers_m))
        self.target_markers_rb = g.apply(g.invert(self.truth.target_from_targetrb), self.markers.centres_m)
        self.target_normals_target = self.markers.normals
        u = self.truth.unmodelled
        self.mocap_errors = mocap.SystemErrors(u.vicon_scale, u.vicon_camera_errors, u.vicon_reflection_bias_m)

    def truth_record(self) -> TruthRecord:
        """``W/truth.json``: TRON's arms' truth, or the facility folder's robots'."""
        return self.truth.to_record(None if self.rig is None else self.rig.truth())

    def markers_record(self) -> MarkersRecord:
        """Where this testbed stuck the model's markers (``W/markers.json``)."""
        return MarkersRecord("chosen" if self.markers.chosen else "declared", self.markers.parts,
                             tuple(tuple(map(float, c)) for c in self.markers.centres_m),
                             tuple(tuple(map(float, n)) for n in self.markers.normals))

    def samples(self) -> list[dict[str, Any]]:
        if self._plan is None:
            self._plan = read_manifest(self.workspace, "plan").to_pylist()
        return self._plan

    def moment(self, sample: dict[str, Any]) -> Moment:
        """The capture's place in its session's timeline (computed once from the plan)."""
        if self._moments is None:
            self._moments = timeline(self.config, self.samples(), self.truth.unmodelled.start_direction)
        return self._moments[sample["sample_id"]]

    def session(self) -> Session:
        camera = self.config.camera
        sources = ("kuka", "vicon") if self.room.mocap_cameras else ("kuka",)
        return Session("virtual", "virtual", sources,
                       SessionCamera(camera.width_px, camera.height_px, camera.camera_matrix().tolist(),
                                     list(camera.dist)),
                       board_pattern(self.config.testbed, self.target).to_json(), mockup_scale=self.target.mockup_scale)

    @property
    def scene(self):  # noqa: ANN201 - TestbedScene, imported lazily with Mitsuba
        if self._scene is None:
            from stages.acquire.virtual.scene import TestbedScene

            self._scene = TestbedScene(self.config, self.sensor.geometry, self.target)
        return self._scene

    def _move(self, sample: dict[str, Any], rng: np.random.Generator) -> tuple[robots.RobotState, np.ndarray]:
        """The robots at a plan row's commands, and their links' segments (S, 2, 3) in K."""
        if self.rig is not None:
            return rig.move(self.config, self.truth, self.rig, sample, rng, self.payload)
        state = robots.move(self.config, self.truth, sample, rng, self.moment(sample), self.payload)
        return state, self._link_segments(state)

    def _link_segments(self, state: robots.RobotState) -> np.ndarray:
        camera_points = g.apply(state.world_from_camera_base, link_points(state.camera_arm, state.camera_link_rad))
        target_points = g.apply(state.world_from_target_base, link_points(state.target_arm, state.target_link_rad))
        return np.concatenate([np.stack([p[:-1], p[1:]], axis=1) for p in (camera_points, target_points)])

    def capture(self, sample: dict[str, Any]) -> CaptureRecord:
        config = self.config
        sample_id, session = sample["sample_id"], sample["session"]
        index = sample_ids.parse(sample_id)[1]
        rng = np.random.default_rng([config.virtual.seed, SESSION_CODES[session], index])
        moment = self.moment(sample)
        state, segments = self._move(sample, rng)
        camera_body, target_body = self._track(rng, state, segments)
        image = self.photograph(state, session, sample["light"], list(sample["light_boxes"]), rng,
                                seed=SESSION_CODES[session] * 1_000_000 + index)
        image_path = self.workspace.image_relpath(session, sample_id)
        files = {image_path: encode_png(image)}
        cam_from_target = g.invert(state.world_from_cam) @ state.world_from_target
        maps_path = None
        if session == "dataset":
            maps_path = TRUTH_MAPS_TEMPLATE.format(sample_id=sample_id)
            files[maps_path] = self.truth_maps(session, cam_from_target)
        captures = {
            "sample_id": sample_id, "session": session, "fixture": sample["mount"], "image_path": image_path,
            "source_image": None, "image_conversion": None,
            **pose_columns("kuka_world_from_camee", state.kuka_world_from_camee),
            **pose_columns("kuka_world_from_targetee", state.kuka_world_from_targetee),
            "kuka_camera_joints_rad": state.camera_joints_rad, "kuka_target_joints_rad": state.target_joints_rad,
            "kuka_rail_m": state.rail_m, "capture_time_s": moment.time_s,
            "move_s": moment.move_s,
            **pose_columns("vicon_world_from_camrb", camera_body.vicon_world_from_rb),
            **pose_columns("vicon_world_from_targetrb", target_body.vicon_world_from_rb),
            "vicon_camrb_markers": camera_body.markers, "vicon_targetrb_markers": target_body.markers,
            "vicon_targetrb_used": list(target_body.used) if target_body.used else None,
            "vicon_targetrb_residual_m": target_body.residual_m,
            "status": "ok",
        }
        truth_row = {
            "sample_id": sample_id, **pose_columns("cam_from_target", cam_from_target),
            **pose_columns("world_from_camee", state.world_from_camee),
            **pose_columns("world_from_targetee", state.world_from_targetee),
            "fixture_sag_rad": state.sag_rad,
            "vicon_camrb_ghost": camera_body.ghost, "vicon_targetrb_ghost": target_body.ghost,
            "maps_path": maps_path,
        }
        return CaptureRecord(captures, truth_row, files)

    def _track(self, rng: np.random.Generator, state: robots.RobotState,
               segments: np.ndarray) -> tuple[mocap.RigidBodyObservation, mocap.RigidBodyObservation]:
        """What motion capture reports of the camera's and the mock-up's rigid bodies (both
        untracked in a room without it)."""
        config, truth = self.config, self.truth
        if not self.room.mocap_cameras:
            return mocap.RigidBodyObservation(None, 0, False), mocap.RigidBodyObservation(None, 0, False)
        camera_body = mocap.observe(config, rng, self.camera_markers_rb,
                                    state.world_from_camee @ truth.camee_from_camrb,
                                    truth.vicon_world_from_world, segments, state.world_from_target, self.body,
                                    errors=self.mocap_errors)
        target_normals = self.target_normals_target @ state.world_from_target[:3, :3].T
        target_body = mocap.observe(config, rng, self.target_markers_rb,
                                    state.world_from_target @ truth.target_from_targetrb,
                                    truth.vicon_world_from_world, segments, state.world_from_target, self.body,
                                    config.virtual.vicon_model_noise_factor, self.mocap_errors, target_normals)
        return camera_body, target_body

    def truth_maps(self, session: str, cam_from_target: np.ndarray) -> bytes:
        """Depth and part ids of the mock-up at its TRUE pose, through the session's true
        lens (``stages.common.ground_truth``), for evaluation only: the EXR file's bytes."""
        from stages.common.surface import TargetSurfaces

        if self._surfaces is None:
            self._surfaces = TargetSurfaces(self.target.parts)
            self._points_m = self.target.vertices_m
        scale = self.target.mockup_scale
        full_scale = cam_from_target.copy()
        full_scale[:3, 3] /= scale  # the mesh is the full-scale target; the mock-up is it scaled
        camera = lens_camera(self.sensors[session].camera)
        lens = self.sensors[session].lens
        # cast only where the mock-up can be (stages.common.windows), as the twins' truth is
        window = image_window(lens, film_window(lens.geometry, full_scale, self._points_m))
        maps = (self._surfaces.through_lens(full_scale, camera) if window is None
                else self._surfaces.in_window(full_scale, camera, window))
        return ground_truth.encode(ground_truth.channels_of(maps, None, ground_truth.TRUTH, scale), camera,
                                   cam_from_target, maps.ids, scale)

    def photograph(self, state: robots.RobotState, session: str, light: str, boxes: list[int],
                   rng: np.random.Generator, seed: int) -> np.ndarray:
        """The 8-bit image the camera takes at the true poses, with the session's intrinsics
        (the board is up during the calibration session only)."""
        config, sensor = self.config, self.sensors[session]
        radiance = sensor.distort(self.scene.render(state.world_from_cam, state.world_from_target, light,
                                                    boxes, session == "calibration", seed))
        glare = None
        if light == "sunlamp":
            lamp_cam = g.apply(g.invert(state.world_from_cam), self.room.sun_lamp_m[None])[0]
            glare = sensor.glare(lamp_cam)
        exposure = {"lightbox": config.virtual.exposure_lightbox, "sunlamp": config.virtual.exposure_sunlamp,
                    "ambient": config.virtual.exposure_ambient}[light]
        return sensor.expose(radiance, exposure, rng, glare)

    def silhouette(self, sample: dict[str, Any]) -> np.ndarray:
        """The mock-up's silhouette (H, W) bool in the capture of a plan row: the scene's
        model at the TRUE poses of that capture, through the camera's lens."""
        config = self.config
        session, index = sample["session"], sample_ids.parse(sample["sample_id"])[1]
        rng = np.random.default_rng([config.virtual.seed, SESSION_CODES[session], index])
        state, _ = self._move(sample, rng)  # capture()'s draws
        coverage = self.sensors[session].distort(self.scene.silhouette(state.world_from_cam,
                                                                        state.world_from_target))
        return coverage >= 0.5
