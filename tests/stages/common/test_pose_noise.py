"""The calibration poses' residual covariance (``stages.common.pose_noise``) and the arms'
fit that whitens by it (``arms.map_fit``): seeded simulations with known variances."""

from __future__ import annotations

import numpy as np
import pytest

from stages.common import arms
from stages.common import geometry as g
from stages.common.pose_noise import ResidualCovariance, stacked_pnp


def pnp_like(rng: np.random.Generator, count: int) -> np.ndarray:
    """(N, 6, 6) PnP-like covariances: a board's sideways shift goes with its turn about the
    other sideways axis (correlation about 0.95, as a 0.3 m board at 0.75 m gives)."""
    out = []
    for _ in range(count):
        depth = rng.uniform(0.6, 0.9)
        basis = rng.normal(size=(6, 6)) * np.r_[[1e-5] * 3, [1e-5] * 3][:, None]
        covariance = basis @ basis.T * 0.05
        turn, shift = 2e-4, 2e-4 * depth  # rad, m: one ambiguous combination per sideways axis
        for rotation_axis, shift_axis, sign in ((0, 4, -1.0), (1, 3, 1.0)):
            v = np.zeros(6)
            v[rotation_axis], v[shift_axis] = turn, sign * shift
            covariance += np.outer(v, v)
        covariance[2, 2] += (3e-5) ** 2
        covariance[5, 5] += (6e-5) ** 2
        out.append(covariance)
    return np.stack(out)


def draw(rng: np.random.Generator, covariances: np.ndarray) -> np.ndarray:
    return np.einsum("nij,nj->ni", np.linalg.cholesky(covariances), rng.normal(size=(len(covariances), 6)))


def fit_linear(design: np.ndarray, observed: np.ndarray, noise: ResidualCovariance, rounds: int = 10):
    """Generalised least squares of ``observed`` (N, 6) = ``design`` (N, 6, F) x with the
    variances re-estimated after each fit, as ``map_fit`` does."""
    for _ in range(rounds):
        whitening = noise.whitening(len(observed))
        jacobian = np.einsum("nij,njf->nif", whitening, design).reshape(-1, design.shape[-1])
        whitened = np.einsum("nij,nj->ni", whitening, observed).ravel()
        x = np.linalg.lstsq(jacobian, whitened, rcond=None)[0]
        noise, previous = noise.at_fit(jacobian @ x - whitened, jacobian, len(observed)), noise
        if noise.settled(previous, 1e-3):
            break
    return x, previous


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_helmert_recovers_the_three_variances(seed):
    rng = np.random.default_rng(seed)
    count, unknowns = 400, 12
    pnp = pnp_like(rng, count)
    truth = np.array([1.7, (4e-5) ** 2, (9e-5) ** 2])
    covariances = truth[0] * pnp + np.stack([np.diag([truth[1]] * 3 + [truth[2]] * 3)] * count)
    design = rng.normal(size=(count, 6, unknowns)) * 1e-4
    observed = design @ rng.normal(size=unknowns) + draw(rng, covariances)
    start = ResidualCovariance.start(observed, pnp)
    _, noise = fit_linear(design, observed, start)
    # 2400 residuals: each component's standard error is a few percent
    np.testing.assert_allclose(noise.variances, truth, rtol=0.25)


def test_without_pnp_covariances_the_groups_are_each_one_sum_of_squares_over_its_redundancy():
    rng = np.random.default_rng(5)
    count, unknowns = 30, 8
    design = rng.normal(size=(count, 6, unknowns))
    observed = design @ rng.normal(size=unknowns) + rng.normal(size=(count, 6)) * np.r_[[2e-4] * 3, [5e-5] * 3]
    x, noise = fit_linear(design, observed, ResidualCovariance.start(observed, None))
    whitening = noise.whitening(count)
    jacobian = np.einsum("nij,njf->nif", whitening, design).reshape(-1, unknowns)
    hat = jacobian @ np.linalg.pinv(jacobian.T @ jacobian) @ jacobian.T
    leverage = np.diag(hat).reshape(count, 6)
    residual = observed - design @ x
    for column, variance in ((slice(0, 3), noise.variances[1]), (slice(3, 6), noise.variances[2])):
        expected = np.sum(residual[:, column] ** 2) / (residual[:, column].size - leverage[:, column].sum())
        assert variance == pytest.approx(expected, rel=1e-2)
    assert noise.variances[0] == 0.0 and noise.pnp is None


def test_a_pose_without_its_own_covariance_takes_the_others_mean():
    a, b = np.eye(6), 3 * np.eye(6)
    np.testing.assert_array_equal(stacked_pnp([a, None, b])[1], 2 * np.eye(6))
    assert stacked_pnp([None, None]) is None


def turned(params: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """(K, N, 4, 4): a camera offset (rotation vector, translation; K, 6) applied to every pose."""
    offset = np.stack([g.make_transform(g.rotvec_to_matrix(p[:3]), p[3:]) for p in params])
    return offset[:, None] @ nominal[None]


def test_the_arms_fit_whitened_by_the_pnp_covariance_is_better_and_its_covariance_honest():
    """A camera offset seen through PnP poses whose sideways errors are their turns': the fit
    that knows it errs less than the one that weighs rotations and translations apart, and
    its covariance holds its errors (rms z near 1 over seeds)."""
    errors = {"whitened": [], "apart": []}
    z = []
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        count = 24
        nominal = np.stack([g.make_transform(g.rotvec_to_matrix(rng.normal(0, 0.4, 3)),
                                             [rng.normal(0, 0.1), rng.normal(0, 0.1), rng.uniform(0.6, 0.9)])
                            for _ in range(count)])
        true = np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 1e-3, 3)]
        pnp = pnp_like(rng, count)
        covariances = pnp + np.stack([np.diag([(1e-5) ** 2] * 3 + [(1e-5) ** 2] * 3)] * count)
        noise = draw(rng, covariances)
        clean = turned(true[None], nominal)[0]
        a = np.stack([g.make_transform(g.rotvec_to_matrix(n[:3]) @ c[:3, :3], c[:3, 3] + n[3:])
                      for n, c in zip(noise, clean, strict=True)])
        free, priored = np.ones(6, bool), np.arange(6)
        prior = np.full(6, 0.1)
        for name, given in (("whitened", pnp), ("apart", None)):
            fit = arms.map_fit(lambda p, nominal=nominal: turned(p, nominal), a, np.zeros(6), free, prior, priored,
                               given)
            errors[name].append(fit.params - true)
            if given is not None:
                z.append((fit.params - true) / np.sqrt(np.diag(fit.covariance)))
    rms = {name: np.sqrt(np.mean(np.square(e), axis=0)) for name, e in errors.items()}
    assert np.all(rms["whitened"] <= rms["apart"] * 1.05), rms
    assert np.mean(rms["whitened"] / rms["apart"]) < 0.8, rms
    spread = np.sqrt(np.mean(np.square(z)))
    assert 0.7 < spread < 1.4, spread


def test_components_the_data_cannot_tell_apart_stay_finite_and_their_sum_fits():
    """PnP covariances that are the model's own shapes (the Fisher information singular):
    the variances stay within their bounds and their sum still fits the residuals."""
    rng = np.random.default_rng(9)
    count, unknowns = 40, 6
    pnp = np.stack([np.diag([1e-8] * 3 + [4e-8] * 3)] * count)
    design = rng.normal(size=(count, 6, unknowns)) * 1e-3
    observed = design @ rng.normal(size=unknowns) + draw(rng, 3.0 * pnp)
    _, noise = fit_linear(design, observed, ResidualCovariance.start(observed, pnp))
    assert np.all(np.isfinite(noise.variances)) and np.all(noise.variances > 0)
    total = noise.covariances(count)[0]
    np.testing.assert_allclose(np.diag(total), 3.0 * np.diag(pnp[0]), rtol=0.35)


def test_a_fit_stopped_by_the_iterations_cap_says_so(monkeypatch):
    """``MapFit.capped``: false where SciPy's tolerances stopped the fit, true where the cap
    did (calibrate then says so, and records it in the arms' note)."""
    rng = np.random.default_rng(7)
    nominal = np.stack([g.make_transform(g.rotvec_to_matrix(rng.normal(0, 0.4, 3)),
                                         [rng.normal(0, 0.1), rng.normal(0, 0.1), rng.uniform(0.6, 0.9)])
                        for _ in range(24)])
    a = turned(np.r_[rng.normal(0, 1e-2, 3), rng.normal(0, 1e-2, 3)][None], nominal)[0]
    a[:, :3, 3] += rng.normal(0, 1e-4, (24, 3))

    def fit():
        return arms.map_fit(lambda p: turned(p, nominal), a, np.zeros(6), np.ones(6, bool), np.full(6, 0.1),
                            np.arange(6), pnp_like(rng, 24))

    assert not fit().capped
    monkeypatch.setattr(arms, "MAX_ITERATIONS", 1)
    assert fit().capped
