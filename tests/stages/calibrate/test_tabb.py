"""Real data (Tabb & Ahmad Yousef 2017, UR10, camera on the hand): the default solver
calibrates better than OpenCV's Shah closed form on the same detections and intrinsics."""

import json
from pathlib import Path

import pytest

from manifests import Workspace
from tests.conftest import speedplus

TABB = Path(__file__).resolve().parents[4] / "shared" / "external" / "tabb_ds1"


@pytest.fixture(scope="module")
def tabb_calibration(tmp_path_factory):
    root = tmp_path_factory.mktemp("tabb") / "w"
    result = speedplus("acquire", "--workspace", str(root), "--backend", "replay", "--format", "tabb",
                       "--source", str(TABB))
    assert result.returncode == 0, result.stderr
    result = speedplus("calibrate", "--workspace", str(root))
    assert result.returncode == 0, result.stderr
    return json.loads((Workspace(root).root / "calibration.json").read_text()), result.stdout


def test_default_solver_beats_opencv_shah_on_tabb(tabb_calibration):
    calibration, _ = tabb_calibration
    kuka = calibration["kuka"]
    ours, shah = kuka["metrics"]["in_sample"], kuka["opencv_shah_in_sample"]
    assert ours["E_T_m"][0] < shah["E_T_m"][0]
    assert ours["E_p_px"][0] < shah["E_p_px"][0]
    assert kuka["samples"] >= 70  # most of the 88 images have the whole chessboard
    assert calibration["vicon"] is None


def test_a_static_board_gets_no_fixture_compliance(tabb_calibration):
    calibration, stdout = tabb_calibration
    compliance = calibration["kuka"]["fixture_compliance"]
    assert compliance["estimated"] is False and "under 5.0 deg" in compliance["why"]
    assert "Table 1" in stdout
