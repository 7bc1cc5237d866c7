"""Kinematic calibration of the arms: exact on noise-free data, carried over to other arm
configurations, and read back from calibration.json unchanged."""

import json

import numpy as np
import pytest

from manifests.sidecars.arm_fit import ArmCorrections
from manifests.sidecars.base import Fields
from pipeline.config import load_config
from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.kinematics import arm_model
from stages.common.target import load_target
from stages.common.targets import builtin_folder

PAYLOAD = arms.Payload.of(load_target(builtin_folder()))


def random_readings(rng, n, limits_fraction=0.4):
    nominal = arm_model(load_config("default").testbed.robot_model)
    low, high = np.array(nominal.lower) * limits_fraction, np.array(nominal.upper) * limits_fraction
    return arms.Readings(rng.uniform(low, high, (n, 6)), rng.uniform(low, high, (n, 6)), rng.uniform(0.5, 5.5, n),
                         PAYLOAD)


def true_errors(rng):
    """Arm errors of the size the virtual testbed draws (docs/architecture.md section 5)."""
    return arms.ArmErrors(np.concatenate([rng.normal(0, 6e-4, 12), rng.normal(0, 3e-4, 12), rng.normal(0, 2e-4, 3),
                                          rng.normal(0, 5e-4, 3), rng.normal(0, 2e-4, 3), rng.normal(0, 5e-4, 3),
                                          rng.normal(0, 1e-4, 1), rng.normal(0, [2e-6, 4e-6, 1.7e-5] * 2)]))


def captures(testbed, errors, readings, z, x, k, fixtures, world_up, anisotropy=None):
    """PnP poses A (N, 4, 4) the true arms and compliant (anisotropic) fixtures would give."""
    b, up = arms.corrected_b(testbed, errors, readings, world_up)
    return rwhe.Solution(z, x, k, anisotropy or {}).predict(b, fixtures, up)


@pytest.mark.parametrize("seed", [0, 1])
def test_noise_free_arms_are_calibrated_and_carry_over_to_other_configurations(seed):
    rng = np.random.default_rng(seed)
    config = load_config("default")
    testbed, world_up = config.testbed, np.array(config.calibrate.world_up)
    errors = true_errors(rng)
    z = g.transform_from_qt(g.random_quats(rng, 1)[0], rng.normal(0, 0.1, 3))
    x = {f: g.transform_from_qt(g.random_quats(rng, 1)[0], rng.normal(0, 0.2, 3)) for f in ("minus_x", "plus_x")}
    k = {"minus_x": np.array([-6e-4, 9e-4, 0.011]), "plus_x": np.array([1e-3, -7e-4, 0.010])}
    readings = random_readings(rng, 60)
    fixtures = ["minus_x", "plus_x"] * 30
    d = {"minus_x": np.array([0.3, -0.2, 0.1, 0.15, 0.0, -0.1]), "plus_x": np.array([-0.25, 0.2, 0.0, 0.1, 0.2, 0.0])}
    a = captures(testbed, errors, readings, z, x, k, fixtures, world_up, d)

    # the nominal arms' solution is the start, as in the calibrate stage
    b_nominal, up_nominal = arms.corrected_b(testbed, arms.NOMINAL, readings, world_up)
    start = rwhe.frobenius(a, b_nominal, fixtures, rwhe.shah(a, b_nominal, fixtures), up_nominal)
    fit = arms.fit(testbed, config.calibrate, a, readings, fixtures, start, compliant=True)
    solution, fitted = fit.offsets, fit.errors

    others = random_readings(rng, 40)  # other arm configurations: what the dataset session does
    other_fixtures = ["plus_x", "minus_x"] * 20
    expected = captures(testbed, errors, others, z, x, k, other_fixtures, world_up, d)
    b_fitted, up_fitted = arms.corrected_b(testbed, fitted, others, world_up)
    predicted = solution.predict(b_fitted, other_fixtures, up_fitted)
    assert np.abs(predicted[:, :3, 3] - expected[:, :3, 3]).max() < 1e-6
    assert g.angular_distance(predicted[:, :3, :3], expected[:, :3, :3]).max() < 1e-6
    # the uncertainty of a prediction: a covariance, tiny for noise-free data
    covariances = arms.pose_covariances(testbed, fit.record(), others, other_fixtures, world_up)
    assert covariances.shape == (40, 6, 6)
    np.testing.assert_array_equal(covariances, np.swapaxes(covariances, -1, -2))
    assert np.linalg.eigvalsh(covariances).min() > -1e-18
    assert np.sqrt(np.trace(covariances, axis1=1, axis2=2)).max() < 1e-4  # priors bound what the data do not
    # the nominal arms' solution does not carry over
    b_rigid, up_rigid = arms.corrected_b(testbed, arms.NOMINAL, others, world_up)
    rigid = start.predict(b_rigid, other_fixtures, up_rigid)
    assert np.abs(rigid[:, :3, 3] - expected[:, :3, 3]).max() > 1e-3


def test_arm_errors_survive_json():
    """Through calibration.json's record and its validating reader, as fuse reads them."""
    errors = true_errors(np.random.default_rng(3))
    data = json.loads(json.dumps(errors.record().to_json()))
    read = ArmCorrections.from_fields(Fields(data, "calibration.json", ""))
    assert np.array_equal(arms.ArmErrors.from_record(read).params, errors.params)


def test_readings_need_every_capture_to_have_them():
    row = {"kuka_camera_joints_rad": [0.0] * 6, "kuka_target_joints_rad": [0.1] * 6, "kuka_rail_m": 2.0}
    assert arms.readings([row, row], PAYLOAD).rail_m.tolist() == [2.0, 2.0]
    assert arms.readings([row, {**row, "kuka_rail_m": None}], PAYLOAD) is None
    assert arms.readings([], PAYLOAD) is None


def test_a_batch_of_parameters_predicts_each_exactly_and_differences_as_scipy_does():
    """The fit's Jacobian evaluates every finite-difference step in one batch: each batch
    row is the single prediction bit for bit, and the columns are SciPy's ``2-point``."""
    from scipy.optimize._numdiff import approx_derivative

    rng = np.random.default_rng(3)
    config = load_config("default")
    testbed, world_up = config.testbed, np.array(config.calibrate.world_up)
    readings = random_readings(rng, 12)
    names, fixtures = ["minus_x", "plus_x"], ["minus_x", "plus_x"] * 6
    size = arms.N_ARM + len(rwhe.pack(rwhe.Solution(np.eye(4), {f: np.eye(4) for f in names},
                                                    {f: np.zeros(3) for f in names},
                                                    {f: np.zeros(6) for f in names}), names, True, True))
    batch = np.concatenate([true_errors(rng).params[None].repeat(4, 0), rng.normal(0, 0.05, (4, size - arms.N_ARM))],
                           axis=1)
    batch[1, :arms.N_ARM] = 0.0  # a nominal arm in the batch: the compliance branch is the batch's
    together = arms.predict_batch(testbed, batch, names, True, readings, fixtures, world_up)
    for params, predicted in zip(batch, together, strict=True):
        np.testing.assert_array_equal(predicted, arms.predict(testbed, params, names, True, readings, fixtures,
                                                              world_up))
        # and the packed offsets predict as the unpacked solution does
        b, up = arms.corrected_b(testbed, arms.ArmErrors(params[:arms.N_ARM]), readings, world_up)
        solution = rwhe.unpack(params[arms.N_ARM:], names, True, anisotropic=True)
        np.testing.assert_allclose(predicted, solution.predict(b, fixtures, up), rtol=0, atol=1e-12)

    def residuals(params):
        return arms.predict_batch(testbed, params, names, True, readings, fixtures, world_up)[..., :3, :].reshape(
            len(params), -1)

    x = batch[0]
    np.testing.assert_array_equal(arms._forward_differences(residuals, x),
                                  approx_derivative(lambda p: residuals(p[None])[0], x, method="2-point"))


def test_lost_motion_covers_joints_resting_on_either_flank():
    """A joint below the preload rests on a random flank, +-l / 2 from where its offset was
    fitted, l 50-100% of the rating: the propagated covariance predicts the pose errors that
    gives (rms of error over sigma 1 per camera axis); a loaded joint adds nothing."""
    rng = np.random.default_rng(11)
    config = load_config("default")
    testbed, world_up = config.testbed, np.array(config.calibrate.world_up)
    readings = random_readings(rng, 300)
    fixtures = ["minus_x", "plus_x"] * 150
    names = ["minus_x", "plus_x"]
    solution = rwhe.Solution(np.eye(4), {name: np.eye(4) for name in names})
    params = np.concatenate([arms.NOMINAL.params, rwhe.pack(solution, names, False, anisotropic=False)])
    entry = arms.Fit(solution, arms.NOMINAL, params, np.zeros((len(params), len(params))), names, False).record()
    lost = config.fuse.lost_motion_rad
    variances = arms.flank_variances(testbed, readings, lost, config.fuse.backlash_preload_nm)
    camera_torque, target_torque = arms.torques(testbed, readings)
    loaded = np.abs(np.concatenate([camera_torque, target_torque], axis=1)) > config.fuse.backlash_preload_nm
    assert loaded.any() and (~loaded).any()
    assert np.all(variances[loaded] == 0)
    np.testing.assert_allclose(variances[~loaded],
                               7 / 12 * np.tile((np.asarray(lost) / 2) ** 2, (300, 2))[~loaded])

    # each unit's lost motion 50-100% of the rating, each joint on a random flank
    unit = rng.uniform(0.5, 1.0, (300, 12)) * np.tile(np.asarray(lost), 2)
    flank = np.where(loaded, 0.0, rng.choice([-1.0, 1.0], (300, 12)) * unit / 2)
    turned = arms.Readings(readings.camera_joints_rad + flank[:, :6], readings.target_joints_rad + flank[:, 6:],
                           readings.rail_m, readings.payload, readings.fixtures)
    true = arms.predict(testbed, params, names, False, turned, fixtures, world_up)
    estimate = arms.predict(testbed, params, names, False, readings, fixtures, world_up)
    covariances = arms.pose_covariances(testbed, entry, readings, fixtures, world_up, variances)
    error = true[:, :3, 3] - estimate[:, :3, 3]
    assert np.sqrt(np.mean(error**2)) > 1e-4  # tenths of a mm at these reaches
    normalised = error / np.sqrt(np.diagonal(covariances, axis1=1, axis2=2)[:, 3:])
    np.testing.assert_allclose(np.sqrt(np.mean(normalised**2, axis=0)), 1.0, atol=0.12)
    without = arms.pose_covariances(testbed, entry, readings, fixtures, world_up)
    assert np.abs(without).max() == 0.0


def test_the_named_layout_tiles_the_packed_vector_and_round_trips_json():
    """Seeded: the layout's groups tile 0..N_ARM in order without overlap, and an ArmErrors
    reads back from its JSON as it was, each group under its own key."""
    at = arms.ArmLayout
    groups = [at.camera_joint_offsets, at.target_joint_offsets, at.camera_link_deltas, at.target_link_deltas,
              at.camera_base, at.target_base, at.rail_scale, at.camera_compliance, at.target_compliance]
    assert [g.start for g in groups[1:]] == [g.stop for g in groups[:-1]] and groups[-1].stop == arms.N_ARM
    assert (at.compliance.start, at.compliance.stop) == (at.camera_compliance.start, at.target_compliance.stop)
    rng = np.random.default_rng(12)
    errors = arms.ArmErrors(rng.normal(size=arms.N_ARM))
    entry = errors.record().to_json()
    np.testing.assert_array_equal(arms.ArmErrors.from_record(errors.record()).params, errors.params)
    assert entry["rail_scale_error"] == errors.params[at.rail_scale][0]
    assert entry["target_base_correction"]["t_m"] == list(errors.params[at.target_base][3:])
