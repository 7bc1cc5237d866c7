"""When calibrate estimates the model fixture's compliance and the arms' kinematics, and why not."""

import numpy as np
import pytest

from pipeline.config import load_config
from speedplus.errors import InputError
from stages.calibrate.stage import arm_decision, compliance_decision
from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.robots import identification
from stages.common.robots.errors import Holders
from stages.common.robots.facility import load_facility
from stages.common.sources import up_targetee
from stages.common.workspace_target import planned_target


def config_with(**calibrate):
    settings = [f"calibrate.{k}={v}" for k, v in calibrate.items()]
    return load_config("smoke", None, settings)


def scattered_up(rng, n):
    up = rng.normal(scale=0.4, size=(n, 3)) + [0.3, -0.2, -0.9]
    return up / np.linalg.norm(up, axis=1, keepdims=True)


def test_auto_estimates_when_the_flange_attitude_varies_and_not_when_it_is_fixed():
    rng = np.random.default_rng(0)
    fixtures = ["minus_x", "plus_x"] * 10
    on, why = compliance_decision(config_with(), scattered_up(rng, 20), fixtures)
    assert on and "minus_x" in why and "plus_x" in why
    # a static target (a board on a table, as in hand-eye data sets): nothing to observe
    off, why = compliance_decision(config_with(), np.tile([0.0, 0.0, 1.0], (20, 1)), fixtures)
    assert not off and "under 5.0 deg" in why


def test_on_with_a_fixed_attitude_says_what_to_capture():
    with pytest.raises(rwhe.DegenerateError, match="minus_x.*add calibration captures with the model presented"):
        compliance_decision(config_with(fixture_compliance="on"), np.tile([0.0, 0.0, 1.0], (8, 1)), ["minus_x"] * 8)


def test_off_and_shah_never_estimate_and_on_with_shah_is_refused():
    rng = np.random.default_rng(1)
    up, fixtures = scattered_up(rng, 12), ["fixed"] * 12
    assert compliance_decision(config_with(fixture_compliance="off"), up, fixtures)[0] is False
    assert compliance_decision(config_with(solver="shah"), up, fixtures)[0] is False
    with pytest.raises(InputError, match="needs the frobenius or reprojection solver"):
        compliance_decision(config_with(solver="shah", fixture_compliance="on"), up, fixtures)


def test_up_direction_comes_from_the_target_flange_telemetry():
    flange = g.axis_angle_matrix("x", np.pi / 2)  # flange y axis points up
    row = {"kuka_world_from_targetee_q": g.matrix_to_quat(flange)}
    np.testing.assert_allclose(up_targetee(row, np.array([0.0, 0.0, 1.0])), [0, 1, 0], atol=1e-12)


def test_arm_kinematics_need_encoder_readings():
    payload = arms.Payload.of(planned_target(load_config("smoke")))
    rows = [{"kuka_camera_joints_rad": [0.0] * 6, "kuka_target_joints_rad": [0.0] * 6, "kuka_rail_m": 1.0,
             "fixture": "minus_x"}] * 10
    readings = identification.measured(Holders.of(load_facility()), rows, payload, np.array([0.0, 0.0, 1.0]))
    assert arm_decision(config_with(), readings) == (True, "encoder readings of 10 calibration captures, the arms' "
                                                           "URDFs")
    assert arm_decision(config_with(), None) == (False, "the captures have no encoder readings")
    assert arm_decision(config_with(arm_kinematics="off"), readings)[0] is False
    with pytest.raises(InputError, match="lack the robots' encoder readings.*kuka_camera_joints_rad"):
        arm_decision(config_with(arm_kinematics="on"), None)
