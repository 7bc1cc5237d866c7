"""Label accuracy on the default profile against the virtual testbed's hidden truth
(issue 4, item 4): the testbed is as hard as TRON with the paper's method, fusion beats
each source and the paper's fused figures, and the dataset labels are scored against the
SPEED+ thresholds. `python -m bench accuracy` prints the same figures."""

import json
import shutil

import numpy as np
import pytest

from bench.accuracy import PAPERS_METHOD
from manifests import Workspace, read_manifest
from stages import geometry as g
from stages.calibrate.table import PAPER
from tests.conftest import speedplus

SPEEDPLUS_ROTATION_RAD = np.radians(0.169)
SPEEDPLUS_TRANSLATION = 2.173e-3


def labelled_copy(default_acquisition, root, *settings):
    shutil.copytree(default_acquisition.root, root)
    args = [a for s in settings for a in ("--set", s)]
    result = speedplus("run", "--workspace", str(root), "--until", "label", *args)
    assert result.returncode == 0, result.stderr
    return Workspace(root)


@pytest.fixture(scope="module")
def labelled(default_acquisition, tmp_path_factory):
    return labelled_copy(default_acquisition, tmp_path_factory.mktemp("accuracy") / "w")


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


def test_fixture_compliance_is_estimated_and_removes_most_of_the_robots_rotation_error(labelled, rigid):
    compliance = calibration(labelled)["kuka"]["fixture_compliance"]
    assert compliance["estimated"], compliance["why"]
    assert 0.001 < compliance["tilt_rad_mean"] < 0.02  # tenths of a degree, as DESIGN says
    with_compliance = calibration(labelled)["kuka"]["metrics"]
    without = calibration(rigid)["kuka"]["metrics"]
    assert calibration(rigid)["kuka"]["fixture_compliance"]["estimated"] is False
    for kind in ("cross_validated", "truth"):
        assert with_compliance[kind]["E_R_rad"][0] < 0.5 * without[kind]["E_R_rad"][0]
        assert with_compliance[kind]["E_T_m"][0] < without[kind]["E_T_m"][0]


def test_fused_calibration_beats_the_papers_fused_figures_and_each_source(labelled):
    c = calibration(labelled)
    truth = c["fused"]["metrics"]["truth"]
    assert truth["E_T_m"][0] * 1000 < PAPER["fused"][0][0]
    assert np.degrees(truth["E_R_rad"][0]) < PAPER["fused"][1][0]
    for kind in ("in_sample", "cross_validated", "truth"):
        fused = c["fused"]["metrics"][kind]["E_T_m"][0]
        assert fused < c["kuka"]["metrics"][kind]["E_T_m"][0] and fused < c["vicon"]["metrics"][kind]["E_T_m"][0]


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
    # (d) fusion beats each source in mean position error on the dataset captures too
    assert ours["fused"].mean() < ours["kuka"].mean() and ours["fused"].mean() < ours["vicon"].mean()
    # (c) the goal is every label under both thresholds; these floors guard what is reached
    # (README: 92% in rotation, 79% in position), and the method must beat the paper's
    under = {name: (e["rotation"] < SPEEDPLUS_ROTATION_RAD) & (e["position"] < SPEEDPLUS_TRANSLATION)
             for name, e in (("ours", ours), ("paper", papers))}
    assert np.mean(ours["rotation"] < SPEEDPLUS_ROTATION_RAD) >= 0.85
    assert under["ours"].mean() >= 0.7 and under["ours"].mean() > under["paper"].mean() + 0.1
    assert ours["rotation"].mean() < 0.6 * papers["rotation"].mean()
    # (e) the sigmas: 90-99% is the goal; README: 95.8%, 97.9%, 89.6%
    assert np.all(ours["inside"].mean(axis=0) >= 0.85), ours["inside"].mean(axis=0)


def test_the_sessions_variance_factor_makes_the_sigmas_honest(labelled, tmp_path):
    """With the fixture compliance, the robots' calibrated sigmas are small; carried to the
    dataset's poses unscaled they reject good motion capture and under-state the error."""
    factor = json.loads((labelled.root / "fusion.json").read_text())["variance_factor"]
    assert factor["samples"] >= 30 and min(factor["robots_t"]) >= 1.0 and factor["r"] >= 1.0
    unscaled = Workspace(tmp_path / "unscaled")
    shutil.copytree(labelled.root, unscaled.root)
    for stage in ("fuse", "label"):
        result = speedplus(stage, "--workspace", str(unscaled.root), "--force", "--set", "fuse.sigma_scale=calibration")
        assert result.returncode == 0, result.stderr
    assert json.loads((unscaled.root / "fusion.json").read_text())["variance_factor"]["samples"] == 0
    scaled, plain = dataset_errors(labelled), dataset_errors(unscaled)
    assert plain["inside"].mean() < 0.75 < 0.85 < scaled["inside"].mean()
    assert scaled["fused"].mean() < plain["fused"].mean()
