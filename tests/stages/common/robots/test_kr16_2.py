"""TRON's KR 16-2 pair is one case of the URDF arms' model (issue 57): the built-in
facility's URDF carries the data sheet's masses, and its fit takes true arms drawn as the
virtual testbed draws TRON's (perturbed data-sheet dimensions, encoder offsets, bases, rail
scale, joints winding up under the links' own weight) to other configurations exactly;
the joints' lost motion reaches each pose's covariance."""

from dataclasses import replace

import numpy as np
import pytest

from pipeline.config import load_config
from stages.calibrate.arm_models import arms_model
from stages.common import arms, layout, rwhe
from stages.common import geometry as g
from stages.common.kinematics import arm_model, forward
from stages.common.pose_noise import ResidualCovariance
from stages.common.robots import identification, lost_motion
from stages.common.robots.errors import Holders
from stages.common.robots.facility import load_facility
from stages.common.statics import KR16_2_MASSES, gravity_torques
from stages.common.target import load_target
from stages.common.targets import builtin_folder

PAYLOAD = arms.Payload.of(load_target(builtin_folder()))
CAMERA_KG = 2.5  # the camera robot's payload_kg in core/facilities/tron/facility.toml


def readings(rng: np.random.Generator, n: int, fraction: float = 0.4) -> list[dict]:
    """Captures' rows: both arms' joints (within ``fraction`` of their limits), the rail, the fixture."""
    nominal = arm_model(load_config("default").testbed.robot_model)
    low, high = np.array(nominal.lower) * fraction, np.array(nominal.upper) * fraction
    return [{"kuka_camera_joints_rad": rng.uniform(low, high).tolist(),
             "kuka_target_joints_rad": rng.uniform(low, high).tolist(),
             "kuka_rail_m": float(rng.uniform(0.5, 5.5)), "fixture": ("minus_x", "plus_x")[i % 2]} for i in range(n)]


@pytest.mark.parametrize("seed", [0, 1])
def test_the_urdf_gives_the_data_sheets_gravity_torques(seed):
    """The links' masses in kr16_2.urdf are statics' KR16_2_MASSES, hung as the closed form hangs them."""
    rng = np.random.default_rng(seed)
    chain = load_facility().robots[0].chain
    nominal = arm_model(load_config("default").testbed.robot_model)
    joints = rng.uniform(np.array(nominal.lower) * 0.8, np.array(nominal.upper) * 0.8, (20, 6))
    for world_from_base in (np.eye(4), layout.world_from_camera_base(load_config("default").testbed, 1.0)):
        expected = gravity_torques(nominal, KR16_2_MASSES, world_from_base, joints, 0.0, np.zeros(3))
        gravity = np.tile(world_from_base[:3, :3].T @ np.array([0.0, 0.0, -9.80665]), (20, 1))
        np.testing.assert_allclose(chain.gravity_torques(joints, gravity), expected, atol=1e-4)
        assert np.abs(expected[:, 1]).max() > 100.0  # the shoulder carries hundreds of N m


def true_poses(rows: list[dict], truth: dict) -> np.ndarray:
    """``cam_from_target`` (N, 4, 4) of TRON's true arms (the closed form, as the virtual
    testbed moves them) holding the camera and a rigidly fixed target."""
    testbed = load_config("default").testbed
    out = []
    for row in rows:
        flanges = []
        for key, arm, offsets, base, compliance, payload in (
                ("kuka_camera_joints_rad", truth["camera_arm"], truth["camera_offsets"],
                 layout.world_from_camera_base(testbed, row["kuka_rail_m"] * (1 + truth["rail_scale"]))
                 @ truth["camera_base"], truth["camera_compliance"], (CAMERA_KG, np.array([0.0, 0.0, 0.06]))),
                ("kuka_target_joints_rad", truth["target_arm"], truth["target_offsets"],
                 layout.world_from_target_base(testbed) @ truth["target_base"], truth["target_compliance"],
                 (PAYLOAD.mass_kg, PAYLOAD.centre_in_flange(row["fixture"])))):
            q = np.asarray(row[key]) + offsets
            torque = gravity_torques(arm, KR16_2_MASSES, base, q, payload[0], payload[1])
            flanges.append(base @ forward(arm, q + compliance * torque))
        b = g.invert(flanges[0]) @ flanges[1]
        out.append(truth["z"] @ b @ g.invert(truth["x"][row["fixture"]]))
    return np.stack(out)


def draw_truth(rng: np.random.Generator) -> dict:
    """TRON's arms as the virtual testbed draws them (docs/architecture.md section 5)."""
    nominal = arm_model(load_config("default").testbed.robot_model)

    def arm() -> object:
        return replace(nominal, **{k: getattr(nominal, k) + rng.normal(0, 3e-4) for k in ("a1", "a2", "c1", "c2",
                                                                                          "c3", "c4")})

    def base() -> np.ndarray:
        return g.make_transform(g.rotvec_to_matrix(rng.normal(0, 2e-4, 3)), rng.normal(0, 5e-4, 3))

    compliance = np.zeros(6)
    compliance[[1, 2, 4]] = [2e-6, 4e-6, 1.7e-5]
    return {"camera_arm": arm(), "target_arm": arm(), "camera_offsets": rng.normal(0, 6e-4, 6),
            "target_offsets": rng.normal(0, 6e-4, 6), "camera_base": base(), "target_base": base(),
            "rail_scale": rng.normal(0, 1e-4), "camera_compliance": compliance, "target_compliance": compliance,
            "z": g.transform_from_qt(g.random_quats(rng, 1)[0], rng.normal(0, 0.1, 3)),
            "x": {f: g.transform_from_qt(g.random_quats(rng, 1)[0], rng.normal(0, 0.2, 3))
                  for f in ("minus_x", "plus_x")}}


@pytest.mark.parametrize("seed", [0, 1])
def test_trons_true_arms_are_fitted_by_their_urdf_and_carry_over(seed):
    rng = np.random.default_rng(seed)
    config = load_config("default")
    model = arms_model(config, PAYLOAD)
    assert [robot.chain.source.endswith("kr16_2.urdf") for robot in model.holders.robots] == [True, True]
    truth = draw_truth(rng)
    rows = readings(rng, 64)
    a = true_poses(rows, truth)
    measured = model.readings(rows)
    fixtures = [row["fixture"] for row in rows]
    b, up = identification.corrected_b(model.holders, np.zeros(model.size), measured, np.array([0.0, 0.0, 1.0]))
    start = rwhe.frobenius(a, b, fixtures, rwhe.shah(a, b, fixtures), None)
    fitted = model.fit(a, measured, fixtures, start, False)

    others = readings(rng, 40)  # the dataset's configurations
    expected = true_poses(others, truth)
    b_fitted, _ = fitted.corrected_b(model.readings(others))
    predicted = fitted.offsets.predict(b_fitted, [row["fixture"] for row in others], None)
    error_m = np.linalg.norm(predicted[:, :3, 3] - expected[:, :3, 3], axis=1)
    b_rigid, _ = identification.corrected_b(model.holders, np.zeros(model.size), model.readings(others),
                                            np.array([0.0, 0.0, 1.0]))
    rigid = start.predict(b_rigid, [row["fixture"] for row in others], None)
    rigid_m = np.linalg.norm(rigid[:, :3, 3] - expected[:, :3, 3], axis=1)
    assert rigid_m.mean() > 1e-3  # the nominal arms do not carry over
    assert error_m.max() < 1e-4 and error_m.mean() < rigid_m.mean() / 20
    assert g.angular_distance(predicted[:, :3, :3], expected[:, :3, :3]).max() < 2e-5


def test_lost_motion_covers_joints_resting_on_either_flank():
    """A joint below the preload rests on a random flank, +-l / 2 from where its offset was
    fitted, l 50-100% of the rating: the propagated covariance predicts the pose errors that
    gives (rms of error over sigma 1 per camera axis); a loaded joint adds nothing."""
    rng = np.random.default_rng(11)
    config = load_config("default")
    holders = Holders.of(load_facility())
    rows = readings(rng, 300)
    lost, preload = config.fuse.lost_motion_rad, config.calibrate.backlash_preload_nm
    m = identification.measured(holders, rows, PAYLOAD, np.array([0.0, 0.0, 1.0]), preload)
    names = ["minus_x", "plus_x"]
    solution = rwhe.Solution(np.eye(4), {name: np.eye(4) for name in names})
    params = np.concatenate([np.zeros(holders.size), rwhe.pack(solution, names, False, anisotropic=False)])
    unfitted = np.array([0.0 if name.endswith(".lost_motion") else 1.0 for name in holders.names])
    noise = ResidualCovariance(None, np.array([0.0, 1e-8, 1e-8]), np.ones(3))  # the groups' (rad^2, m^2)
    record = identification.Fitted(holders, solution, params, np.zeros((len(params), len(params))), names, False,
                                   {}, unfitted, preload, noise, False).record()
    variances = lost_motion.flank_variances(holders, m, record, lost)
    loaded = np.abs(np.concatenate([m.camera_torque, m.target_torque], axis=1)) > preload
    assert loaded.any() and (~loaded).any()
    assert np.all(variances[loaded] == 0)
    np.testing.assert_allclose(variances[~loaded], 7 / 12 * np.tile((np.asarray(lost) / 2) ** 2, (300, 2))[~loaded])

    unit = rng.uniform(0.5, 1.0, (300, 12)) * np.tile(np.asarray(lost), 2)
    flank = np.where(loaded, 0.0, rng.choice([-1.0, 1.0], (300, 12)) * unit / 2)
    turned = identification.Measured(m.camera_joints + flank[:, :6], m.target_joints + flank[:, 6:], m.rail_m,
                                     m.fixtures, m.camera_torque, m.target_torque, m.camera_flank, m.target_flank)
    up = np.array([0.0, 0.0, 1.0])
    true = identification.predict_batch(holders, params[None], names, False, turned, up)[0]
    estimate = identification.predict_batch(holders, params[None], names, False, m, up)[0]
    jacobians = identification.pose_jacobians(holders, record, m, up)
    shared, own = arms.pose_covariance_parts(jacobians, np.zeros((len(params), len(params))), variances,
                                             identification.joint_columns(holders))
    assert np.abs(shared).max() == 0.0
    error = true[:, :3, 3] - estimate[:, :3, 3]
    assert np.sqrt(np.mean(error**2)) > 1e-4  # tenths of a mm at these reaches
    normalised = error / np.sqrt(np.diagonal(own, axis1=1, axis2=2)[:, 3:])
    np.testing.assert_allclose(np.sqrt(np.mean(normalised**2, axis=0)), 1.0, atol=0.12)
    assert lost_motion.flank_variances(holders, m, record, None).max() == 0.0


def test_forward_differences_step_as_scipy_does():
    """The batched Jacobian the MAP fit hands to least_squares equals SciPy's 2-point scheme."""
    from scipy.optimize._numdiff import approx_derivative

    rng = np.random.default_rng(5)

    def residuals(batch: np.ndarray) -> np.ndarray:  # row by row, so a batch rounds as one vector does
        return np.concatenate([np.sin(batch), batch[:, :1] * batch[:, 1:2] + batch**3], axis=1)

    x = rng.normal(size=4)
    np.testing.assert_array_equal(arms._forward_differences(residuals, x),
                                  approx_derivative(lambda v: residuals(v[None])[0], x, method="2-point"))


def test_trons_arms_stand_where_the_configuration_puts_them():
    """An override of ``[testbed]`` moves the arms' model as it moves the planned robots."""
    from stages.common.robots.errors import configured_holders

    config = load_config("default", overrides=["testbed.target_base_m=[0.7, 1.4, 0.0]",
                                               "testbed.rail_origin_m=[1.5, 1.5, 3.0]",
                                               "testbed.camera_payload_kg=3.5"])
    holders, _ = configured_holders("", config.testbed)
    np.testing.assert_allclose(holders.target.world_from_base, layout.world_from_target_base(config.testbed))
    np.testing.assert_allclose(holders.camera.base_at(np.array([2.0]))[0],
                               layout.world_from_camera_base(config.testbed, 2.0))
    assert holders.camera.payload_kg == 3.5
    assert configured_holders("", load_config("default").testbed)[0].target.world_from_base[0, 3] == 0.6


def test_a_capture_without_its_rail_reading_gives_the_arms_no_readings():
    """The camera robot rides a rail: a capture without ``kuka_rail_m`` is not taken at rail
    0 (its arm would be placed metres off), it leaves the arms without readings."""
    rows = readings(np.random.default_rng(3), 4)
    holders = Holders.of(load_facility())
    assert identification.measured(holders, rows, PAYLOAD, np.array([0.0, 0.0, 1.0])) is not None
    rows[2] = {key: value for key, value in rows[2].items() if key != "kuka_rail_m"}
    assert identification.measured(holders, rows, PAYLOAD, np.array([0.0, 0.0, 1.0])) is None
