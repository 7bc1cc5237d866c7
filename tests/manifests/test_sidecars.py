"""The workspace's JSON files as typed, versioned files: one writer, one reader, errors naming file and key."""

import json

import pytest

from manifests import Workspace
from manifests.sidecars import (
    ArmKinematics,
    Calibration,
    FixtureCompliance,
    Folds,
    FusedColumn,
    FusionRecord,
    Intrinsics,
    Metrics,
    MetricSet,
    MotionFit,
    Pose,
    Screening,
    Session,
    SessionCamera,
    SessionSources,
    SidecarError,
    SigmaRecord,
    SolverRecord,
    SourceCalibration,
    TruthRecord,
    read_calibration,
    read_fusion,
    read_session,
    read_truth,
    write_calibration,
    write_fusion,
    write_session,
    write_truth,
)
from manifests.sidecars.arm_fit import ChainFit, ResidualNoise, RobotCorrection
from manifests.sidecars.truth import POSE_KEYS, HolderTruth

SESSION = Session("replay", "handeye", ("kuka",), SessionCamera(1928, 1208, None, None),
                  {"kind": "chessboard", "size": [28, 17], "square_m": 0.02}, "/data/kuka",
                  {"camee": "flange", "targetee": "robot base"})


def test_a_session_survives_its_file(tmp_path):
    workspace = Workspace(tmp_path)
    write_session(workspace, SESSION)
    assert read_session(workspace) == SESSION
    assert json.loads(workspace.session_path.read_text())["version"] == 1


@pytest.mark.parametrize("change, message", [
    ({"version": None}, r"version None, this program reads version 1 .*; rerun acquire with --force"),
    ({"backend": "robot"}, r"key backend: expected virtual or replay, got 'robot'"),
    ({"sources": ["vicon"]}, r"key sources: expected a list starting with \"kuka\""),
    ({"camera": {"width": 0, "height": 10}}, r"key camera.width: expected an integer >= 1, got 0"),
    ({"mockup_scale": "half"}, r"key mockup_scale: expected a positive number, got 'half'"),
    ({"extra": 1}, r"unknown key\(s\) extra"),
])
def test_a_malformed_session_names_the_file_and_key(tmp_path, change, message):
    workspace = Workspace(tmp_path)
    workspace.session_path.write_text(json.dumps({**SESSION.to_json(), **change}))
    with pytest.raises(SidecarError, match=f"session.json: {message}"):
        read_session(workspace)


def test_missing_or_corrupt_sessions_say_what_to_rerun(tmp_path):
    workspace = Workspace(tmp_path)
    with pytest.raises(SidecarError, match="session.json: missing; rerun acquire with --force"):
        read_session(workspace)
    workspace.session_path.write_text('{"version": 1, "backend": ')
    with pytest.raises(SidecarError, match="session.json: not valid JSON .*; rerun acquire with --force"):
        read_session(workspace)


# ----------------------------------------------------------------- calibration, fusion, truth
POSE = Pose((0.5, 0.5, -0.5, 0.5), (0.1, -0.2, 0.3))
METRIC = MetricSet((1e-4, 5e-5), (3e-4, 1e-4), (0.2, 0.1))
METRICS = Metrics(METRIC, METRIC, Folds(40, 5, (), True), None)
ON_BOTH = Metrics(METRIC, METRIC, Folds(40), METRIC)
SCREENING = Screening(("cal000001",), (), ("cal000002",), 58, MotionFit(
    ("cal000003",), 0.0088, 0.59, 0.0057, 0.0014, 0.995, 0.019, 0.021, 0.01, 0.01))
PATTERN = {"kind": "charuco", "size": [11, 11], "square_m": 0.03, "marker_m": 0.022, "dictionary": "DICT_5X5_100"}


def source(name: str, kinematics: ArmKinematics) -> SourceCalibration:
    compliance = FixtureCompliance(True, "spread", {"minus_x": (0.0, 1e-3, 0.0), "plus_x": (1e-3, 0.0, 0.0)},
                                   {"minus_x": (0.1, -0.2, 0.0, 0.05, 0.0, 0.0), "plus_x": (0.0,) * 6}, 1e-3, 2e-3,
                                   {"minus_x": 4e-4, "plus_x": 0.0})
    return SourceCalibration(name, POSE, {"minus_x": POSE, "plus_x": Pose((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.1))},
                             compliance, kinematics, SigmaRecord((1e-5, 2e-5, 3e-5), 1e-4, 5e-5), 60, ("cal000003",),
                             METRICS)


CALIBRATION = Calibration(
    Intrinsics(((1500.0, 0.0, 480.0), (0.0, 1500.0, 300.0), (0.0, 0.0, 1.0)), (-0.2, 0.5, 0.0, 0.0, -0.1), 960, 600,
               0.08, True),
    source("kuka", ArmKinematics(True, "encoders", ChainFit(
        (RobotCorrection("slide", "camera", ("a1",), (1e-4,), ((0.0, 1e-4, 0.0, 1e-3, 0.0, 0.0), (0.0,) * 6), 2e-5,
                         (1e-6,), (2e-4,)),),
        ("slide.a1.zero", *(f"slide.{frame}.{axis}" for frame in ("a1.origin", "flange")
                            for axis in ("rx", "ry", "rz", "x", "y", "z")), "slide.rail.scale", "slide.a1.compliance",
         "slide.a1.lost_motion"),
        {"slide.flange.z": "a combination of the hand-eye offsets"}, {"slide.rail.scale": 0.9}, ("minus_x", "plus_x"),
        True, (0.0,) * 17, tuple(tuple(float(i == j) for j in range(17)) for i in range(17)), (1e-3,) * 16,
        15.0, ResidualNoise(1.1, 2e-4, 5e-5)))),
    source("vicon", ArmKinematics(False, "motion capture tracks the model itself")),
    0.9, (0.8, 0.8, 0.005), (0.0, 0.0, 1.0),
    FusedColumn(55, ON_BOTH, {"kuka": ON_BOTH, "vicon": ON_BOTH}),
    SigmaRecord((6e-4, 5e-4, 2e-4), 2e-3, None), SolverRecord("frobenius", 5, PATTERN, ("minus_x", "plus_x")),
    SessionSources("virtual", ("kuka", "vicon")), SCREENING)


def test_a_calibration_survives_its_file_with_the_offsets_named_by_their_frames(tmp_path):
    workspace = Workspace(tmp_path)
    write_calibration(workspace, CALIBRATION)
    assert read_calibration(workspace) == CALIBRATION
    stored = json.loads(workspace.calibration_path.read_text())
    assert stored["version"] == 7
    assert stored["kuka"]["cam_from_camee"] == {"q": [0.5, 0.5, -0.5, 0.5], "t": [0.1, -0.2, 0.3]}
    assert "target_from_targetrb_by_fixture" in stored["vicon"] and "cam_from_camee" not in stored["vicon"]
    # the first fixture's offset stands for the source's target offset
    assert stored["vicon"]["target_from_targetrb"] == stored["vicon"]["target_from_targetrb_by_fixture"]["minus_x"]


def _edit(data: dict, path: str, value) -> dict:
    data = json.loads(json.dumps(data))  # a copy: to_json shares the records' metric dicts
    keys = path.split(".")
    node = data
    for key in keys[:-1]:
        node = node[key]
    if value is KeyError:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return data


@pytest.mark.parametrize("path, value, message", [
    ("version", KeyError, r"version None, this program reads version 7 .*rerun calibrate with --force"),
    ("kuka.fixture_compliance.play_rad_by_fixture.minus_x", "x",
     "key kuka.fixture_compliance.play_rad_by_fixture.minus_x: expected"),
    ("kuka.fixture_compliance.play_rad_by_fixture.minus_x", -1e-4,
     "key kuka.fixture_compliance.play_rad_by_fixture.minus_x: expected a play of at least 0 rad"),
    ("kuka.fixture_compliance.anisotropy_by_fixture.minus_x", [0.1, 0.2],
     "key kuka.fixture_compliance.anisotropy_by_fixture.minus_x: expected"),
    ("kuka.cam_from_camee.q", [1.0, 0.0, 0.0, 0.1], r"key kuka.cam_from_camee.q: expected a unit quaternion"),
    ("kuka.cam_from_camee", KeyError, r"key kuka.cam_from_camee missing"),
    ("intrinsics.K", [[1, 0, 0], [0, 1, 0]], r"key intrinsics.K: expected a 3 x 3 list"),
    ("intrinsics.dist", [0.0, "x", 0, 0, 0], r"key intrinsics.dist: expected a list of 5 finite numbers"),
    ("vicon.sigma_r_rad", float("nan"), r"key vicon.sigma_r_rad: expected a finite number"),
    ("kuka.fixture_compliance.k_rad_by_fixture.plus_x", [0.0], r"key kuka.fixture_compliance.k_rad_by_fixture."
                                                               r"plus_x: expected a list of 3"),
    ("kuka.arm_kinematics.chains.covariance", [[1.0]], r"key kuka.arm_kinematics.chains.covariance: expected a "
                                                       r"17 x 17"),
    ("kuka.arm_kinematics.chains.robots", KeyError, r"key kuka.arm_kinematics.chains.robots missing"),
    ("kuka.arm_kinematics.chains.parameter_names", ["slide.a1.zero"],
     r"key kuka.arm_kinematics.chains.parameter_names: .*16 names"),
    ("kuka.arm_kinematics.fit", {}, r"unknown key\(s\) in kuka.arm_kinematics fit"),
    ("kuka.arm_kinematics.chains.residual_noise.translation_sigma_m", -1e-5,
     r"key kuka.arm_kinematics.chains.residual_noise.translation_sigma_m: expected a 1-sigma >= 0"),
    ("kuka.arm_kinematics.chains.residual_noise.pnp_scale", 0.0,
     r"key kuka.arm_kinematics.chains.residual_noise.pnp_scale: expected"),
    ("vicon.metrics.in_sample.E_T_m", [0.1], r"key vicon.metrics.in_sample.E_T_m: expected a list of 2"),
    ("kuka.metrics.cross_validation.undetermined_folds", [6], r"key kuka.metrics.cross_validation."
                                                              r"undetermined_folds: expected a list of fold numbers"),
    ("kuka.metrics.cross_validated", None, r"key kuka.metrics.cross_validated: expected an object"),
    ("fused.sources_on_the_same_samples.vicon.truth.E_R_rad", "x",
     r"key fused.sources_on_the_same_samples.vicon.truth.E_R_rad: expected a list of 2"),
    ("solver.fixtures", "minus_x", r"key solver.fixtures: expected a list of fixture names"),
    ("session.sources", ["kuka", "ros"], r"key session.sources: expected a list of kuka or vicon"),
    ("screening.motions.pitch_scale", "1", r"key screening.motions.pitch_scale: expected a number or null"),
    ("screening.corner_order.undecided", [3], r"key screening.corner_order.undecided: expected a list of sample"),
    ("rejection", None, r"keys vicon, fused and rejection: all null or all present"),
    ("kuka.pose", 1, r"unknown key\(s\) in kuka pose"),
    ("kuka.samplez", 1, r"unknown key\(s\) in kuka samplez \(did you mean samples\?\)"),
])
def test_a_malformed_calibration_names_the_file_and_the_key(tmp_path, path, value, message):
    workspace = Workspace(tmp_path)
    workspace.calibration_path.write_text(json.dumps(_edit(CALIBRATION.to_json(), path, value)))
    with pytest.raises(SidecarError, match=f"calibration.json: {message}") as raised:
        read_calibration(workspace)
    assert str(raised.value).endswith("rerun calibrate with --force")


def test_missing_calibration_says_to_run_calibrate(tmp_path):
    with pytest.raises(SidecarError, match="calibration.json: missing; rerun calibrate with --force"):
        read_calibration(Workspace(tmp_path))


def test_fusion_and_truth_files_survive_and_refuse_what_is_malformed(tmp_path):
    workspace = Workspace(tmp_path)
    record = FusionRecord((1.02, 1.01, 1.6), 1.29, 44, "robust spread", 1.96, ("fused", "fused", "kuka"),
                          "z: factor 1.60 > 1.32", (1.1, 1.01, 1.6), (0.0021, -0.0004, 0.0011), (3e-4, 3e-4, 1e-4),
                          ("vicon", "vicon", "kuka"), "median on 44 captures", 6.1e-4, "marker noise 0.61 mm",
                          kuka_t=(1.02, 1.01, 1.08), vicon_t=(1.02, 1.01, 1.71))
    write_fusion(workspace, record)
    assert read_fusion(workspace) == record
    workspace.fusion_path.write_text(json.dumps(_edit(record.to_json(), "sigmas.marker_sigma_m", -1.0)))
    with pytest.raises(SidecarError, match=r"fusion.json: key sigmas.marker_sigma_m"):
        read_fusion(workspace)
    workspace.fusion_path.write_text(json.dumps(_edit(record.to_json(), "variance_factor.t", [1.0, 0.0, 1.0])))
    with pytest.raises(SidecarError, match=r"fusion.json: key variance_factor.t: expected three positive factors"):
        read_fusion(workspace)
    workspace.fusion_path.write_text(json.dumps(_edit(record.to_json(), "variance_factor.measured_t", [1.0, 1.0])))
    with pytest.raises(SidecarError, match=r"fusion.json: key variance_factor.measured_t"):
        read_fusion(workspace)
    workspace.fusion_path.write_text(json.dumps(_edit(record.to_json(), "variance_factor.by_source.vicon",
                                                      [1.0, -1.0, 1.0])))
    with pytest.raises(SidecarError, match=r"key variance_factor.by_source.vicon: expected three positive"):
        read_fusion(workspace)
    workspace.fusion_path.write_text(json.dumps(_edit(record.to_json(), "axes.sources", ["fused", "pnp", "kuka"])))
    with pytest.raises(SidecarError, match=r"fusion.json: key axes.sources: expected a list of three of fused"):
        read_fusion(workspace)
    workspace.fusion_path.write_text(json.dumps(_edit(record.to_json(), "offset.removed_from", ["vicon", "pnp"])))
    with pytest.raises(SidecarError, match=r"fusion.json: key offset.removed_from: expected a list of three of kuka"):
        read_fusion(workspace)

    arm = {"name": "KR 16", "source": "datasheet", "a1": 0.26, "a2": -0.035, "b": 0.0, "c1": 0.675, "c2": 0.68,
           "c3": 0.67, "c4": 0.158, "offsets": [0.0] * 6, "signs": [1] * 6, "lower": [-3.0] * 6, "upper": [3.0] * 6}
    truth = TruthRecord(arm, arm, (0.0,) * 6, (1e-3,) * 6, 1.0001, dict.fromkeys(POSE_KEYS, POSE),
                        {"minus_x": POSE}, {"vicon_scale": 1.0003})
    write_truth(workspace, truth)
    assert read_truth(workspace) == truth
    workspace.truth_path.write_text(json.dumps(_edit(truth.to_json(), "camera_arm.a1", "long")))
    with pytest.raises(SidecarError, match=r"truth.json: key camera_arm.a1: expected a finite number"):
        read_truth(workspace)
    # a facility folder's: its robots' truth instead of TRON's arms
    arm_truth = HolderTruth("ur10", (1e-4,) * 6, (POSE,) * 7, POSE, 1.0, None)
    on_facility = TruthRecord(None, None, None, None, None,
                              {k: None if k.endswith("base_error") else POSE for k in POSE_KEYS}, {"minus_x": POSE},
                              {"vicon_scale": 1.0}, {"camera": arm_truth, "target": HolderTruth(None, (), (), POSE,
                                                                                                1.0, None)})
    write_truth(workspace, on_facility)
    assert read_truth(workspace) == on_facility
    workspace.truth_path.write_text(json.dumps(_edit(on_facility.to_json(), "rail_scale", 1.0)))
    with pytest.raises(SidecarError, match=r"truth.json: key rail_scale: expected null on a facility folder"):
        read_truth(workspace)
    workspace.truth_path.write_text(json.dumps(_edit(on_facility.to_json(), "facility.camera.joint_origin_errors",
                                                     [POSE.to_json()] * 6)))
    with pytest.raises(SidecarError, match=r"key facility.camera.joint_origin_errors: expected one pose per joint"):
        read_truth(workspace)
