"""``speedplus view DIR|W``: a facility folder or a workspace as a Rerun recording
(``.rrd``), which the Rerun viewer opens (``rerun FILE``), in 3D and on a timeline.

Rerun, because it is a maintained viewer for exactly this: 3D transforms, link geometry,
pinhole cameras with their images and per-entity timelines, written from Python without a
running viewer (``rerun-sdk``), read back headless (``rerun.chunk.RrdReader``) by the tests;
RViz needs ROS, and Foxglove reads the ROS bag that ``export --format rosbag`` writes.

Every entity lives under ``room`` in the robot world K (m):

- ``room``: the room's box; ``room/obstacles/<i>``: the obstacles' boxes;
- ``room/robots/<name>``: each arm's links as capsules (segments with their radii), at its
  joints' zeros in a facility, at each capture's planned joints in a workspace (timeline
  ``capture``); ``room/robots/<name>/rail``: its rail's travel;
- ``room/statics/<name>``: the static mounts;
- ``room/motion_capture/<i>``: each motion-capture camera and its aim, and in a workspace
  ``room/motion_capture/sight``: its lines of sight to the target's markers at each capture;
- ``room/lights/box_<i>``, ``room/lights/sun``: the light boxes and the sun lamp;
- ``room/camera``: the camera at each capture (its frustum, a pinhole with the calibrated or
  configured intrinsics, OpenCV's frame) and ``room/camera/image``, the captured image;
- ``room/target/true`` (a virtual testbed's truth) and ``room/target/labelled`` (fuse's pose):
  the target's vertices at mock-up scale; the labelled one green where the label meets
  both SPEED+ thresholds, red where it misses one, with its errors as a text.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from core.config import Config
from manifests import Workspace, read_manifest
from manifests.facility import FACILITY_FILE, StaticSpec
from manifests.sidecars import read_markers, read_session
from manifests.workspace import CONFIG_FILE
from speedplus.errors import InputError
from stages.common import geometry as g
from stages.common.robots.facility import Facility, Robot, load_facility
from stages.common.scores import ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD

TIMELINE = "capture"
MET, MISSED, TRUE = (40, 200, 80), (220, 50, 50), (120, 120, 255)
#: the first bytes of an .rrd: a file view may replace
RRD_MAGIC = b"RRF2"
#: vertices drawn of the target: enough to see its shape, few enough for a light recording
TARGET_POINTS = 3000


def _rr() -> Any:
    import rerun as rr  # imported only where a recording is written: the pipeline runs without it

    return rr


def transform(rr: Any, pose: np.ndarray) -> Any:
    """A ``Transform3D`` of a (4, 4) pose (parent from child)."""
    w, x, y, z = g.matrix_to_quat(pose[:3, :3])
    return rr.Transform3D(translation=pose[:3, 3], quaternion=rr.Quaternion(xyzw=[x, y, z, w]))


def robot_links(rr: Any, robot: Robot, joints: np.ndarray, rail_m: float) -> Any:
    """The arm's link capsules in K as segments with their radii."""
    a, b, radius = robot.capsules(np.asarray(joints, float), rail_m)
    return rr.LineStrips3D(np.stack([a, b], axis=1), radii=radius, colors=(230, 140, 30))


def log_facility(rr: Any, recording: Any, facility: Facility) -> None:
    """The room, its obstacles, robots (at their joints' zeros), rails, static mounts, motion
    capture and lights: static entities (and the robots' default pose)."""
    spec = facility.spec
    room = np.asarray(spec.room_m)
    recording.log("room", rr.Boxes3D(centers=[room / 2], half_sizes=[room / 2], colors=(160, 160, 160)), static=True)
    for index, (low, high) in enumerate(facility.obstacles):
        recording.log(f"room/obstacles/{index}", rr.Boxes3D(mins=[low], sizes=[high - low], colors=(120, 90, 60)),
                      static=True)
    for robot in facility.robots:
        path = f"room/robots/{robot.spec.name}"
        recording.log(path, robot_links(rr, robot, np.zeros(robot.chain.dof), 0.0), static=True)
        if robot.spec.rail is not None:
            low, high = robot.spec.rail.travel_m
            base, axis = np.asarray(robot.spec.world_from_base.t), np.asarray(robot.spec.rail.axis)
            recording.log(f"{path}/rail", rr.LineStrips3D([[base + low * axis, base + high * axis]], radii=0.03,
                                                          colors=(90, 90, 90)), static=True)
    for static in spec.statics:
        assert isinstance(static, StaticSpec)
        recording.log(f"room/statics/{static.name}", rr.Points3D([static.world_from_mount.t], radii=0.05,
                                                                 labels=[f"{static.name} ({static.carries})"]),
                      static=True)
    if spec.motion_capture is not None:
        for index, (position, aim) in enumerate(spec.motion_capture.cameras):
            direction = np.asarray(aim) - np.asarray(position)
            recording.log(f"room/motion_capture/{index}", rr.Arrows3D(
                origins=[position], vectors=[0.4 * direction / np.linalg.norm(direction)], colors=(60, 160, 220)),
                static=True)
    for index, box in enumerate(spec.light_boxes):
        recording.log(f"room/lights/box_{index}", rr.Boxes3D(
            centers=[box.centre_m], half_sizes=[[box.size_m[0] / 2, box.size_m[1] / 2, 0.02]],
            colors=(250, 240, 180)), static=True)
    if spec.sun_lamp is not None:
        recording.log("room/lights/sun", rr.Points3D([spec.sun_lamp.position_m], radii=spec.sun_lamp.radius_m,
                                                     colors=(255, 220, 80)), static=True)


def _target_points(config: Config, workspace: Workspace) -> np.ndarray:
    """(P, 3) the target's vertices at mock-up scale (its own ``mockup_scale``, as label
    takes it: a recording's session has none), in T, m."""
    from stages.common.workspace_target import workspace_target

    target = workspace_target(config, workspace)
    vertices = target.vertices_m * target.mockup_scale
    step = max(1, len(vertices) // TARGET_POINTS)
    return vertices[::step]


def _camera(config: Config, workspace: Workspace) -> tuple[np.ndarray, int, int]:
    """K (3, 3), width, height: calibrated where calibrate ran, else as the session recorded
    it (a replay's images and their K where given), else as configured."""
    if workspace.calibration_path.exists():
        from stages.common.json_arrays import calibrated_camera

        camera = calibrated_camera(workspace)
        return np.asarray(camera.camera_matrix, float), camera.width, camera.height
    configured = config.camera.camera_matrix(), config.camera.width_px, config.camera.height_px
    if not workspace.session_path.exists():
        return configured
    recorded = read_session(workspace).camera
    if recorded.camera_matrix is not None:
        return np.asarray(recorded.camera_matrix, float), recorded.width, recorded.height
    from core.config import resize_camera_matrix  # the configured lens on the recorded sensor

    return (resize_camera_matrix(configured[0], recorded.width / configured[1], recorded.height / configured[2]),
            recorded.width, recorded.height)


def label_colour(error_t_m: float, range_m: float, error_r_rad: float) -> tuple[int, int, int]:
    """Green where a label meets both SPEED+ thresholds, red where it misses one."""
    met = error_r_rad < ROTATION_THRESHOLD_RAD and error_t_m / range_m < TRANSLATION_THRESHOLD
    return MET if met else MISSED


def _stations(config: Config, workspace: Workspace, facility: Facility) -> list[dict[str, Any]]:
    """Each capture's sample id, the camera in K (4, 4), the arms' joints by what they carry
    (None: not drawn) and the rail: as planned on the virtual testbed; on a replay as the
    recording measured them (the flange composed with the calibrated ``cam_from_camee``
    where calibrate ran), the arms drawn only on a facility folder of the lab's own."""
    plan = _rows(workspace, "plan")
    if plan:
        fixture = facility.fixture("camera")
        return [{"sample_id": r["sample_id"], "rail_m": r["rail_m"],
                 "world_from_cam": g.transform_from_qt(r["world_from_camee_q"], r["world_from_camee_t"]) @ fixture,
                 "joints": {"camera": r["camera_joints_rad"], "target": r["target_joints_rad"]},
                 "cam_from_target": g.transform_from_qt(r["cam_from_target_q"], r["cam_from_target_t"])}
                for r in plan]
    camee_from_cam = np.eye(4)
    if workspace.calibration_path.exists():
        from manifests.sidecars import read_calibration

        offset = read_calibration(workspace).kuka.cam_from_offset
        camee_from_cam = g.invert(g.transform_from_qt(offset.q, offset.t))
    own = bool(config.facility.path)
    return [{"sample_id": r["sample_id"], "rail_m": r["kuka_rail_m"] or 0.0,
             "world_from_cam": g.transform_from_qt(r["kuka_world_from_camee_q"], r["kuka_world_from_camee_t"])
             @ camee_from_cam,
             "joints": {"camera": r["kuka_camera_joints_rad"] if own else None,
                        "target": r["kuka_target_joints_rad"] if own else None},
             "cam_from_target": None}
            for r in sorted(_rows(workspace, "captures"), key=lambda r: (r["session"] != "calibration",
                                                                          r["sample_id"]))]


def log_captures(rr: Any, recording: Any, config: Config, workspace: Workspace, facility: Facility) -> int:
    """Per capture on the ``capture`` timeline (``_stations``): the arms, the camera and its
    image, the true and labelled target, motion capture's lines of sight. Returns the count."""
    stations = _stations(config, workspace, facility)
    captures = {r["sample_id"]: r for r in _rows(workspace, "captures")}
    truth = {r["sample_id"]: r for r in _rows(workspace, "truth")}
    poses = {r["sample_id"]: r for r in _rows(workspace, "poses")}
    points = _target_points(config, workspace)
    markers = np.asarray(read_markers(workspace).centres_m) if workspace.markers_path.exists() else np.zeros((0, 3))
    matrix, width, height = _camera(config, workspace)
    holders = {carried: facility.holder(carried) for carried in ("camera", "target")}
    for index, station in enumerate(stations):
        sample_id, world_from_cam = station["sample_id"], station["world_from_cam"]
        recording.set_time(TIMELINE, sequence=index)
        for carried, holder in holders.items():
            joints = station["joints"][carried]
            if isinstance(holder, Robot) and joints is not None:
                rail = station["rail_m"] if holder.spec.rail is not None else 0.0
                recording.log(f"room/robots/{holder.spec.name}", robot_links(rr, holder, joints, rail))
        recording.log("room/camera", transform(rr, world_from_cam))
        recording.log("room/camera", rr.Pinhole(image_from_camera=matrix, width=width, height=height,
                                                 image_plane_distance=0.3))
        if sample_id in captures:
            recording.log("room/camera/image", rr.EncodedImage(path=workspace.fetch(captures[sample_id]["image_path"])))
        true = None
        if sample_id in truth:
            true = g.transform_from_qt(truth[sample_id]["cam_from_target_q"], truth[sample_id]["cam_from_target_t"])
            recording.log("room/target/true", rr.Points3D(g.apply(world_from_cam @ true, points), radii=0.004,
                                                          colors=TRUE))
        seen_at = true if true is not None else station["cam_from_target"]
        if sample_id in poses:
            labelled = _log_label(rr, recording, world_from_cam, true, poses[sample_id], points)
            seen_at = labelled if seen_at is None else seen_at
        if seen_at is not None and len(markers) and facility.spec.motion_capture is not None:
            seen = g.apply(world_from_cam @ seen_at, markers)
            sight = [[position, marker] for position, _ in facility.spec.motion_capture.cameras for marker in seen]
            recording.log("room/motion_capture/sight", rr.LineStrips3D(sight, radii=0.002, colors=(60, 160, 220)))
    return len(stations)


def _log_label(rr: Any, recording: Any, world_from_cam: np.ndarray, true: np.ndarray | None,
               pose: dict[str, Any], points: np.ndarray) -> np.ndarray:
    """The labelled target, coloured by its errors against ``true`` (None: a recording has
    no truth); returns its ``cam_from_target`` (4, 4)."""
    labelled = g.transform_from_qt(pose["cam_from_target_q"], pose["cam_from_target_t"])
    colour, text = (200, 200, 200), "no truth to measure the label against"
    if true is not None:
        error_t = float(np.linalg.norm(labelled[:3, 3] - true[:3, 3]))
        error_r = float(g.angular_distance(labelled[:3, :3], true[:3, :3]))
        colour = label_colour(error_t, float(np.linalg.norm(true[:3, 3])), error_r)
        text = f"E_T {error_t * 1000:.2f} mm at {np.linalg.norm(true[:3, 3]):.2f} m, E_R {np.degrees(error_r):.3f} deg"
    recording.log("room/target/labelled", rr.Points3D(g.apply(world_from_cam @ labelled, points), radii=0.004,
                                                      colors=colour))
    recording.log("room/target/labelled/error", rr.TextDocument(text))
    return labelled


def _rows(workspace: Workspace, name: str) -> list[dict[str, Any]]:
    from manifests import read_marker

    return read_manifest(workspace, name).to_pylist() if read_marker(workspace, name) is not None else []


def _first_bytes(path: Path) -> bytes:
    with path.open("rb") as file:
        return file.read(len(RRD_MAGIC))


class Recording:
    """An ``.rrd`` written beside its place, then moved there whole."""

    def __init__(self, out: Path, name: str) -> None:
        if out.is_dir() or (out.exists() and _first_bytes(out) != RRD_MAGIC):
            raise InputError(f"{out}: not a Rerun recording, and view replaces only its own; choose another --out")
        self.rr, self.out = _rr(), out
        out.parent.mkdir(parents=True, exist_ok=True)
        self.partial = out.with_name(f".{out.name}.partial")
        self.stream = self.rr.RecordingStream("speedplus", recording_id=name)
        self.stream.save(self.partial)
        self.stream.log("room", self.rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def close(self) -> Path:
        self.stream.flush()
        self.stream.disconnect()
        self.partial.replace(self.out)
        return self.out


def record_facility(folder: Path, out: Path) -> tuple[Path, str]:
    """The facility folder's recording at ``out``, and what it holds, in words."""
    if not (Path(folder) / FACILITY_FILE).is_file():
        raise InputError(f"{folder}: neither a facility folder ({FACILITY_FILE}) nor a workspace ({CONFIG_FILE})")
    facility = load_facility(folder)
    recording = Recording(out, f"facility {facility.spec.name}")
    log_facility(recording.rr, recording.stream, facility)
    mocap = facility.spec.motion_capture
    return recording.close(), (f"facility {facility.spec.name}: the room, {len(facility.robots)} robot(s), "
                               f"{len(facility.spec.light_boxes)} light box(es), "
                               f"{0 if mocap is None else len(mocap.cameras)} motion-capture camera(s)")


def record_workspace(config: Config, workspace: Workspace, out: Path) -> tuple[Path, str]:
    """The workspace's recording at ``out`` (its facility, then each planned capture), and
    what it holds, in words."""
    facility = load_facility(Path(config.facility.path) if config.facility.path else None)
    recording = Recording(out, f"workspace {workspace.location}")
    log_facility(recording.rr, recording.stream, facility)
    count = log_captures(recording.rr, recording.stream, config, workspace, facility)
    return recording.close(), f"workspace {workspace.location}: facility {facility.spec.name}, {count} capture(s)"
