"""The manifests of docs/architecture.md section 4, defined as code.

Each manifest is a ``ManifestSpec``: ordered columns with their Arrow type, unit,
convention and validation rule (quaternion, workspace path, enumeration). The Arrow
schema built from it carries units and conventions in field metadata, and the manifest
name and ``SCHEMA_VERSION`` in schema metadata, so a Parquet part describes itself.

Change a column's meaning or type and ``SCHEMA_VERSION`` must change: readers refuse
parts written under another version, and stage fingerprints include it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import pyarrow as pa

#: 1.10: captures' vicon_targetrb_used and _residual_m, poses' per-source sigmas; 1.11: scores'
#: intervals, median and failure share; 1.12: models' detector rows (the box IoU; no SPEED score),
#: predictions' scores under each RANSAC seed; 1.13: the plan's joints nullable (a static mount),
#: the export_robot manifest; 1.14: captures' marker counts nullable (a ROS 2 bag records none)
SCHEMA_VERSION = "1.14"
#: older versions whose parts still read when their columns are this version's by name and
#: type, less nullable columns added since (read as nulls): 1.7 differs only in the
#: keypoint columns' fixed length (11) and the view columns' enumeration, 1.8 lacks the
#: plan's trajectory columns and captures' move_s, 1.9 the target body's used markers and
#: residual and the poses' per-source sigmas, 1.10 the scores' intervals (a scores part of
#: 1.10 does not read: evaluate writes it again), 1.11 the models' box IoU, 1.12 and 1.13 the same columns
#: (nullability aside); a kept recording reads as it is
READABLE_VERSIONS = ("1.7", "1.8", "1.9", "1.10", "1.11", "1.12", "1.13")

QUAT = pa.list_(pa.float64(), 4)
VEC3 = pa.list_(pa.float64(), 3)
VEC6 = pa.list_(pa.float64(), 6)
JOINTS = pa.list_(pa.float64(), 6)
KEYPOINTS = pa.list_(pa.list_(pa.float64(), 2))  # (K, 2): the target's K keypoints
BBOX = pa.list_(pa.float64(), 4)
KEYPOINTS_TEXT = "the target's keypoints (target.toml order; Tango: the 11 of SPEED+), distorted image coordinates"


@dataclass(frozen=True)
class Column:
    """One manifest column and the rule its values obey."""

    name: str
    type: pa.DataType
    unit: str
    description: str
    nullable: bool = False
    kind: str = "value"  # "value" | "quaternion" | "path" | "enum" | "name" (matches NAME_PATTERN)
    allowed: tuple[str, ...] = ()

    def field(self) -> pa.Field:
        metadata = {"unit": self.unit, "description": self.description, "kind": self.kind}
        if self.allowed:
            metadata["allowed"] = ",".join(self.allowed)
        return pa.field(self.name, self.type, nullable=self.nullable, metadata=metadata)


@dataclass(frozen=True)
class ManifestSpec:
    """A manifest: its name (directory under ``W/manifests``) and its columns."""

    name: str
    description: str
    columns: tuple[Column, ...]
    key: str = "sample_id"
    #: path columns naming workspace files whose sizes and hashes the completion marker records
    files: tuple[str, ...] = ()
    #: the command that makes it, where that is not the chain's stage of its name (what a
    #: reader that misses it is told to run, with ``-w W``)
    made_by: str = ""

    def schema(self) -> pa.Schema:
        return pa.schema(
            [c.field() for c in self.columns],
            metadata={"speedplus.manifest": self.name, "speedplus.schema_version": SCHEMA_VERSION},
        )

    def column(self, name: str) -> Column:
        for column in self.columns:
            if column.name == name:
                return column
        raise KeyError(f"manifest {self.name!r} has no column {name!r}")


def pose(prefix: str, frame_note: str, *, nullable: bool = False) -> tuple[Column, Column]:
    """The ``<a>_from_<b>_q`` / ``_t`` pair of a rigid transform ``a_from_b``."""
    return (
        Column(f"{prefix}_q", QUAT, "1",
               f"rotation of {prefix}, Hamilton (w, x, y, z), unit, w >= 0; {frame_note}",
               nullable=nullable, kind="quaternion"),
        Column(f"{prefix}_t", VEC3, "m",
               f"translation of {prefix} (origin of b in a); {frame_note}", nullable=nullable),
    )


def _configuration_columns() -> tuple[Column, ...]:
    """Table 2's grouping of a summary row (``scores``, ``comparisons``): domain, view, light."""
    return (Column("domain", pa.string(), "", "image domain; testbed = lightbox and sunlamp together", kind="enum",
                   allowed=("synthetic", "testbed")),
            Column("view", pa.string(), "", "one of the target's view names, or all", kind="name"),
            Column("light", pa.string(), "", "light set-up or all", kind="enum",
                   allowed=("lightbox", "sunlamp", "all")))


def _sample_id() -> Column:
    return Column("sample_id", pa.string(), "", "unique sample identifier, e.g. cal000003 or img000012")


SESSIONS = ("calibration", "dataset")
#: the built-in Tango's views; a target folder names its own (``[views] names``)
VIEWS = ("solar_panel", "rear_panel")
#: what a target's view names (and other names from a target folder) look like
NAME_PATTERN = re.compile(r"[a-z0-9_-]+")
LIGHTS = ("lightbox", "sunlamp", "ambient")
MOUNTS = ("minus_x", "plus_x")
DOMAINS = ("lightbox", "sunlamp")

PLAN = ManifestSpec(
    "plan",
    "relative poses to capture and the robot/rail commands that realise them",
    (
        _sample_id(),
        Column("session", pa.string(), "", "capture session", kind="enum", allowed=SESSIONS),
        *pose("cam_from_target", "mock-up scale, OpenCV camera frame C, the target's body frame T"),
        Column("view", pa.string(), "", "the side of the target the camera is on: the target's first view name "
               "(Tango: solar_panel) when it sees the side its view axis points to, else the second", kind="name"),
        Column("light", pa.string(), "", "light set-up", kind="enum", allowed=LIGHTS),
        Column("light_boxes", pa.list_(pa.int8()), "index",
               "active Earth-albedo light boxes (0-9); empty unless lightbox"),
        Column("mount", pa.string(), "", "model fixture used: the face of T the target flange holds, "
               "always the side away from the camera", kind="enum", allowed=MOUNTS),
        Column("rail_m", pa.float64(), "m", "commanded rail position of the robot on a rail (TRON: the camera "
               "robot; a facility folder: its one robot on a rail; 0 without a rail)"),
        Column("camera_joints_rad", JOINTS, "rad", "commanded joints of the camera robot in its URDF's order (TRON: "
               "A1..A6, KUKA joint convention); null: the camera stands on a static mount", nullable=True),
        Column("target_joints_rad", JOINTS, "rad", "commanded joints of the target robot in its URDF's order (TRON: "
               "A1..A6, KUKA joint convention); null: the target stands on a static mount", nullable=True),
        *pose("world_from_camee", "nominal, robot world frame K, camera flange C_K"),
        *pose("world_from_targetee", "nominal, robot world frame K, target flange T_K"),
        Column("reachable", pa.bool_(), "", "both robots reach the commands within joint limits"),
        Column("redraws", pa.int32(), "count", "relative poses drawn and discarded as unreachable before this one"),
        Column("sequence_id", pa.string(), "", "plan.mode = trajectory: the rendezvous sequence (W/trajectories.json); "
               "null for independent poses", nullable=True, kind="name"),
        Column("frame", pa.int32(), "index", "frame of the sequence, from 0, in capture order", nullable=True),
        Column("time_s", pa.float64(), "s", "time since the sequence's epoch", nullable=True),
        Column("rtn_servicer_m", VEC3, "m", "the servicer's camera relative to the target's centre of mass, in the "
               "target's orbital RTN frame (radial, along-track, orbit normal), full scale", nullable=True),
        Column("eci_from_target_q", QUAT, "1", "the target's attitude in ECI (mean equator and equinox of date), "
               "Hamilton (w, x, y, z), w >= 0", nullable=True, kind="quaternion"),
        Column("eci_from_cam_q", QUAT, "1", "the camera's attitude in ECI (OpenCV camera frame C)", nullable=True,
               kind="quaternion"),
        Column("sun_eci", VEC3, "1", "unit vector from the Earth's centre to the sun, ECI", nullable=True),
        Column("in_eclipse", pa.bool_(), "", "the target is in the Earth's shadow", nullable=True),
        Column("light_from_sun_rad", pa.float64(), "rad", "angle between the testbed light's direction at the model "
               "(the sun lamp, or the mean of the active light boxes) and the true sun's", nullable=True),
    ),
)

CAPTURES = ManifestSpec(
    "captures",
    "raw measurements of every capture: robot telemetry, motion capture, image",
    (
        _sample_id(),
        Column("session", pa.string(), "", "capture session", kind="enum", allowed=SESSIONS),
        Column("fixture", pa.string(), "", "model fixture (mount) in use: the plan's mount, or 'fixed' for "
               "sessions with one fixture; each fixture has its own flange-to-model offset"),
        Column("image_path", pa.string(), "", "image relative to the workspace: PNG (8 or 16-bit), or the "
               "recorded file itself for float images (EXR)", kind="path"),
        Column("source_image", pa.string(), "", "replay: the recorded image, relative to the source folder; "
               "null for the virtual testbed", nullable=True),
        Column("image_conversion", pa.string(), "", "replay: how a non-PNG image was stored without loss (e.g. "
               "'bmp uint8 3ch 640x480 -> png (lossless)'); null when copied byte for byte or rendered",
               nullable=True),
        *pose("kuka_world_from_camee", "robot telemetry, frame K"),
        *pose("kuka_world_from_targetee", "robot telemetry, frame K"),
        Column("kuka_camera_joints_rad", VEC6, "rad", "camera robot's encoder readings A1-A6 (KUKA signs); null when "
               "not recorded", nullable=True),
        Column("kuka_target_joints_rad", VEC6, "rad", "target robot's encoder readings A1-A6; null when not recorded",
               nullable=True),
        Column("kuka_rail_m", pa.float64(), "m", "the railed robot's reported rail position (TRON: the camera "
               "robot's); null when not recorded", nullable=True),
        Column("capture_time_s", pa.float64(), "s", "exposure time since the session's first capture; null when "
               "not recorded", nullable=True),
        Column("move_s", pa.float64(), "s", "duration of the robots' move from the session's previous capture (the "
               "previous frame of a sequence); null for the first capture or when not recorded", nullable=True),
        *pose("vicon_world_from_camrb", "motion capture, frame V; null when not tracked", nullable=True),
        *pose("vicon_world_from_targetrb", "motion capture, frame V; null when not tracked", nullable=True),
        Column("vicon_camrb_markers", pa.int8(), "count", "markers used for the camera rigid body; null when not "
               "recorded (a ROS bag's PoseStamped carries none)", nullable=True),
        Column("vicon_targetrb_markers", pa.int8(), "count", "markers used for the target rigid body; null when not "
               "recorded", nullable=True),
        Column("vicon_targetrb_used", pa.list_(pa.int8()), "", "which markers the target rigid body's fit used: "
               "indices into the target's markers (W/markers.json, target.toml [mockup] markers); null when not "
               "recorded (fuse then takes motion capture's calibrated sigma as it is)", nullable=True),
        Column("vicon_targetrb_residual_m", pa.float64(), "m", "RMS distance of those markers from the fitted "
               "model, as the system reports it; null when not recorded", nullable=True),
        Column("status", pa.string(), "", "capture outcome", kind="enum", allowed=("ok", "failed")),
    ),
    files=("image_path",),
)

TRUTH = ManifestSpec(
    "truth",
    "hidden ground truth of the virtual testbed; read only by tests, benchmarks and report",
    (
        _sample_id(),
        *pose("cam_from_target", "true pose, mock-up scale"),
        *pose("world_from_camee", "true camera flange pose in K"),
        *pose("world_from_targetee", "true target flange pose in K"),
        Column("fixture_sag_rad", pa.float64(), "rad", "tilt of the model fixture under the model's weight"),
        Column("vicon_camrb_ghost", pa.bool_(), "", "a ghost or mislabelled marker entered the camera body fit"),
        Column("vicon_targetrb_ghost", pa.bool_(), "", "a ghost or mislabelled marker entered the model body fit"),
        Column("maps_path", pa.string(), "", "EXR of the mock-up's depth (m) and part ids at the true pose "
               "(stages/common/ground_truth.py); dataset captures only", kind="path", nullable=True),
    ),
    files=("maps_path",),
)

CALIBRATION_SAMPLES = ManifestSpec(
    "calibration_samples",
    "every calibration capture: detection, PnP pose, and each source's calibrated estimate",
    (
        _sample_id(),
        Column("fixture", pa.string(), "", "model fixture of the capture"),
        Column("corners", pa.int32(), "count", "pattern corners detected"),
        Column("used", pa.bool_(), "", "the capture entered the calibration"),
        Column("reason", pa.string(), "", "why it did not, or why one source left it out (motion capture did not "
               "measure it, an outlier of one source); null when every source used it", nullable=True),
        Column("pnp_rms_px", pa.float64(), "px", "RMS reprojection error of the PnP pose", nullable=True),
        *pose("cam_from_target_cal", "PnP pose of the pattern, mock-up scale", nullable=True),
        *pose("kuka_cam_from_target", "robots' estimate with the calibrated offsets", nullable=True),
        *pose("vicon_cam_from_target", "motion capture's estimate with the calibrated offsets", nullable=True),
        Column("corners_px", pa.list_(pa.list_(pa.float64(), 2)), "px", "the detected pattern corners (M, 2), "
               "distorted image coordinates; null when none were found", nullable=True),
        Column("corners_target_m", pa.list_(pa.list_(pa.float64(), 3)), "m", "the same corners (M, 3) in the "
               "target frame T, mock-up scale: reproject them with a pose to see its error", nullable=True),
    ),
)

POSES = ManifestSpec(
    "poses",
    "per-source and fused camera-from-target poses of the dataset captures",
    (
        _sample_id(),
        *pose("kuka_cam_from_target", "from robot telemetry, mock-up scale"),
        *pose("vicon_cam_from_target", "from motion capture, mock-up scale; null when missing", nullable=True),
        Column("vicon_accepted", pa.bool_(), "", "motion capture passed the rejection test and was fused"),
        Column("reject_reason", pa.string(), "", "why motion capture was rejected; null when accepted", nullable=True),
        *pose("cam_from_target", "fused estimate, mock-up scale"),
        Column("sigma_t_m", VEC3, "m", "1-sigma of the fused translation per camera axis"),
        Column("sigma_r_rad", pa.float64(), "rad", "1-sigma of the fused rotation angle"),
        Column("kuka_sigma_t_m", VEC3, "m", "1-sigma of the robots' translation per camera axis at this capture "
               "(calibrated, grown to it, scaled by the session's factor; on an axis kept from one source, by its own "
               "share of it: fusion.json variance_factor.by_source)", nullable=True),
        Column("vicon_sigma_t_m", VEC3, "m", "1-sigma of motion capture's translation per camera axis at this "
               "capture, its target body's fit there included, scaled as kuka_sigma_t_m is; null when not tracked",
               nullable=True),
    ),
)

LABELS = ManifestSpec(
    "labels",
    "SPEED+ pose labels of the testbed images, full scale",
    (
        _sample_id(),
        Column("filename", pa.string(), "", "image file name in the export"),
        Column("domain", pa.string(), "", "testbed domain", kind="enum", allowed=DOMAINS),
        Column("view", pa.string(), "", "visible side: one of the target's two view names", kind="name"),
        Column("q_vbs2tango_true", QUAT, "1", "rotation of cam_from_target (Tango body into camera), "
               "Hamilton (w, x, y, z)", kind="quaternion"),
        Column("r_Vo2To_vbs_true", VEC3, "m", "translation of cam_from_target, full scale"),
        Column("label_source", pa.string(), "", "which estimate made the label", kind="enum",
               allowed=("fused", "kuka_only")),
        Column("sigma_t_m", VEC3, "m", "1-sigma of the translation per camera axis, full scale"),
        Column("sigma_r_rad", pa.float64(), "rad", "1-sigma of the rotation angle"),
        Column("keypoints_px", KEYPOINTS, "px", KEYPOINTS_TEXT),
        Column("bbox_px", BBOX, "px", "x_min, y_min, x_max, y_max of the projected model"),
    ),
)

_RENDER_COLUMNS = (
    _sample_id(),
    Column("set", pa.string(), "", "twin of a label or training image", kind="enum", allowed=("twin", "train")),
    Column("image_path", pa.string(), "", "8-bit PNG relative to the workspace, in the camera's channels: "
           "grey (mono) or RGB (colour)", kind="path"),
    Column("mask_path", pa.string(), "", "8-bit mask PNG (255: the target covers the pixel centre)", kind="path"),
    Column("ground_truth_path", pa.string(), "", "EXR of per-pixel depth, normals, body coordinates, part index and "
           "linear radiance (stages/common/ground_truth.py); null when render.ground_truth is off", kind="path",
           nullable=True),
    Column("q_vbs2tango_true", QUAT, "1", "rotation of cam_from_target, Hamilton (w, x, y, z)", kind="quaternion"),
    Column("r_Vo2To_vbs_true", VEC3, "m", "translation of cam_from_target, full scale"),
    Column("light_dir_cam", VEC3, "1", "unit direction from the target towards the light, camera frame"),
    Column("irradiance", pa.float64(), "W/m^2", "irradiance of the directional light"),
    Column("earth", pa.bool_(), "", "the Earth is in the background"),
    Column("keypoints_px", KEYPOINTS, "px", KEYPOINTS_TEXT),
    Column("bbox_px", BBOX, "px", "x_min, y_min, x_max, y_max of the mask (pixel centres)"),
    Column("width", pa.int32(), "px", "image width"),
    Column("height", pa.int32(), "px", "image height"),
    Column("seed", pa.int64(), "", "Monte-Carlo seed of this image"),
    Column("spp", pa.int32(), "count", "samples per pixel"),
    Column("seconds", pa.float64(), "s", "render wall time"),
)

RENDERS = ManifestSpec("renders", "synthetic twins of the labelled testbed captures (same pose, aligned light)",
                       _RENDER_COLUMNS, files=("image_path", "mask_path", "ground_truth_path"))

TRAIN = ManifestSpec("train", "the synthetic training set: SO(3)-uniform poses, random lights (SPEED+-like)",
                     _RENDER_COLUMNS, files=("image_path", "mask_path", "ground_truth_path"),
                     made_by="speedplus render --set train")

PREDICTION_DOMAINS = ("synthetic", "lightbox", "sunlamp")

PREDICTIONS = ManifestSpec(
    "predictions",
    "model predictions and SPEED / SPEED+ scores, one row per image (twin or testbed capture)",
    (
        Column("prediction_id", pa.string(), "", "<model>:<crop>:<domain>:<sample_id>"),
        Column("model", pa.string(), "", "the model's name: its file name without .onnx"),
        _sample_id(),
        Column("domain", pa.string(), "", "image domain: synthetic twin or testbed light", kind="enum",
               allowed=PREDICTION_DOMAINS),
        Column("view", pa.string(), "", "visible side: one of the target's two view names", kind="name"),
        Column("light", pa.string(), "", "light set-up of the sample (the twin's light is aligned with it)",
               kind="enum", allowed=LIGHTS),
        Column("crop", pa.string(), "", "full image, oracle box from the label, or self: the model's own crop (a "
               "pass on the whole image, then passes around what it found)", kind="enum",
               allowed=("full", "oracle_box", "self")),
        Column("box_iou", pa.float64(), "1", "self crop: intersection over union of the box the model found with "
               "the label's box", nullable=True),
        Column("pose_found", pa.bool_(), "", "the model's output gave a pose that the image supports (else scored "
               "as the worst case, e_q = pi and e_t = 1: non-finite outputs, and refused poses)"),
        Column("pose_refused", pa.string(), "", "why a decoded pose was refused: the target drawn at it outside the "
               "crop the model saw, or not about the crop's size (stages/common/pose_support.py); null when not",
               nullable=True),
        Column("pnp_method", pa.string(), "", "how the pose was found: AP3P in RANSAC, EPnP on all points "
               "(no consensus), the model's own pose output, or none", kind="enum",
               allowed=("ransac", "all_points", "direct", "none")),
        Column("pnp_inliers", pa.int32(), "count", "keypoints within the RANSAC threshold of the pose (keypoint "
               "models; of a heatmap model, a keypoint is there when one of its peaks is)", nullable=True),
        Column("reprojection_rms_px", pa.float64(), "px", "reprojection RMS of every finite keypoint at the pose "
               "(keypoint models; of a heatmap model, each keypoint at its nearest peak)", nullable=True),
        Column("q_pred", QUAT, "1", "predicted rotation of cam_from_target", nullable=True, kind="quaternion"),
        Column("t_pred", VEC3, "m", "predicted translation of cam_from_target, full scale", nullable=True),
        Column("err_q_rad", pa.float64(), "rad", "2 arccos |<q_pred, q_true>| (pi when no pose)"),
        Column("err_t_norm", pa.float64(), "1", "|t_true - t_pred| / |t_true| (1 when no pose)"),
        Column("score_speed", pa.float64(), "1", "SPEED (2019) score, err_q_rad + err_t_norm"),
        Column("score_speedplus", pa.float64(), "1", "SPEED+ (2021) score, terms zeroed under thresholds"),
        Column("score_speed_seeds", pa.list_(pa.float64()), "1", "SPEED score of the pose decoded under each RANSAC "
               "seed (evaluate.ransac_seeds; the first is score_speed): Table 2 averages them and its intervals "
               "draw among them", nullable=True),
        Column("score_speedplus_seeds", pa.list_(pa.float64()), "1", "SPEED+ score under each seed, as "
               "score_speed_seeds", nullable=True),
        Column("seconds", pa.float64(), "s", "inference time of this image (its share of the batch)"),
    ),
    key="prediction_id",
)

SCORES = ManifestSpec(
    "scores",
    "the paper's Table 2: mean scores per domain and configuration (view x light)",
    (
        Column("group", pa.string(), "", "<model>/<crop>/<domain>/<view>/<light>, 'all' for every value"),
        Column("model", pa.string(), "", "the model's name"),
        Column("crop", pa.string(), "", "full, oracle_box or self (see predictions)", kind="enum",
               allowed=("full", "oracle_box", "self")),
        *_configuration_columns(),
        Column("count", pa.int64(), "count", "images"),
        Column("pose_found_share", pa.float64(), "1", "share of images that gave a pose the image supports; the "
               "others are scored as the worst case, e_q = pi and e_t = 1"),
        Column("refused_share", pa.float64(), "1", "share of images whose decoded pose was refused (see "
               "predictions.pose_refused)"),
        Column("mean_score_speed", pa.float64(), "1", "mean SPEED score (of each image's mean over its RANSAC seeds)"),
        Column("mean_score_speed_low", pa.float64(), "1", "lower end of its 95% interval: BCa bootstrap over the "
               "images, stratified by configuration (stages/evaluate/intervals.py)"),
        Column("mean_score_speed_high", pa.float64(), "1", "upper end of that interval"),
        Column("median_score_speed", pa.float64(), "1", "median SPEED score (of each image's mean over its seeds)"),
        Column("mean_score_speedplus", pa.float64(), "1", "mean SPEED+ score"),
        Column("mean_score_speedplus_low", pa.float64(), "1", "lower end of its 95% interval (as for SPEED)"),
        Column("mean_score_speedplus_high", pa.float64(), "1", "upper end of that interval"),
        Column("failure_share", pa.float64(), "1", "share of images whose pose misses: rotation error over 10 deg "
               "or translation error over 10% of the range (no pose included)"),
        Column("mean_err_q_deg", pa.float64(), "deg", "mean rotation error"),
        Column("median_err_q_deg", pa.float64(), "deg", "median rotation error"),
        Column("mean_err_t_norm", pa.float64(), "1", "mean normalised translation error"),
        Column("mean_box_iou", pa.float64(), "1", "self crop: mean intersection over union of the found box with "
               "the label's box", nullable=True),
    ),
    key="group",
)

COMPARISONS = ManifestSpec(
    "comparisons",
    "each model against the reference model on the same images: the mean of the paired differences of their "
    "scores (model minus reference; below zero, the model scores lower, which is better), per domain and "
    "configuration",
    (
        Column("group", pa.string(), "", "<model>/<crop>/<reference>/<reference_crop>/<domain>/<view>/<light>"),
        Column("model", pa.string(), "", "the model compared"),
        Column("crop", pa.string(), "", "its crop (see predictions)", kind="enum",
               allowed=("full", "oracle_box", "self")),
        Column("reference", pa.string(), "", "the model it is compared with: 'reference' when scored, else the "
               "first of evaluate.models"),
        Column("reference_crop", pa.string(), "", "the reference's crop: the model's own when the reference has "
               "it, else the reference's first", kind="enum", allowed=("full", "oracle_box", "self")),
        *_configuration_columns(),
        Column("count", pa.int64(), "count", "images scored by both"),
        Column("mean_difference_speed", pa.float64(), "1", "mean of the per-image SPEED score differences"),
        Column("mean_difference_speed_low", pa.float64(), "1", "lower end of its 95% paired-bootstrap interval, "
               "stratified by configuration (stages/evaluate/intervals.py)"),
        Column("mean_difference_speed_high", pa.float64(), "1", "upper end of that interval"),
        Column("mean_difference_speedplus", pa.float64(), "1", "mean of the per-image SPEED+ score differences"),
        Column("mean_difference_speedplus_low", pa.float64(), "1", "lower end of its 95% interval"),
        Column("mean_difference_speedplus_high", pa.float64(), "1", "upper end of that interval"),
        Column("better_share", pa.float64(), "1", "share of the images where the model's SPEED score (mean over "
               "its seeds) is lower"),
    ),
    key="group",
)

TRACKS = ManifestSpec(
    "tracks",
    "plan.mode = trajectory: a navigation filter fed each model's per-frame poses, per sequence and domain, "
    "against the per-frame scores (stages/common/tracking.py)",
    (
        Column("track_id", pa.string(), "", "<model>:<crop>:<domain>:<sample_id>"),
        Column("model", pa.string(), "", "the model's name"),
        Column("crop", pa.string(), "", "full, oracle_box or self (see predictions)", kind="enum",
               allowed=("full", "oracle_box", "self")),
        Column("domain", pa.string(), "", "synthetic twins, or the testbed's frames (either light) in frame order",
               kind="enum", allowed=("synthetic", "testbed")),
        Column("sequence_id", pa.string(), "", "the sequence (W/trajectories.json)", kind="name"),
        Column("frame", pa.int32(), "index", "frame of the sequence"),
        Column("time_s", pa.float64(), "s", "time since the sequence's epoch"),
        _sample_id(),
        Column("measured", pa.bool_(), "", "the model gave a pose for this frame"),
        Column("rotation_used", pa.bool_(), "", "the attitude filter took the measurement (innovation gate passed)"),
        Column("position_used", pa.bool_(), "", "the position filter took the measurement"),
        Column("q_track", QUAT, "1", "tracked rotation of cam_from_target; null before a first measurement",
               nullable=True, kind="quaternion"),
        Column("t_track", VEC3, "m", "tracked translation of cam_from_target, full scale", nullable=True),
        Column("err_q_rad", pa.float64(), "rad", "tracked rotation error against the label (pi when none)"),
        Column("err_t_norm", pa.float64(), "1", "tracked |t_true - t_track| / |t_true| (1 when none)"),
        Column("score_speed", pa.float64(), "1", "tracked SPEED score"),
        Column("frame_score_speed", pa.float64(), "1", "the same image's per-frame SPEED score (predictions)"),
    ),
    key="track_id",
)

_EXPORT_COLUMNS = (
    Column("export_id", pa.string(), "", "<set>/<sample_id>: one exported image", kind="value"),
    _sample_id(),
    Column("set", pa.string(), "", "which images: the labelled testbed captures, their twins or the training set",
           kind="enum", allowed=("testbed", "twins", "train")),
    Column("domain", pa.string(), "", "testbed light set-up, or synthetic for the training set", kind="enum",
           allowed=(*DOMAINS, "synthetic")),
    Column("file", pa.string(), "", "the exported image, relative to the export folder (never leaves it)",
           kind="path"),
    Column("source_image", pa.string(), "", "the workspace image it was made from, relative to W", kind="path"),
)
EXPORT_SPEEDPLUS = ManifestSpec("export_speedplus", "images written by export --format speedplus", _EXPORT_COLUMNS,
                                key="export_id")
EXPORT_BOP = ManifestSpec("export_bop", "images written by export --format bop", _EXPORT_COLUMNS, key="export_id")
EXPORT_SHIRT = ManifestSpec("export_shirt", "images written by export --format shirt (sequences)", _EXPORT_COLUMNS,
                            key="export_id")
EXPORT_ROBOT = ManifestSpec(
    "export_robot",
    "waypoints written by export --format robot: each robot's commands, in the order its program runs them",
    (
        Column("waypoint_id", pa.string(), "", "<robot>/<step, 6 digits>", kind="value"),
        Column("robot", pa.string(), "", "the facility's robot", kind="name"),
        Column("step", pa.int32(), "index", "place in the robot's program, from 1"),
        _sample_id(),
        Column("session", pa.string(), "", "capture session", kind="enum", allowed=SESSIONS),
        Column("capture", pa.bool_(), "", "the robot waits here for the logger to take an image"),
        Column("joints_rad", pa.list_(pa.float64()), "rad", "commanded joints in the URDF's order (radians; the "
               "program files carry the controller's units)"),
        Column("rail_m", pa.float64(), "m", "commanded rail position; null for a robot without a rail", nullable=True),
    ),
    key="waypoint_id",
)
EXPORT_SESSION = ManifestSpec(
    "export_session",
    "images written by export --format session: the captures as a lab's logger writes them (replay reads them)",
    (
        Column("export_id", pa.string(), "", "<session>/<sample_id>: one exported capture", kind="value"),
        _sample_id(),
        Column("session", pa.string(), "", "capture session", kind="enum", allowed=SESSIONS),
        Column("file", pa.string(), "", "the exported image, relative to the export folder (never leaves it)",
               kind="path"),
        Column("source_image", pa.string(), "", "the workspace image it was copied from, relative to W", kind="path"),
    ),
    key="export_id",
)

EXPORT_ROSBAG = ManifestSpec(
    "export_rosbag",
    "captures written by export --format rosbag: a ROS 2 bag (MCAP) that replay --format rosbag reads back",
    (
        Column("export_id", pa.string(), "", "<session>/<sample_id>: one exported capture", kind="value"),
        _sample_id(),
        Column("session", pa.string(), "", "capture session", kind="enum", allowed=SESSIONS),
        Column("stamp_ns", pa.int64(), "ns", "the capture's stamp in the bag (its image's header and its trigger)"),
        Column("source_image", pa.string(), "", "the workspace image in the bag, relative to W", kind="path"),
    ),
    key="export_id",
)

MODELS = ManifestSpec(
    "models",
    "models trained by train-reference, with their held-out synthetic accuracy",
    (
        Column("model", pa.string(), "", "model name"),
        Column("path", pa.string(), "", "the ONNX file, relative to W (its model card: the same path, .json)",
               kind="path"),
        Column("sha256", pa.string(), "", "SHA-256 of the ONNX file"),
        Column("training_images", pa.int64(), "count", "synthetic images trained on"),
        Column("held_out_images", pa.int64(), "count", "synthetic images held out"),
        Column("held_out_mean_speed_score", pa.float64(), "1", "mean SPEED score on the held-out images "
               "(null for the detector)", nullable=True),
        Column("held_out_median_rotation_error_deg", pa.float64(), "deg", "median rotation error, held out "
               "(null for the detector)", nullable=True),
        Column("train_seconds", pa.float64(), "s", "training wall time (this run's share when resumed)"),
        Column("held_out_median_box_iou", pa.float64(), "1", "the detector's median box IoU on the held-out "
               "images (null for keypoint models)", nullable=True),
    ),
    key="model",
    files=("path",),
)

MANIFESTS: dict[str, ManifestSpec] = {
    spec.name: spec for spec in (PLAN, CAPTURES, TRUTH, CALIBRATION_SAMPLES, POSES, LABELS, RENDERS, TRAIN,
                                  PREDICTIONS, SCORES, COMPARISONS, TRACKS, EXPORT_SPEEDPLUS, EXPORT_BOP, EXPORT_SHIRT,
                                  EXPORT_ROBOT, EXPORT_SESSION, EXPORT_ROSBAG, MODELS)
}
