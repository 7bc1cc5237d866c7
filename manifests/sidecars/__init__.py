"""Typed JSON files of the workspace (docs/architecture.md section 4). Each has a dataclass
with ``to_json``/``from_json``, a version, validation that names the file and the key, one
path on the ``Workspace``, and one reader and one writer:

| file | written by | read by |
|---|---|---|
| ``session.json`` | acquire | calibrate, fuse, label, render (mock-up scale) |
| ``calibration.json`` | calibrate | fuse, label, render, evaluate, report, export |
| ``fusion.json`` | fuse | report, benchmarks |
| ``truth.json`` | acquire (virtual only) | tests and benchmarks, never a stage after acquire |
| ``markers.json`` | acquire (virtual only) | tests; the lab (where the virtual markers sat) |
| ``trajectories.json`` | plan (trajectory mode) | export (SHIRT), evaluate (tracking), tests |
"""

from manifests.sidecars.base import Pose, SidecarError
from manifests.sidecars.calibration import (
    CALIBRATION_VERSION,
    OFFSET_KEYS,
    ArmKinematics,
    Calibration,
    FixtureCompliance,
    Intrinsics,
    OffsetUncertainty,
    SessionSources,
    SigmaRecord,
    SolverRecord,
    SourceCalibration,
    read_calibration,
    write_calibration,
)
from manifests.sidecars.fusion import FUSION_VERSION, FusionRecord, read_fusion, write_fusion
from manifests.sidecars.markers import MARKERS_VERSION, MarkersRecord, read_markers, write_markers
from manifests.sidecars.screening import MotionFit, Screening
from manifests.sidecars.session import (
    BACKENDS,
    FORMATS,
    SESSION_VERSION,
    SOURCES,
    Session,
    SessionCamera,
    read_session,
    write_session,
)
from manifests.sidecars.table1 import METRIC_KEYS, METRIC_KINDS, Baseline, Folds, FusedColumn, Metrics, MetricSet
from manifests.sidecars.trajectories import (
    TRAJECTORIES_VERSION,
    SequenceRecord,
    TrajectoriesRecord,
    read_trajectories,
    write_trajectories,
)
from manifests.sidecars.truth import TRUTH_VERSION, TruthRecord, read_truth, write_truth

__all__ = [
    "BACKENDS", "CALIBRATION_VERSION", "FORMATS", "FUSION_VERSION", "MARKERS_VERSION", "METRIC_KEYS", "METRIC_KINDS",
    "OFFSET_KEYS", "Baseline", "Folds", "FusedColumn", "MetricSet", "Metrics", "MotionFit", "Screening",
    "SessionSources", "SolverRecord",
    "SESSION_VERSION", "SOURCES", "TRAJECTORIES_VERSION", "TRUTH_VERSION",
    "ArmKinematics", "Calibration", "FixtureCompliance", "FusionRecord", "Intrinsics", "MarkersRecord",
    "Pose", "SequenceRecord", "Session", "SessionCamera", "SidecarError", "SigmaRecord", "SourceCalibration",
    "OffsetUncertainty",
    "TrajectoriesRecord", "TruthRecord",
    "read_calibration", "read_fusion", "read_markers", "read_session", "read_trajectories", "read_truth",
    "write_calibration", "write_fusion", "write_markers", "write_session", "write_trajectories", "write_truth",
]
