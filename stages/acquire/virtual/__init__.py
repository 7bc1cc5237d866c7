"""The virtual TRON testbed: robots with true and nominal kinematics, compliant fixtures,
motion capture, and a camera that photographs the room in Mitsuba at the TRUE pose."""

from __future__ import annotations

from typing import Any

import numpy as np

from manifests import Workspace, read_manifest
from manifests.sidecars import Session, SessionCamera
from pipeline.config import Config
from stages.acquire.backend import CaptureRecord
from stages.acquire.virtual import mocap, robots
from stages.acquire.virtual.sensor import Sensor
from stages.acquire.virtual.truth import Truth, draw_truth
from stages.common import geometry as g
from stages.common import layout
from stages.common.geometry import pose_columns
from stages.common.image_io import write_png_atomic
from stages.common.kinematics import link_points
from stages.common.patterns import board_pattern

SESSION_CODES = {"calibration": 0, "dataset": 1}


class VirtualTestbed:
    """Implements ``stages.acquire.backend.Testbed``; the renderer loads on first capture."""

    def __init__(self, config: Config, workspace: Workspace) -> None:
        self.config, self.workspace = config, workspace
        self.truth: Truth = draw_truth(config)
        self.sensor = Sensor(config.camera, config.virtual)
        self._scene = None
        self.camera_markers_rb = g.apply(g.invert(self.truth.camee_from_camrb),
                                         np.asarray(config.virtual.camera_markers_m))
        self.target_markers_rb = g.apply(g.invert(self.truth.target_from_targetrb), mocap.target_markers(config))

    def samples(self) -> list[dict[str, Any]]:
        return read_manifest(self.workspace, "plan").to_pylist()

    def session(self) -> Session:
        camera = self.config.camera
        return Session("virtual", "virtual", ("kuka", "vicon"),
                       SessionCamera(camera.width_px, camera.height_px, camera.camera_matrix().tolist(),
                                     list(camera.dist)),
                       board_pattern(self.config.testbed).to_json(), mockup_scale=self.config.testbed.mockup_scale)

    @property
    def scene(self):  # noqa: ANN201 - TestbedScene, imported lazily with Mitsuba
        if self._scene is None:
            from stages.acquire.virtual.scene import TestbedScene

            self._scene = TestbedScene(self.config, self.sensor.geometry)
        return self._scene

    def _link_segments(self, state: robots.RobotState) -> np.ndarray:
        truth, testbed = self.truth, self.config.testbed
        camera_base = layout.world_from_camera_base(testbed, state.rail_m * truth.rail_scale) @ truth.camera_base_error
        target_base = layout.world_from_target_base(testbed) @ truth.target_base_error
        camera_points = g.apply(camera_base, link_points(truth.camera_arm,
                                                         state.camera_joints_rad + truth.camera_joint_offsets_rad))
        target_points = g.apply(target_base, link_points(truth.target_arm,
                                                         state.target_joints_rad + truth.target_joint_offsets_rad))
        return np.concatenate([np.stack([p[:-1], p[1:]], axis=1) for p in (camera_points, target_points)])

    def capture(self, sample: dict[str, Any]) -> CaptureRecord:
        config, truth = self.config, self.truth
        sample_id, session = sample["sample_id"], sample["session"]
        index = int(sample_id[3:])
        rng = np.random.default_rng([config.virtual.seed, SESSION_CODES[session], index])
        state = robots.move(config, truth, sample, rng)
        segments = self._link_segments(state)
        camera_body = mocap.observe(config, rng, self.camera_markers_rb,
                                    state.world_from_camee @ truth.camee_from_camrb,
                                    truth.vicon_world_from_world, segments, state.world_from_target)
        target_body = mocap.observe(config, rng, self.target_markers_rb,
                                    state.world_from_target @ truth.target_from_targetrb,
                                    truth.vicon_world_from_world, segments, state.world_from_target,
                                    config.virtual.vicon_model_noise_factor)
        image = self.photograph(state, sample["light"], list(sample["light_boxes"]), session == "calibration",
                                rng, seed=SESSION_CODES[session] * 1_000_000 + index)
        image_path = self.workspace.image_relpath(session, sample_id)
        write_png_atomic(self.workspace.resolve(image_path), image)
        cam_from_target = g.invert(state.world_from_cam) @ state.world_from_target
        captures = {
            "sample_id": sample_id, "session": session, "fixture": sample["mount"], "image_path": image_path,
            "source_image": None, "image_conversion": None,
            **pose_columns("kuka_world_from_camee", state.kuka_world_from_camee),
            **pose_columns("kuka_world_from_targetee", state.kuka_world_from_targetee),
            "kuka_camera_joints_rad": state.camera_joints_rad, "kuka_target_joints_rad": state.target_joints_rad,
            "kuka_rail_m": state.rail_m,
            **pose_columns("vicon_world_from_camrb", camera_body.vicon_world_from_rb),
            **pose_columns("vicon_world_from_targetrb", target_body.vicon_world_from_rb),
            "vicon_camrb_markers": camera_body.markers, "vicon_targetrb_markers": target_body.markers,
            "status": "ok",
        }
        truth_row = {
            "sample_id": sample_id, **pose_columns("cam_from_target", cam_from_target),
            **pose_columns("world_from_camee", state.world_from_camee),
            **pose_columns("world_from_targetee", state.world_from_targetee),
            "fixture_sag_rad": state.sag_rad,
            "vicon_camrb_ghost": camera_body.ghost, "vicon_targetrb_ghost": target_body.ghost,
        }
        return CaptureRecord(captures, truth_row)

    def photograph(self, state: robots.RobotState, light: str, boxes: list[int], show_board: bool,
                   rng: np.random.Generator, seed: int) -> np.ndarray:
        """The 8-bit image the camera takes at the true poses."""
        config = self.config
        radiance = self.sensor.distort(self.scene.render(state.world_from_cam, state.world_from_target, light,
                                                         boxes, show_board, seed))
        glare = None
        if light == "sunlamp":
            lamp_cam = g.apply(g.invert(state.world_from_cam), np.asarray(config.testbed.sun_lamp_position_m)[None])[0]
            glare = self.sensor.glare(lamp_cam)
        exposure = {"lightbox": config.virtual.exposure_lightbox, "sunlamp": config.virtual.exposure_sunlamp,
                    "ambient": config.virtual.exposure_ambient}[light]
        return self.sensor.expose(radiance, exposure, rng, glare)

    def silhouette(self, sample: dict[str, Any]) -> np.ndarray:
        """The mock-up's silhouette (H, W) bool in the capture of a plan row: the scene's
        model at the TRUE poses of that capture, through the camera's lens."""
        config, truth = self.config, self.truth
        session, index = sample["session"], int(sample["sample_id"][3:])
        rng = np.random.default_rng([config.virtual.seed, SESSION_CODES[session], index])
        state = robots.move(config, truth, sample, rng)  # the same draws as capture()
        coverage = self.sensor.distort(self.scene.silhouette(state.world_from_cam, state.world_from_target))
        return coverage >= 0.5
