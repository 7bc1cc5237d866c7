"""Fusion that does no harm: seeded two-source sessions at the dataset's 4 m where one source's
depth errs beyond its calibrated sigma, from capture to capture or by one offset for the
whole session. Fuse must then stay within 1% of the better source (mean E_T) and keep its
sigmas covering the errors; where both sigmas hold it fuses every axis."""

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import pytest

from core.config import parse_override, with_overrides
from pipeline.config import default_config
from stages.common import geometry as g
from stages.common.fusion import Sigma
from stages.fuse.session import kept_factors
from stages.fuse.stage import (
    ArmUncertainty,
    Estimates,
    applied_factor,
    axis_sources,
    fuse_capture,
    rejections,
    session_factor,
    session_fusion,
    session_offset,
)

CAPTURES = 48
SEEDS = range(6)


@dataclass(frozen=True)
class Calibrated:
    """A source as fuse sees it: its calibrated sigma, not grown with the lever (the test
    puts every capture at the calibration's lever)."""

    sigma: Sigma
    calibration_lever_sq: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))

    def sigma_at(self, pose: np.ndarray, sigma: Sigma | None = None) -> Sigma:
        return self.sigma if sigma is None else sigma


def session(seed: int, kuka_true_mm, vicon_true_mm, vicon_offset_mm=(0.0, 0.0, 0.0), arm=None, gross=None):
    """48 captures 3-5 m away; each source errs with the given 1-sigma per camera axis, and
    motion capture also by one offset for the whole session (its wand's scale at range).
    ``arm``: the robots' uncertainty from their calibrated parameters, drawn once for the
    session (``ArmUncertainty``: the position block of its covariance). ``gross``: (share,
    low mm, high mm): that share of motion capture's captures errs instead by a length
    drawn between the two, in any direction (a fit on few markers with a short lever)."""
    rng = np.random.default_rng(seed)
    shared = np.zeros(3) if arm is None else arm.jacobian_t @ rng.multivariate_normal(np.zeros(len(arm.parameters)),
                                                                                        arm.parameters)
    truths, estimates = [], []
    for index in range(CAPTURES):
        true = g.make_transform(g.rotvec_to_matrix(rng.normal(scale=0.5, size=3)),
                                [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(3.0, 5.0)])
        kuka, vicon = true.copy(), true.copy()
        kuka[:3, 3] += rng.normal(size=3) * np.asarray(kuka_true_mm) / 1000 + shared
        vicon[:3, 3] += (rng.normal(size=3) * np.asarray(vicon_true_mm) + vicon_offset_mm) / 1000
        if gross is not None and rng.uniform() < gross[0]:
            direction = rng.normal(size=3)
            vicon[:3, 3] = true[:3, 3] + rng.uniform(*gross[1:]) / 1000 * direction / np.linalg.norm(direction)
        truths.append(true)
        estimates.append(Estimates({"sample_id": f"d{index:03d}"}, kuka, vicon, arm))
    return truths, estimates


def fused_session(seed, kuka_true_mm, vicon_true_mm, policy="fall_back", vicon_offset_mm=(0.0, 0.0, 0.0),
                  offset="on", vicon_sigma_mm=(3.5, 3.5, 0.9), scale_by="applied", arm=None, kuka_sigma_mm=None,
                  declared=True, gross=None, shares=True):
    """Mean E_T (mm) of fused, robots, motion capture (and their depth's rms error, mm);
    errors / sigmas (N, 3); sources. ``scale_by``: the factor fuse applies, or the one as
    measured (offset included). ``shares``: a kept source's sigma scaled by its own share of
    the excess (``kept_axes``), else by the common factor."""
    config = with_overrides(default_config(), [parse_override(f"fuse.inconsistent_axes={policy}"),
                                       parse_override(f"fuse.session_offset={offset}")])
    kuka = Calibrated(Sigma(np.asarray(kuka_sigma_mm or (1.2, 1.2, 0.6)) / 1000, 1e-4))
    vicon = Calibrated(Sigma(np.asarray(vicon_sigma_mm) / 1000, 1e-3))
    rejection = Sigma(np.hypot(kuka.sigma.t_m, vicon.sigma.t_m), float(np.hypot(1e-4, 1e-3)))
    truths, estimates = session(seed, kuka_true_mm, vicon_true_mm, vicon_offset_mm, arm, gross)
    factor, _ = session_factor(config, estimates, vicon, rejection)
    removed = session_offset(config, estimates, kuka, vicon)
    refused = rejections(estimates, vicon, rejection, applied_factor(estimates, vicon, rejection, factor, removed),
                         1.96, removed, config.fuse.min_scale_samples)
    sources, _ = axis_sources(config, estimates, kuka, vicon, factor, refused)
    if not declared:  # no shared part: each capture's own Jacobian against a mean that is zero
        removed = dataclasses.replace(removed, mean_jacobian_t=np.zeros_like(removed.mean_jacobian_t))
        estimates = [dataclasses.replace(e, arm=dataclasses.replace(e.arm, jacobian_t=np.zeros_like(
            e.arm.jacobian_t))) for e in estimates]
    applied = applied_factor(estimates, vicon, rejection, factor, removed) if scale_by == "applied" else factor
    by_source = kept_factors(config, estimates, kuka, vicon, rejection, applied, sources) if shares else None
    rows = [fuse_capture(e, kuka, vicon, rejection, applied, 1.96, sources, removed, by_source) for e in estimates]
    true_t = np.stack([t[:3, 3] for t in truths])
    fused = np.stack([r["cam_from_target_t"] for r in rows])
    positions = (("fused", fused), ("kuka", np.stack([e.kuka[:3, 3] for e in estimates])),
                 ("vicon", np.stack([e.vicon[:3, 3] for e in estimates])))
    e_t = {name: float(np.linalg.norm(p - true_t, axis=1).mean() * 1000) for name, p in positions}
    e_t.update({f"{name} depth rms": float(np.sqrt(np.mean((p - true_t)[:, 2] ** 2)) * 1000) for name, p in positions})
    return e_t, (fused - true_t) / np.stack([r["sigma_t_m"] for r in rows]), sources


# robots 1.1 / 1.1 / 0.35 mm, motion capture 3 / 3 / 2.7 mm: its depth errs 3x beyond its 0.9 mm
MOCAP_DEPTH_OFF = ([1.1, 1.1, 0.35], [3.0, 3.0, 2.7])
# robots' depth 1.6 mm where they claim 0.6 (a rail scale the prior did not foresee)
ROBOTS_DEPTH_OFF = ([1.1, 1.1, 1.6], [3.0, 3.0, 0.9])


@pytest.mark.parametrize("errors", [MOCAP_DEPTH_OFF, ROBOTS_DEPTH_OFF], ids=["mocap depth", "robots depth"])
def test_a_source_whose_depth_errs_beyond_its_sigma_does_no_harm(errors):
    normalised = []
    for seed in SEEDS:
        e_t, errors_over_sigma, sources = fused_session(seed, *errors)
        assert sources[:2] == ("fused", "fused"), sources
        if errors == MOCAP_DEPTH_OFF:  # 3x beyond its sigma: always caught, the smaller sigma kept alone
            assert sources[2] == "kuka", sources
        assert e_t["fused"] <= 1.01 * min(e_t["kuka"], e_t["vicon"]), (seed, e_t)
        normalised.append(errors_over_sigma)
    pooled = np.concatenate(normalised)
    inside = np.mean(np.abs(pooled) <= 1.96, axis=0)
    if errors == MOCAP_DEPTH_OFF:
        assert np.all(inside >= 0.9), inside
    else:  # the kept robots' depth, 2.7x off, takes only its likely share of the excess: covered less
        assert np.all(inside[:2] >= 0.9) and inside[2] >= 0.7, inside


# facility 33's case: the robots' depth errs 0.3 mm where they claim 0.6, motion capture's
# 1.2 mm where it claims 1.5, plus one offset of 1 mm for the whole session (its wand's
# scale at 4 m), too small for the consistency test to see on 48 captures
ROBOTS_LUCKY = ([1.1, 1.1, 0.3], [3.0, 3.0, 1.2])
MOCAP_SIGMA_MM = (3.5, 3.5, 1.5)


def test_a_session_offset_of_motion_capture_does_not_reach_the_labels():
    for seed in SEEDS:
        plain, _, plain_sources = fused_session(seed, *ROBOTS_LUCKY, vicon_sigma_mm=MOCAP_SIGMA_MM)
        shifted, normalised, sources = fused_session(seed, *ROBOTS_LUCKY, vicon_offset_mm=(0.0, 0.0, 1.0),
                                                     vicon_sigma_mm=MOCAP_SIGMA_MM)
        assert sources == plain_sources == ("fused", "fused", "fused"), (sources, plain_sources)
        # the same labels but for the captures the rejection test then takes (the factor grew)
        assert shifted["fused depth rms"] == pytest.approx(plain["fused depth rms"], rel=0.02)
        assert shifted["fused"] <= 1.01 * shifted["kuka"], (seed, shifted)
        assert np.all(np.mean(np.abs(normalised) <= 1.96, axis=0) >= 0.85)  # the band for 48 labels


def test_fusing_a_session_offset_as_measured_does_harm():
    """What removing it prevents: the same sessions fused as measured (the paper)."""
    kept, fused = ([fused_session(seed, *ROBOTS_LUCKY, vicon_offset_mm=(0.0, 0.0, 1.0), vicon_sigma_mm=MOCAP_SIGMA_MM,
                                  offset=offset)[0]["fused depth rms"] for seed in SEEDS] for offset in ("on", "off"))
    assert np.mean(np.array(fused) / np.array(kept)) > 1.05, (kept, fused)


def test_plain_fusion_is_harmed_where_motion_capture_depth_is_off():
    """What the fall-back prevents: fusing the depth lets motion capture pull the robots."""
    worse = [fused_session(seed, *MOCAP_DEPTH_OFF, policy="fuse")[0] for seed in SEEDS]
    assert np.mean([e["fused"] / e["kuka"] for e in worse]) > 1.03


def test_sources_whose_sigmas_hold_are_fused_on_every_axis():
    for seed in SEEDS:
        e_t, errors_over_sigma, sources = fused_session(seed, [1.1, 1.1, 0.5], [3.0, 3.0, 0.8])
        assert sources == ("fused", "fused", "fused")
        assert e_t["fused"] < e_t["kuka"]


# both sources' capture-to-capture errors as their sigmas say; motion capture's depth also
# off by one offset of 2 mm for the session (twice its sigma), which the consistency test sees
HONEST = ([1.2, 1.2, 0.6], [3.5, 3.5, 0.9])


def depth_rms(scale_by: str) -> tuple[float, float]:
    """Pooled over the seeds: rms(error / sigma) and the share inside 1.96 sigma in depth."""
    normalised = np.concatenate([fused_session(seed, *HONEST, vicon_offset_mm=(0.0, 0.0, 2.0),
                                               scale_by=scale_by)[1][:, 2] for seed in SEEDS])
    return float(np.sqrt(np.mean(normalised**2))), float(np.mean(np.abs(normalised) <= 1.96))


def test_a_session_offset_does_not_inflate_the_sigmas_of_the_labels_that_do_not_carry_it():
    """The factor that scales the sigmas is measured with the offset removed: the labels'
    depth sigmas stay honest (rms 0.8-1.2, 90-99% inside, the issue's pooled bands), where
    the factor as measured would have put motion capture's offset on the robots' sigma."""
    rms, inside = depth_rms("applied")
    assert 0.8 <= rms <= 1.2 and 0.9 <= inside <= 0.99, (rms, inside)
    inflated, _ = depth_rms("measured")
    assert inflated < 0.75 * rms, (inflated, rms)


def shared_depth_rms(declared: bool) -> float:
    """rms(error / sigma) in depth over 60 sessions whose robots err by 0.45 mm through one
    parameter error shared by the session plus 0.2 mm of their own, motion capture by
    0.5 mm; ``declared``: fuse is told the parameter's share, else it takes it as
    independent between captures."""
    covariance = np.zeros((6, 6))
    covariance[5, 5] = 0.45e-3**2
    jacobian = np.array([[0.0], [0.0], [1.0]])
    parameters = np.array([[0.45e-3**2]])
    drawn = ArmUncertainty(covariance, jacobian, parameters)
    normalised = []
    for seed in range(60):
        _, normalised_errors, _ = fused_session(
            seed, [1.2, 1.2, 0.2], [3.5, 3.5, 0.5], kuka_sigma_mm=(1.2, 1.2, 0.2), vicon_sigma_mm=(3.5, 3.5, 0.5),
            arm=drawn, declared=declared)
        normalised.append(normalised_errors[:, 2])
    return float(np.sqrt(np.mean(np.concatenate(normalised) ** 2)))


def test_the_robots_error_shared_by_the_session_stays_in_the_labels_sigma():
    """With motion capture's median difference removed, the robots' shared error reaches
    both sources and fusion cannot average it: the labels' depth sigma keeps it."""
    honest = shared_depth_rms(declared=True)
    assert 0.85 <= honest <= 1.15, honest
    assert shared_depth_rms(declared=False) > 1.15 * honest  # taken as independent: overconfident


# the panelled bus of ``bench targets`` on facility 92: motion capture at its sigma on two
# captures in three, and 6-30 mm off on the third (markers on a small body, a short lever);
# the robots err by two thirds of their sigma
HEAVY_TAIL = dict(kuka_true_mm=[0.8, 0.8, 0.4], vicon_true_mm=[3.5, 3.5, 0.9], gross=(0.35, 6.0, 30.0))


def refused_count(seed: int, kuka_true_mm, vicon_true_mm, gross=None):
    """The consistency tests' verdicts on a session: the median's per axis, the tails'."""
    config = default_config()
    kuka = Calibrated(Sigma(np.array([1.2, 1.2, 0.6]) / 1000, 1e-4))
    vicon = Calibrated(Sigma(np.array([3.5, 3.5, 0.9]) / 1000, 1e-3))
    rejection = Sigma(np.hypot(kuka.sigma.t_m, vicon.sigma.t_m), float(np.hypot(1e-4, 1e-3)))
    _, estimates = session(seed, kuka_true_mm, vicon_true_mm, gross=gross)
    fusion = session_fusion(config, estimates, kuka, vicon, rejection)
    return fusion.measured.inconsistent(), fusion.refused


def test_a_motion_capture_with_a_heavy_tail_is_not_fused():
    """Where the rejection test refuses more captures than consistent sources would, the
    accepted ones' gross errors inside 1.96 sigma would pull the labels: fuse keeps the
    robots on every axis. On most of these sessions the median of the disagreements passes
    on some axis, and the tails' test is what keeps the robots there."""
    caught = 0
    for seed in range(12):
        median_fails, refused = refused_count(seed, **HEAVY_TAIL)
        e_t, _, sources = fused_session(seed, **HEAVY_TAIL)
        assert e_t["fused"] <= 1.01 * e_t["kuka"], (seed, e_t)
        if refused.inconsistent:
            assert sources == ("kuka", "kuka", "kuka"), (seed, sources)
            caught += not median_fails.all()
    assert caught >= 6, caught


def test_fusing_a_heavy_tailed_motion_capture_does_harm():
    """What the tails' test prevents: the same sessions fused on every axis."""
    ratios = [(lambda e: e["fused"] / e["kuka"])(fused_session(seed, **HEAVY_TAIL, policy="fuse")[0])
              for seed in range(12)]
    assert np.mean(ratios) > 1.02, ratios


def test_the_tails_test_seldom_refuses_consistent_sources():
    """At its 97.5% level, over 200 sessions whose sources err as their sigmas say."""
    flagged = [refused_count(seed, [1.2, 1.2, 0.6], [3.5, 3.5, 0.9])[1].inconsistent for seed in range(200)]
    assert np.mean(flagged) <= 0.03, np.mean(flagged)
