"""Labels on a mock-up whose markers cluster on a small body (issue 43): seeded two-source
sessions at the dataset's 4 m where motion capture's error at the target's origin follows
its rigid-body fit: three to six markers within a few centimetres of each other, a panel's
length from the origin. Fuse must take the fit's geometry into its sigma, and where the
sources disagree beyond their sigmas keep the better one as the session shows it, not the
one that claims the smaller sigma; and a short session's sigmas must cover."""

import numpy as np
import pytest

from manifests.sidecars import Folds, Metrics, MetricSet
from pipeline.config import default_config
from stages.acquire.virtual.mocap import kabsch
from stages.common import geometry as g
from stages.common.fusion import Sigma
from stages.common.marker_fit import fit_covariance
from stages.fuse.marker_geometry import FitVariance, MarkerGeometry, marker_geometry, without_fit
from stages.fuse.short_session import cross_validated
from stages.fuse.stage import Estimates, fuse_capture, session_fusion
from tests.stages.fuse.test_axis_sources import Calibrated

CAPTURES = 48
SEEDS = range(6)
#: six markers on a 0.08 m bus, 0.5 m from the target's origin (a panel's length)
CLUSTERED = np.array([[0.04, 0.04, 0.04], [-0.04, 0.04, 0.04], [0.04, -0.04, 0.04], [0.04, 0.04, -0.04],
                      [-0.04, -0.04, 0.04], [0.04, -0.04, -0.04]]) + [0.5, 0.0, 0.0]


def clustered_session(seed: int, marker_sigma_m: float, claimed_marker_sigma_m: float, captures: int = CAPTURES,
                      robots_mm=(1.2, 1.2, 0.6), ghosts: int = 0, pointing_rad: float = 0.0):
    """Captures 3-5 m away. Motion capture sees 3-6 of the clustered markers at random and
    errs as its fit there does with the true marker noise (plus 0.3 mm of everything else);
    fuse is told ``claimed_marker_sigma_m``. The robots err as their sigma says. ``ghosts``
    captures of motion capture are off by 30-250 mm (a ghost marker in a three-marker fit);
    its line of sight turns by ``pointing_rad`` (1-sigma per axis) at every capture."""
    rng = np.random.default_rng(seed)
    geometry = MarkerGeometry(CLUSTERED, claimed_marker_sigma_m)
    truths, estimates = [], []
    for index in range(captures):
        true = g.make_transform(g.rotvec_to_matrix(rng.normal(scale=1.0, size=3)),
                                [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(3.0, 5.0)])
        used = sorted(rng.choice(len(CLUSTERED), size=int(rng.integers(3, 7)), replace=False).tolist())
        row = {"sample_id": f"d{index:03d}", "vicon_targetrb_used": used}
        # the fit's true error: Kabsch on noisy markers, carried to the origin
        noisy = CLUSTERED[used] + rng.normal(scale=marker_sigma_m, size=(len(used), 3))
        fitted = kabsch(CLUSTERED[used], noisy)  # the fitted body's error, in T
        vicon = true @ fitted
        vicon[:3, 3] += rng.normal(scale=3e-4, size=3)
        if pointing_rad:
            vicon[:3, 3] += np.cross(rng.normal(scale=pointing_rad, size=3), vicon[:3, 3])
        if index < ghosts:
            direction = rng.normal(size=3)
            vicon[:3, 3] += rng.uniform(0.03, 0.25) * direction / np.linalg.norm(direction)
        kuka = true.copy()
        kuka[:3, 3] += rng.normal(size=3) * np.asarray(robots_mm) / 1000
        truths.append(true)
        estimates.append(Estimates(row, kuka, vicon, None, geometry.variance(row, kuka)))
    return truths, estimates


def fuse_session(truths, estimates, kuka_sigma_mm=(1.2, 1.2, 0.6), vicon_rest_mm=0.3, config=None):
    config = config or default_config()
    kuka = Calibrated(Sigma(np.asarray(kuka_sigma_mm) / 1000, 1e-4))
    vicon = Calibrated(Sigma(np.full(3, vicon_rest_mm / 1000), 1e-3))
    rejection = Sigma(np.hypot(kuka.sigma.t_m, vicon.sigma.t_m), float(np.hypot(1e-4, 1e-3)))
    session = session_fusion(config, estimates, kuka, vicon, rejection)
    sources = session.sources
    rows = [fuse_capture(e, kuka, vicon, rejection, session.factor, 1.96, sources, session.offset)
            for e in estimates]
    true_t = np.stack([t[:3, 3] for t in truths])
    fused = np.stack([r["cam_from_target_t"] for r in rows])
    e_t = {name: float(np.linalg.norm(p - true_t, axis=1).mean() * 1000)
           for name, p in (("fused", fused), ("kuka", np.stack([e.kuka[:3, 3] for e in estimates])),
                           ("vicon", np.stack([e.vicon[:3, 3] for e in estimates])))}
    return e_t, (fused - true_t) / np.stack([r["sigma_t_m"] for r in rows]), sources


def without_geometry(estimates):
    return [Estimates(e.row, e.kuka, e.vicon, e.arm, None) for e in estimates]


def test_the_fits_geometry_keeps_clustered_markers_from_pulling_the_labels():
    """Markers as noisy as fuse is told (1 mm): motion capture errs by centimetres where
    its markers sit three in a cluster; with the fit's covariance in its sigma the labels
    stay within 1% of the robots and their sigmas cover; with the calibrated sigma alone
    (the markers unknown) motion capture pulls them."""
    normalised, worse = [], []
    for seed in SEEDS:
        truths, estimates = clustered_session(seed, 1e-3, 1e-3)
        e_t, errors_over_sigma, _ = fuse_session(truths, estimates)
        assert e_t["vicon"] > 2.5 * e_t["kuka"], e_t  # the case: motion capture far worse
        assert e_t["fused"] <= 1.01 * min(e_t["kuka"], e_t["vicon"]), (seed, e_t)
        normalised.append(errors_over_sigma)
        blind, _, _ = fuse_session(truths, without_geometry(estimates))
        worse.append(blind["fused"] / blind["kuka"])
    assert np.all(np.mean(np.abs(np.concatenate(normalised)) <= 1.96, axis=0) >= 0.9)
    assert np.mean(worse) > 1.01, worse


def test_the_fall_back_keeps_the_source_its_markers_say_is_better_not_the_smaller_claim():
    """The markers cluster on the small bus; motion capture's camera body also turns more
    than calibrated, so its lateral errors exceed every sigma and the consistency test
    fails there; three ghost markers among the 48 captures. Its sigma measured at the
    calibration (every marker in view) is the smaller, and would keep it alone; its fit's
    geometry at each capture says otherwise, and the fall-back keeps the robots. The labels
    stay within 1% of the robots on average (an axis the test passes is fused: 2% worse on
    one seed of six when written)."""
    robots = (2.0, 2.0, 0.6)
    ratios = []
    for seed in SEEDS:
        truths, estimates = clustered_session(seed, 1e-3, 1e-3, robots_mm=robots, ghosts=3, pointing_rad=1.5e-3)
        e_t, _, sources = fuse_session(truths, estimates, kuka_sigma_mm=robots, vicon_rest_mm=1.5)
        inconsistent = [axis for axis in (0, 1) if sources[axis] != "fused"]
        assert inconsistent, sources
        assert all(sources[axis] == "kuka" for axis in inconsistent), sources
        ratios.append(e_t["fused"] / e_t["kuka"])
        _, _, claimed = fuse_session(truths, without_geometry(estimates), kuka_sigma_mm=robots, vicon_rest_mm=1.5)
        assert all(claimed[axis] == "vicon" for axis in inconsistent if claimed[axis] != "fused"), claimed
    assert np.mean(ratios) <= 1.01 and max(ratios) <= 1.03, ratios


def test_the_fit_covariance_matches_monte_carlo_fits():
    """Seeded: 4000 Kabsch fits of four markers with 1 mm noise, the origin 0.4 m away."""
    rng = np.random.default_rng(11)
    markers = rng.normal(scale=0.04, size=(4, 3)) + [0.4, 0.0, 0.0]
    errors = np.stack([kabsch(markers, markers + rng.normal(scale=1e-3, size=markers.shape))[:3, 3]
                       for _ in range(4000)])
    predicted = fit_covariance(markers, np.zeros(3)).scaled(1e-3).point
    np.testing.assert_allclose(np.cov(errors.T), predicted, rtol=0.12, atol=0.02 * np.trace(predicted))


def test_the_marker_noise_is_measured_from_the_fits_residuals():
    rng = np.random.default_rng(2)
    rows = []
    for index in range(300):
        used = sorted(rng.choice(6, size=int(rng.integers(3, 7)), replace=False).tolist())
        noisy = CLUSTERED[used] + rng.normal(scale=5e-4, size=(len(used), 3))
        fitted = kabsch(CLUSTERED[used], noisy)
        residual = noisy - g.apply(fitted, CLUSTERED[used])
        rows.append({"sample_id": f"c{index}", "vicon_targetrb_used": used,
                     "vicon_targetrb_residual_m": float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))})
    assert marker_geometry(CLUSTERED, rows).marker_sigma_m == pytest.approx(5e-4, rel=0.1)
    assert marker_geometry(CLUSTERED, [{"sample_id": "x", "vicon_targetrb_used": None}]) is None


def test_the_calibrated_sigma_keeps_at_least_a_floor_when_the_fit_is_taken_out():
    sigma = Sigma(np.array([1e-3, 1e-3, 1e-3]), 2e-3, 1e-3)
    rest = without_fit(sigma, FitVariance(np.array([0.5e-6, 2e-6, 0.0]), 1e-6))
    np.testing.assert_allclose(rest.t_m, [np.sqrt(0.5e-6), np.sqrt(0.1e-6), 1e-3])
    assert rest.r_rad == pytest.approx(np.sqrt(3e-6))
    assert rest.pointing_rad == 1e-3  # the line of sight turns as much as before
    assert without_fit(Sigma(sigma.t_m, 2e-3, None), FitVariance(np.zeros(3), 3e-6)).pointing_rad == 2e-3


SHORT = 8


def test_a_short_sessions_sigmas_cover():
    """Both sources err 3x their in-sample sigmas (a fit that followed its few calibration
    samples), as the calibration's cross-validation measured; 8 captures, too few for a
    factor. Widened to the cross-validated errors and by the few captures' disagreement,
    at least 85% of the errors fall inside 1.96 sigma on every axis; the in-sample sigmas
    as they are cover far fewer."""
    metrics = Metrics(MetricSet((1e-3, 0.5e-3), (1e-3, 0.5e-3), (0.2, 0.1)),
                      MetricSet((3e-3, 1.5e-3), (3e-3, 1.5e-3), (0.6, 0.3)), Folds(15, 5, (), True), None)
    covered = {"widened": [], "in-sample": []}
    for seed in range(40):
        truths, estimates = clustered_session(seed, 6e-4, 6e-4, captures=SHORT, robots_mm=(3.6, 3.6, 1.8))
        for how in covered:
            kuka_sigma = Sigma(np.array([1.2, 1.2, 0.6]) / 1000, 1e-4)
            if how == "widened":
                kuka_sigma = cross_validated(metrics, 16).of(kuka_sigma)
            _, normalised, _ = fuse_session(truths, estimates, kuka_sigma_mm=tuple(kuka_sigma.t_m * 1000))
            covered[how].append(normalised)
    widened = np.mean(np.abs(np.concatenate(covered["widened"])) <= 1.96, axis=0)
    in_sample = np.mean(np.abs(np.concatenate(covered["in-sample"])) <= 1.96, axis=0)
    assert np.all(widened >= 0.85), widened
    assert np.min(in_sample) < 0.8, in_sample


def short_sessions(robots_claim: float = 1.0):
    """40 builds of 8 two-source captures (fewer than ``fuse.min_scale_samples``): each
    source errs at the dataset by its own factor of what its calibration says (log-normal,
    a factor of 1.6 either way at 1 sigma: the robots' arm fit and motion capture's
    extrapolation each grow beyond it by an amount the session cannot see), right on
    average over builds. ``robots_claim``: the robots' sigma that fuse is told, over the
    true one. Returns each build's mean E_T (mm) of the labels and of each source."""
    out = []
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        robots_mm = np.array([1.2, 1.2, 0.6]) * np.exp(rng.normal(scale=0.5))
        marker_m = 2e-4 * np.exp(rng.normal(scale=0.5))
        truths, estimates = clustered_session(seed, marker_m, 2e-4, captures=SHORT, robots_mm=tuple(robots_mm))
        e_t, _, _ = fuse_session(truths, estimates, kuka_sigma_mm=tuple(np.array([1.2, 1.2, 0.6]) * robots_claim))
        out.append(e_t)
    return {name: np.array([e[name] for e in out]) for name in ("fused", "kuka", "vicon")}


def test_a_short_session_is_fused_without_harm_pooled_over_builds():
    """Issue 57 part 4: in sessions too short to test the sources, the labels pooled over
    builds are no worse than the better source pooled by more than 1%. Build by build two
    sources cannot say which errs more (their differences give only the sum of their
    variances), so some builds are fused to harm; pooled they gain (the sources are alike
    here: 1.56 and 1.40 mm). Robots that claim a quarter of their true sigma pull the labels
    to them, and pooled they lose to motion capture."""
    honest = short_sessions()
    pooled = {name: float(values.mean()) for name, values in honest.items()}
    assert pooled["fused"] <= 1.01 * min(pooled["kuka"], pooled["vicon"]), pooled
    per_build_better = np.minimum(honest["kuka"], honest["vicon"])
    assert np.any(honest["fused"] > 1.01 * per_build_better)  # the sessions include builds fused to harm
    overclaimed = {name: float(values.mean()) for name, values in short_sessions(robots_claim=1 / 4).items()}
    assert overclaimed["fused"] > 1.01 * min(overclaimed["kuka"], overclaimed["vicon"]), overclaimed
