"""RWHE solvers against known offsets, OpenCV's Shah, noise, and degenerate data."""

import cv2
import numpy as np
import pytest

from stages.common import geometry as g
from stages.common import rwhe


def random_pose(rng, scale=0.3):
    return g.transform_from_qt(g.random_quats(rng, 1)[0], rng.normal(scale=scale, size=3))


def nudge(rng, size):
    """A small rigid motion: about ``size`` radians and metres."""
    return g.make_transform(g.rotvec_to_matrix(rng.normal(scale=size, size=3)), rng.normal(scale=size, size=3))


def synthetic(rng, n, fixtures=("minus_x", "plus_x"), rotation_noise=0.0, translation_noise=0.0):
    z = random_pose(rng)
    x = {f: random_pose(rng) for f in fixtures}
    b = np.stack([random_pose(rng, 1.0) for _ in range(n)])
    names = [fixtures[i % len(fixtures)] for i in range(n)]
    a = np.stack([z @ b_i @ g.invert(x[f]) for b_i, f in zip(b, names, strict=True)])
    if rotation_noise or translation_noise:
        noise = g.make_transform(g.rotvec_to_matrix(rng.normal(scale=rotation_noise, size=(n, 3))),
                                 rng.normal(scale=translation_noise, size=(n, 3)))
        a = noise @ a
    return a, b, names, z, x


def assert_recovers(solution, z, x, atol):
    np.testing.assert_allclose(solution.z, z, atol=atol)
    for name, x_f in x.items():
        np.testing.assert_allclose(solution.x[name], x_f, atol=atol)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_free_offsets_are_recovered(seed):
    rng = np.random.default_rng(seed)
    a, b, names, z, x = synthetic(rng, 12)
    closed = rwhe.shah(a, b, names)
    assert_recovers(closed, z, x, 1e-9)
    start = rwhe.Solution(closed.z @ nudge(rng, 0.05), {f: x_f @ nudge(rng, 0.05) for f, x_f in closed.x.items()})
    assert_recovers(rwhe.frobenius(a, b, names, start), z, x, 1e-9)


def test_reprojection_refinement_recovers_exact_offsets():
    rng = np.random.default_rng(3)
    z, x = random_pose(rng), {"minus_x": random_pose(rng), "plus_x": random_pose(rng)}
    names = ["minus_x", "plus_x"] * 5
    # patterns in front of the camera, then the measurements B that go with them
    a = np.stack([g.make_transform(g.rotvec_to_matrix(rng.uniform(-0.6, 0.6, 3)),
                                   [*rng.uniform(-0.2, 0.2, 2), rng.uniform(1.2, 2.0)]) for _ in names])
    b = np.stack([g.invert(z) @ a_i @ x[f] for a_i, f in zip(a, names, strict=True)])
    camera_matrix = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    dist = np.array([-0.1, 0.05, 0, 0, 0])
    points = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 5), np.linspace(-0.1, 0.1, 4), [0.0]), -1).reshape(-1, 3)
    pixels = [g.project(a_i, points, camera_matrix, dist) for a_i in a]
    start = rwhe.Solution(z @ nudge(rng, 0.01), {f: x_f @ nudge(rng, 0.01) for f, x_f in x.items()})
    refined = rwhe.reprojection(b, names, start, [points] * len(a), pixels, camera_matrix, dist)
    assert_recovers(refined, z, x, 1e-7)


def test_shah_agrees_with_opencv_on_one_fixture():
    rng = np.random.default_rng(4)
    a, b, names, z, x = synthetic(rng, 10, fixtures=("fixed",))
    ours = rwhe.shah(a, b, names)
    r_base2world, t_base2world, r_gripper2cam, t_gripper2cam = cv2.calibrateRobotWorldHandEye(
        [a_i[:3, :3] for a_i in a], [a_i[:3, 3] for a_i in a], [b_i[:3, :3] for b_i in b],
        [b_i[:3, 3] for b_i in b], method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH)
    np.testing.assert_allclose(ours.x["fixed"], g.make_transform(r_base2world, t_base2world.ravel()), atol=1e-8)
    np.testing.assert_allclose(ours.z, g.make_transform(r_gripper2cam, t_gripper2cam.ravel()), atol=1e-8)


def test_noise_averages_out_like_one_over_sqrt_n():
    """Statistical consistency: unbiased, and the error shrinks as 1/sqrt(N)."""
    errors = {}
    for n in (16, 64):
        trials = []
        for seed in range(20):
            rng = np.random.default_rng(100 + seed)
            a, b, names, z, x = synthetic(rng, n, rotation_noise=1e-3, translation_noise=1e-3)
            solution = rwhe.frobenius(a, b, names, rwhe.shah(a, b, names))
            trials.append(np.linalg.norm(solution.z[:3, 3] - z[:3, 3]))
        errors[n] = np.sqrt(np.mean(np.square(trials)))
    assert 1.4 < errors[16] / errors[64] < 3.0
    assert errors[64] < 1e-3  # better than one sample's noise


def test_degenerate_data_is_refused_with_advice():
    rng = np.random.default_rng(5)
    _, b, names, _, _ = synthetic(rng, 12, fixtures=("fixed",))
    with pytest.raises(rwhe.DegenerateError, match="12 usable calibration samples, at least 20 needed"):
        rwhe.check_diversity(b, names, 20, 0.01, "kuka calibration")
    about_z = np.stack([g.make_transform(g.axis_angle_matrix("z", angle), rng.normal(size=3))
                        for angle in np.linspace(0, 2, 12)])
    with pytest.raises(rwhe.DegenerateError, match="about one axis only.*tilted about other axes"):
        rwhe.check_diversity(about_z, ["fixed"] * 12, 6, np.radians(2), "kuka calibration")
    rwhe.check_diversity(b, names, 6, np.radians(2), "kuka calibration")  # diverse data passes


def compliant(rng, n, k, spread_rad=0.5):
    """Synthetic data whose fixtures tilt under gravity: A_i X_f = Z B_i S(up_i x k_f).
    The up directions (flange frame) scatter by about ``spread_rad`` around one attitude."""
    a, b, names, z, x = synthetic(rng, n)
    up = np.array([0.3, -0.2, -0.93]) + rng.normal(scale=spread_rad, size=(n, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    tilt = rwhe.fixture_tilt(up, np.stack([k[f] for f in names]))
    a = z @ b @ tilt @ np.stack([g.invert(x[f]) for f in names])
    return a, b, names, z, x, up


@pytest.mark.parametrize("seed", [0, 1])
def test_noise_free_fixture_compliance_is_recovered(seed):
    rng = np.random.default_rng(seed)
    k = {"minus_x": np.array([-0.0006, 0.0009, 0.011]), "plus_x": np.array([0.001, -0.0007, 0.010])}
    a, b, names, z, x, up = compliant(rng, 24, k)
    solution = rwhe.frobenius(a, b, names, rwhe.shah(a, b, names), up)
    assert_recovers(solution, z, x, 1e-9)
    for name, k_f in k.items():
        np.testing.assert_allclose(solution.compliance[name], k_f, atol=1e-9)
    np.testing.assert_allclose(solution.predict(b, names, up), a, atol=1e-9)
    # the rigid model cannot explain the tilt: the compliant one predicts other captures better
    rigid = rwhe.frobenius(a, b, names, rwhe.shah(a, b, names))
    a_new, b_new, names_new, *_ = a[:4], b[:4], names[:4]
    assert np.abs(rigid.predict(b_new, names_new) - a_new).max() > 1e-4
    with pytest.raises(ValueError, match="up directions"):
        solution.predict(b, names)


def test_compliance_refined_on_reprojection_stays_exact():
    rng = np.random.default_rng(5)
    k = {"minus_x": np.array([0.002, 0.001, 0.012]), "plus_x": np.array([0.0, 0.003, 0.009])}
    a, b, names, z, x, up = compliant(rng, 16, k)
    # put the patterns in front of the camera: shift the target side so every A looks forward
    points = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 5), np.linspace(-0.1, 0.1, 4), [0.0]), -1).reshape(-1, 3)
    camera_matrix = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    dist = np.zeros(5)
    shift = g.make_transform(np.eye(3), [0, 0, 3.0])
    a = shift @ a
    z = shift @ z
    pixels = [g.project(a_i, points, camera_matrix, dist) for a_i in a]
    start = rwhe.frobenius(a, b, names, rwhe.shah(a, b, names), up)
    refined = rwhe.reprojection(b, names, start, [points] * len(a), pixels, camera_matrix, dist, up)
    assert_recovers(refined, z, x, 1e-7)
    for name, k_f in k.items():
        np.testing.assert_allclose(refined.compliance[name], k_f, atol=1e-7)


def test_gravity_spread_sees_a_fixed_attitude_as_zero():
    rng = np.random.default_rng(6)
    fixed = np.tile([0.0, 0.0, 1.0], (20, 1))
    assert rwhe.gravity_spread(fixed) < 1e-12
    about_one_axis = np.stack([[np.sin(t), 0.0, np.cos(t)] for t in rng.uniform(-0.5, 0.5, 20)])
    assert rwhe.gravity_spread(about_one_axis) < 0.05  # a tilt about one axis moves up along one curve
    scattered = rng.normal(size=(20, 3)) * 0.3 + [0, 0, 1]
    assert rwhe.gravity_spread(scattered / np.linalg.norm(scattered, axis=1, keepdims=True)) > 0.15


def test_an_anisotropic_fixture_tilts_by_its_compliance_shape():
    """D = 0 is the isotropic fixture; otherwise the tilt is (I + D)(up x k), D symmetric."""
    rng = np.random.default_rng(5)
    up = rng.normal(size=(7, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    k = rng.normal(0, 0.01, (7, 3))
    np.testing.assert_array_equal(rwhe.fixture_tilt(up, k, np.zeros((7, 6))), rwhe.fixture_tilt(up, k))
    d = rng.normal(0, 0.3, (7, 6))
    shape = rwhe.symmetric(d)
    np.testing.assert_array_equal(shape, np.swapaxes(shape, -1, -2))
    tilt = g.matrix_to_rotvec(rwhe.fixture_tilt(up, k, d)[:, :3, :3])
    expected = np.einsum("nij,nj->ni", np.eye(3) + shape, np.cross(up, k))
    np.testing.assert_allclose(tilt, expected, atol=1e-12)
    solution = rwhe.Solution(np.eye(4), {"a": np.eye(4), "b": np.eye(4)}, {"a": k[0], "b": k[1]},
                             {"a": d[0], "b": d[1]})
    again = rwhe.unpack(rwhe.pack(solution, ["a", "b"], True, True), ["a", "b"], True, True)
    np.testing.assert_allclose(again.anisotropy["b"], d[1])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_fixtures_play_holds_its_tilt_back_against_its_change(seed):
    """The lag is the play operator's: against the tilt's change, as long as the change up to
    the play ``w``, never longer; none where no capture came before; and a played solution
    packs, unpacks and predicts as its packed form does."""
    rng = np.random.default_rng(seed)
    now, before = rng.normal(0, 1e-3, (50, 3)), rng.normal(0, 1e-3, (50, 3))
    before[:5] = now[:5] + rng.normal(0, 1e-5, (5, 3))  # changes shorter than the play
    before[-3:] = np.nan
    w = rng.uniform(1e-4, 8e-4, 50)
    lag = g.matrix_to_rotvec(rwhe.fixture_lag(now, before, w)[:, :3, :3])
    change = now - before
    size = np.linalg.norm(change, axis=1)
    np.testing.assert_allclose(np.linalg.norm(lag[:-3], axis=1), np.minimum(size, w)[:-3], rtol=1e-9)
    np.testing.assert_allclose(np.cross(lag[:-3], change[:-3]), 0.0, atol=1e-15)
    assert np.all(np.einsum("ij,ij->i", lag[:-3], change[:-3]) < 0)
    np.testing.assert_allclose(lag[:5], -change[:5], atol=1e-15)  # the whole change, held back
    np.testing.assert_array_equal(lag[-3:], 0.0)
    names = ["a", "b"]
    solution = rwhe.Solution(random_pose(rng), {n: random_pose(rng) for n in names},
                             {n: rng.normal(0, 0.01, 3) for n in names}, {n: rng.normal(0, 0.3, 6) for n in names},
                             {"a": 3e-4, "b": 6e-4})
    packed = rwhe.pack(solution, names, True, True, True)
    assert list(packed[rwhe.play_slice(names)]) == [3e-4, 6e-4]
    assert rwhe.unpack(packed, names, True, True, True).play == solution.play
    b = np.stack([random_pose(rng, 1.0) for _ in range(6)])
    fixtures = ["a", "b", "a", "b", "b", "a"]
    up = rng.normal(size=(6, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    up_before = np.roll(up, 1, axis=0)
    up_before[0] = np.nan
    direct = solution.predict(b, fixtures, up, up_before)
    batched = rwhe.predict_packed(packed[None], names, True, True, b[None], fixtures, up[None], True, up_before)[0]
    np.testing.assert_allclose(batched, direct, atol=1e-12)
    still = solution.predict(b, fixtures, up)  # no capture before any: no lag
    np.testing.assert_allclose(direct[0], still[0], atol=1e-15)
    assert np.abs(direct[1:] - still[1:]).max() > 1e-6
