"""Label accuracy on the default profile against the virtual testbed's hidden truth, with
its unmodelled errors on: the testbed is as hard as TRON with the paper's method, the
calibrated robots are about as good as real calibrated arms, fusion beats each source on
the calibration samples and the paper's fused figures, and the dataset labels are scored
against the SPEED+ thresholds. `python -m bench accuracy` prints the same figures;
`python -m bench honesty` the same over independent facilities."""

import json
import shutil

import numpy as np
import pytest

from bench.accuracy import PAPERS_METHOD
from manifests import Workspace, read_manifest
from stages.common import geometry as g
from stages.common.scores import ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD
from stages.common.tables import PAPER
from tests.conftest import speedplus

#: the SPEED+ label precision, defined once (stages/common/scores.py)
SPEEDPLUS_ROTATION_RAD, SPEEDPLUS_TRANSLATION = ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD


def labelled_copy(default_acquisition, root, *settings):
    shutil.copytree(default_acquisition.root, root)
    args = [a for s in settings for a in ("--set", s)]
    result = speedplus("run", "--workspace", str(root), "--until", "label", *args)
    assert result.returncode == 0, result.stderr
    return Workspace(root)


@pytest.fixture(scope="module")
def labelled(default_labelled):
    return default_labelled


@pytest.fixture(scope="module")
def rigid(default_acquisition, tmp_path_factory):
    """The paper's method: nominal arms, rigid fixtures, calibrated sigmas as they are."""
    return labelled_copy(default_acquisition, tmp_path_factory.mktemp("rigid") / "w", *PAPERS_METHOD)


def calibration(ws):
    return json.loads((ws.root / "calibration.json").read_text())


def test_the_testbed_is_as_hard_as_tron_for_the_papers_method(rigid):
    c = calibration(rigid)
    to_paper_px = 1920 / c["intrinsics"]["width"]
    for source in ("kuka", "vicon"):
        metric = c[source]["metrics"]["in_sample"]
        for index, (key, scale) in enumerate((("E_T_m", 1000), ("E_R_rad", np.degrees(1)), ("E_p_px", to_paper_px))):
            ratio = metric[key][0] * scale / PAPER[source][index][0]
            assert 0.5 <= ratio <= 2.0, (source, key, ratio)


def test_compliance_and_arm_kinematics_remove_most_of_the_robots_error(labelled, rigid):
    kuka = calibration(labelled)["kuka"]
    assert kuka["fixture_compliance"]["estimated"], kuka["fixture_compliance"]["why"]
    assert 0.001 < kuka["fixture_compliance"]["tilt_rad_mean"] < 0.02  # tenths of a degree
    assert kuka["arm_kinematics"]["estimated"], kuka["arm_kinematics"]["why"]
    papers = calibration(rigid)["kuka"]
    assert not papers["fixture_compliance"]["estimated"] and not papers["arm_kinematics"]["estimated"]
    for kind in ("cross_validated", "truth"):
        assert kuka["metrics"][kind]["E_R_rad"][0] < 0.2 * papers["metrics"][kind]["E_R_rad"][0]
        assert kuka["metrics"][kind]["E_T_m"][0] < 0.2 * papers["metrics"][kind]["E_T_m"][0]
    # TRON's arms are fitted from their URDF, and written back for a controller
    robots = {robot["role"]: robot for robot in kuka["arm_kinematics"]["chains"]["robots"]}
    assert sorted(robots) == ["camera", "target"]
    assert all((labelled.root / "robots" / f"{robot['robot']}.urdf").is_file() for robot in robots.values())
    # the arms' corrections are of the size the lab's tolerances allow, not fitted noise
    assert np.abs(np.concatenate([robot["zero_offsets"] for robot in robots.values()])).max() < 0.01
    # A2's gearbox compliance is found, of the order of KR-class joints (1e5-1e6 N m/rad)
    for robot in robots.values():
        assert 3e-7 < robot["compliance_rad_per_nm"][robot["joints"].index("joint_a2")] < 1e-5
    # every joint's lost motion is fitted on the flank its last move chose (the captures'
    # times order the moves), and some of it is found: a wrist's rating is 2 arcmin
    lost = np.concatenate([robot["lost_motion_rad"] for robot in robots.values()])
    assert np.abs(lost).max() > 1e-4 and np.abs(lost).max() < 2e-3
    # with thermal drift, the mount's micro-slip and the flanks of the session's first capture
    # left in the arms, the calibrated robots are about as good as real calibrated arms (a
    # tenth of a mm on the board's captures), not better than the PnP noise would allow
    assert 0.03e-3 < kuka["metrics"]["truth"]["E_T_m"][0] < 1e-3
    # the fit weighed each pose by its PnP covariance, which the rendered corners' noise
    # holds within a factor of 2 in sigma, plus what the arms' model leaves out: under the
    # robots' own error against the truth, not all of it put on the model
    noise = kuka["arm_kinematics"]["chains"]["residual_noise"]
    assert 0.25 < noise["pnp_scale"] < 4.0, noise
    assert 0.0 < noise["translation_sigma_m"] < kuka["metrics"]["truth"]["E_T_m"][0], noise
    assert 0.0 < noise["rotation_sigma_rad"] < kuka["metrics"]["truth"]["E_R_rad"][0], noise


def test_fused_calibration_beats_the_papers_fused_figures_and_is_never_worse_than_a_source(labelled):
    fused = calibration(labelled)["fused"]
    truth = fused["metrics"]["truth"]
    assert truth["E_T_m"][0] * 1000 < PAPER["fused"][0][0]
    assert np.degrees(truth["E_R_rad"][0]) < PAPER["fused"][1][0]
    # on the samples both sources measured: with the arms calibrated the robots are some 20x
    # better than motion capture, and fusion must not spoil them (docs/accuracy.md)
    same = fused["sources_on_the_same_samples"]
    for key in ("E_T_m", "E_R_rad"):
        assert truth[key][0] <= 1.01 * same["kuka"]["truth"][key][0]
        assert truth[key][0] < 0.5 * same["vicon"]["truth"][key][0]


def dataset_errors(ws):
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    scale = json.loads(ws.session_path.read_text())["mockup_scale"]
    labels = {r["sample_id"]: r for r in read_manifest(ws, "labels").to_pylist()}
    out = {"rotation": [], "position": [], "inside": [], "kuka": [], "vicon": [], "fused": []}
    for pose in read_manifest(ws, "poses").to_pylist():
        true = g.transform_from_qt(truth[pose["sample_id"]]["cam_from_target_q"],
                                   truth[pose["sample_id"]]["cam_from_target_t"])
        label = labels[pose["sample_id"]]
        out["rotation"].append(g.quat_angular_distance(label["q_vbs2tango_true"], g.matrix_to_quat(true[:3, :3])))
        true_full = true[:3, 3] / scale
        out["position"].append(np.linalg.norm(np.asarray(label["r_Vo2To_vbs_true"]) - true_full)
                               / np.linalg.norm(true_full))
        fused = g.transform_from_qt(pose["cam_from_target_q"], pose["cam_from_target_t"])
        out["inside"].append(np.abs(fused[:3, 3] - true[:3, 3]) <= 1.96 * np.asarray(pose["sigma_t_m"]))
        out["fused"].append(np.linalg.norm(fused[:3, 3] - true[:3, 3]))
        for source in ("kuka", "vicon"):
            if pose[f"{source}_cam_from_target_q"] is not None:
                estimate = g.transform_from_qt(pose[f"{source}_cam_from_target_q"], pose[f"{source}_cam_from_target_t"])
                out[source].append(np.linalg.norm(estimate[:3, 3] - true[:3, 3]))
    return {k: np.array(v) for k, v in out.items()}


def test_dataset_labels_against_the_speedplus_thresholds(labelled, rigid):
    ours, papers = dataset_errors(labelled), dataset_errors(rigid)
    # (d) on the dataset captures motion capture is some 8x worse than the calibrated robots
    # (docs/accuracy.md): fusion cannot gain much there, and must do no harm (issue 28)
    assert ours["fused"].mean() <= 1.01 * ours["kuka"].mean() and ours["fused"].mean() < 0.3 * ours["vicon"].mean()
    assert papers["fused"].mean() < min(papers["kuka"].mean(), papers["vicon"].mean())  # the paper's case
    # (c) the goal is every label under both thresholds; with the unmodelled errors the default
    # facility (seed 11) keeps most of them, seeds 12-15 all (docs/accuracy.md)
    under = (ours["rotation"] < SPEEDPLUS_ROTATION_RAD) & (ours["position"] < SPEEDPLUS_TRANSLATION)
    assert under.mean() >= 0.8
    assert ours["rotation"].mean() < 0.2 * papers["rotation"].mean()
    # (e) the sigmas: 90-99% is the goal (docs/accuracy.md)
    assert np.all(ours["inside"].mean(axis=0) >= 0.85), ours["inside"].mean(axis=0)
    factor = json.loads((labelled.root / "fusion.json").read_text())["variance_factor"]
    assert factor["samples"] >= 30 and min(factor["t"]) >= 1.0 and factor["r"] >= 1.0
