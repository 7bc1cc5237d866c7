"""What fuse measures on the dataset session as a whole, before it fuses any capture
(docs/architecture.md section 6): how much the two sources disagree beyond their sigmas
(the variance factor, as measured and as applied), which source a position axis keeps
where they disagree beyond a consistency test (of the differences' median, and of their
tails: how many captures the rejection test refuses), and the session offset between them.

At the dataset's 3-5 m each source errs mostly by one offset per session (the rail's and
the wand's scale, offsets extrapolated from the calibration's lever), and only the rest
varies from capture to capture. So the offset is removed first and the factor that scales
the sigmas is measured on what is left, which is what fusion averages; the consistency
test sees the differences as measured, offset included: sources whose offsets differ
beyond their sigmas are not fused on that axis.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from core.config import Config
from stages.common import geometry as g
from stages.common.fusion import (
    CONSISTENCY_LEVEL,
    UNIT_FACTOR,
    Sigma,
    VarianceFactor,
    consistency_bound,
    variance_factor,
)
from stages.fuse.kept_axes import SourceFactors, source_factors

if TYPE_CHECKING:
    from stages.fuse.stage import Estimates

#: robust standard deviation of a normal sample from its median absolute deviation
_MAD_TO_SIGMA = 1.482602


class Source(Protocol):
    """What the session's measures need of a calibrated source (``SourceModel``)."""

    def sigma_at(self, pose: np.ndarray, sigma: Sigma | None = None) -> Sigma: ...


def two_source(estimates: list[Estimates]) -> list[Estimates]:
    return [e for e in estimates if e.tracked]


def session_factor(config: Config, estimates: list[Estimates], vicon: Source | None,
                   rejection: Sigma | None) -> tuple[VarianceFactor, str]:
    """The variance factor of the differences as measured on this dataset session (the
    consistency test's), and why it is what it is."""
    if vicon is None or rejection is None:
        return UNIT_FACTOR, "one source: the calibrated sigmas"
    if config.fuse.sigma_scale == "calibration":
        return UNIT_FACTOR, "fuse.sigma_scale = calibration"
    both = two_source(estimates)
    if not both:
        return UNIT_FACTOR, "no capture with both sources: the widened calibrated sigmas"
    predicted = difference_sigmas(both, vicon, rejection)
    if len(both) < config.fuse.min_scale_samples:
        factor = short_session_factor(np.stack([e.kuka for e in both]), np.stack([e.vicon for e in both]), predicted)
        return factor, (f"{len(both)} captures with both sources < fuse.min_scale_samples "
                        f"({config.fuse.min_scale_samples}): their disagreement with a weak prior at the widened "
                        f"calibrated sigmas ({PRIOR_DOF} degrees of freedom), and a Student-t allowance")
    factor = variance_factor(np.stack([e.kuka for e in both]), np.stack([e.vicon for e in both]), predicted)
    return factor, f"robust spread of motion capture against the robots on {len(both)} dataset captures"


#: degrees of freedom of the prior that the (widened) calibrated sigmas hold, in a session
#: too short to measure its factor: weak, two samples' worth
PRIOR_DOF = 2


def short_session_factor(pose_a: np.ndarray, pose_b: np.ndarray, sigma_difference: list[Sigma]) -> VarianceFactor:
    """The variance factor of a short session (fewer captures than a robust factor needs):
    the squared normalised disagreements (each capped at the 99.9% point, so that one
    ghost does not decide) pooled with a scaled inverse chi-square prior at 1 of
    ``PRIOR_DOF`` degrees of freedom (Gelman et al., Bayesian Data Analysis, 3rd ed., 2.6),
    times the Student-t allowance of the predictive interval on that many degrees of
    freedom; never below 1."""
    from scipy.stats import chi2, norm
    from scipy.stats import t as student_t
    n = len(pose_a)
    normalised = (pose_b[:, :3, 3] - pose_a[:, :3, 3]) / np.stack([s.t_m for s in sigma_difference])
    squares = np.minimum(normalised**2, chi2.ppf(0.999, 1))
    dof_t = PRIOR_DOF + n
    t = np.sqrt((PRIOR_DOF + squares.sum(axis=0)) / dof_t) * student_t.ppf(0.975, dof_t) / norm.ppf(0.975)
    angle = g.angular_distance(pose_b[:, :3, :3], pose_a[:, :3, :3])
    # an isotropic rotation error's squared angle over its mean square is chi2_3 / 3
    chi = np.minimum(3 * (angle / np.array([s.r_rad for s in sigma_difference])) ** 2, chi2.ppf(0.999, 3))
    dof_r = PRIOR_DOF + 3 * n
    r = np.sqrt((PRIOR_DOF + chi.sum()) / dof_r) * student_t.ppf(0.975, dof_r) / norm.ppf(0.975)
    return VarianceFactor(np.maximum(t, 1.0), max(float(r), 1.0), n)


def difference_sigmas(both: list[Estimates], vicon: Source, rejection: Sigma) -> list[Sigma]:
    """Per two-source capture, the sigma the variance factor measures the sources' difference
    against: the calibration's (``rejection``) grown to the capture, with motion capture's fit
    and the robots' parameter uncertainty there."""
    return [e.plus_parameters(e.vicon_sigma(vicon, e.kuka, rejection)) for e in both]


def predicted_errors(estimates: list[Estimates], kuka: Source, vicon: Source) -> tuple[np.ndarray, np.ndarray]:
    """The robots' and motion capture's predicted errors per camera axis (3,) m, RMS over the
    session's two-source captures, each from its own measurements there (``better_source``)."""
    both = two_source(estimates)
    return (np.sqrt(np.mean([e.plus_parameters(kuka.sigma_at(e.kuka)).t_m ** 2 for e in both], axis=0)),
            np.sqrt(np.mean([e.vicon_sigma(vicon, e.vicon).t_m ** 2 for e in both], axis=0)))


def better_source(estimates: list[Estimates], kuka: Source, vicon: Source) -> tuple[np.ndarray, str]:
    """Per camera axis (3,) the better source on this session ("kuka" or "vicon"), and the
    evidence in words: the one whose error on the two-source captures each source's own
    measurements there predict the smaller (RMS over the captures). The robots' from their
    calibrated arms' parameter covariance and joints at each configuration; motion
    capture's from its rigid-body fit at each capture (the markers it used, the marker
    noise its own residuals show, the lever to the origin: ``marker_geometry``), not one
    sigma measured at the calibration, where every marker was in view 0.75 m away.

    The differences themselves cannot say which of two sources errs: two variance
    components of the squared differences were tried (Student-t, with a prior at the
    predictions), and on the panelled bus of ``bench targets`` (facility 92) they put motion
    capture's 10-26 mm gross errors on the robots, whose true errors were 0.3 of their
    sigma; with one source's predicted variance nearly constant there is nothing to tell
    them apart by."""
    both = two_source(estimates)
    robots, motion = predicted_errors(estimates, kuka, vicon)
    words = ", ".join(f"{a} {k * 1000:.2f}/{v * 1000:.2f}" for a, k, v in zip("xyz", robots, motion, strict=True))
    return (np.where(robots <= motion, "kuka", "vicon"),
            f"RMS predicted error robots/motion capture on {len(both)} captures (mm): {words}")


@dataclass(frozen=True)
class SessionOffset:
    """Per camera axis (m): motion capture's median excess over the robots on the session,
    its standard error, and the source it is removed from (the worse one, ``better_source``)."""

    t_m: np.ndarray  # (3,)
    sigma_m: np.ndarray  # (3,)
    removed_from: tuple[str, str, str]
    why: str
    estimated: bool = True  # False: nothing removed (one source, switched off, too few captures)
    #: (3, P) the mean over the captures the median was taken on of the robots' position
    #: Jacobian by the arms' parameters (``ArmUncertainty``; None without calibrated arms)
    mean_jacobian_t: np.ndarray | None = None

    def robots(self, pose: np.ndarray) -> np.ndarray:
        """The robots' ``cam_from_target`` (4, 4), the offset added where they are the worse source."""
        out = pose.copy()
        out[:3, 3] += np.where([source == "kuka" for source in self.removed_from], self.t_m, 0.0)
        return out

    def motion_capture(self, pose: np.ndarray) -> np.ndarray:
        """Motion capture's ``cam_from_target`` (4, 4), the offset removed where it is the worse source."""
        out = pose.copy()
        out[:3, 3] -= np.where([source == "vicon" for source in self.removed_from], self.t_m, 0.0)
        return out


NO_OFFSET = SessionOffset(np.zeros(3), np.zeros(3), ("vicon",) * 3, "", estimated=False)


def session_offset(config: Config, estimates: list[Estimates], kuka: Source, vicon: Source | None) -> SessionOffset:
    """The median difference (motion capture minus robots, per camera axis) over the
    session's two-source captures: a median, so that ghost markers, which the rejection test
    has not yet removed, barely move it.

    Why: inverse-variance fusion treats errors as independent from capture to capture;
    fusing two session offsets helps on average but harms wherever the better source drew
    the smaller one, which two sources cannot see. With the difference of the offsets
    removed from the worse source (``better_source``), the labels keep the better's own offset and fuse
    only what varies between captures, which the session's many captures do average. The
    standard error is the median's, ``sqrt(pi / 2)`` times the mean's, from the differences'
    own robust spread (their median absolute deviation)."""
    if vicon is None or config.fuse.session_offset == "off":
        return dataclasses.replace(NO_OFFSET, why="one source" if vicon is None else "fuse.session_offset = off")
    both = two_source(estimates)
    if len(both) < config.fuse.min_scale_samples:
        return dataclasses.replace(NO_OFFSET, why=f"{len(both)} two-source captures < "
                                   f"fuse.min_scale_samples ({config.fuse.min_scale_samples}): none removed")
    difference = np.stack([e.vicon[:3, 3] - e.kuka[:3, 3] for e in both])
    offset = np.median(difference, axis=0)
    spread = _MAD_TO_SIGMA * np.median(np.abs(difference - offset), axis=0)
    sigma = np.sqrt(np.pi / 2) * spread / np.sqrt(len(both))
    larger = tuple("vicon" if source == "kuka" else "kuka" for source in better_source(estimates, kuka, vicon)[0])
    words = ", ".join(f"{a} {o * 1000:+.2f} +- {e * 1000:.2f}" for a, o, e in zip("xyz", offset, sigma, strict=True))
    jacobians = [e.arm.jacobian_t for e in both if e.arm is not None]
    return SessionOffset(offset, sigma, larger, f"median of motion capture minus robots on {len(both)} captures "
                         f"(mm): {words}; removed from {'/'.join(larger)}",
                         mean_jacobian_t=np.mean(jacobians, axis=0) if jacobians else None)


#: the level of the test of the disagreements' tails (``Rejections``): stricter than the
#: median's (``CONSISTENCY_LEVEL``), since a ghost or two is the rejection test's job, not a
#: reason to give up fusion
TAIL_LEVEL = 0.975


@dataclass(frozen=True)
class Rejections:
    """How many of the session's two-source captures the rejection test refuses, against
    what sources whose (factor-scaled) sigmas hold would give: each capture is refused with
    probability ``p = 1 - (1 - 2 Q(k))^3 P(chi2_3 <= 3 k^2)`` (three position components
    and the angle, whose square over its mean square is chi2_3 / 3), so the count is
    Binomial(n, p); ``bound`` is its ``TAIL_LEVEL`` quantile (None: not tested)."""

    count: int
    samples: int
    bound: int | None

    @property
    def inconsistent(self) -> bool:
        return self.bound is not None and self.count > self.bound


def rejections(estimates: list[Estimates], vicon: Source | None, rejection: Sigma | None,
               factor: VarianceFactor, k: float, offset: SessionOffset, min_samples: int) -> Rejections:
    """The rejection test's count on the session (``Estimates.rejection``, with the factor
    and offset that fusion applies), and its bound when there are ``min_samples`` or more."""
    from scipy.stats import binom, chi2, norm
    both = two_source(estimates)
    if vicon is None or rejection is None or not both:
        return Rejections(0, len(both), None)
    count = sum(e.rejection(vicon, rejection, factor, k, offset) is not None for e in both)
    if len(both) < min_samples:
        return Rejections(count, len(both), None)
    refused = 1.0 - (1.0 - 2.0 * norm.sf(k)) ** 3 * chi2.cdf(3.0 * k**2, 3)
    return Rejections(count, len(both), int(binom.ppf(TAIL_LEVEL, len(both), refused)))


def axis_sources(config: Config, estimates: list[Estimates], kuka: Source, vicon: Source | None,
                 factor: VarianceFactor, refused: Rejections) -> tuple[tuple[str, str, str], str]:
    """Per camera axis, where the labels' position comes from (``AXIS_SOURCES``), and why.

    Inverse-variance fusion holds where both sources err as normal laws at their sigmas.
    Two tests ask whether they do on this session: the core of the disagreements (``factor``,
    as measured, fails ``VarianceFactor.inconsistent`` on that axis) and their tails (more
    captures refused by the rejection test than ``refused.bound``, on every axis). Failing
    either, one source errs beyond its sigma; where it is the tails, the captures the test
    accepts come from the same heavy-tailed law (the test cuts at ``k`` sigma, and a gross
    error of a few sigma passes it), so fusing would let the worse pull the better. The
    better source on that axis, as each source's own measurements predict it
    (``better_source``), is kept alone."""
    if vicon is None or config.fuse.inconsistent_axes == "fuse":
        return ("fused",) * 3, ("one source" if vicon is None else "fuse.inconsistent_axes = fuse")
    if factor.samples < config.fuse.min_scale_samples:  # a short session's factor is not the test's median
        return ("fused",) * 3, (f"{factor.samples} two-source captures < fuse.min_scale_samples: too few to test "
                                "the sources' consistency; fused with the widened sigmas")
    inconsistent = factor.inconsistent() | refused.inconsistent
    better, evidence = better_source(estimates, kuka, vicon)
    sources = tuple(str(better[axis]) if inconsistent[axis] else "fused" for axis in range(3))
    reasons = [f"{name}: factor {factor.t[axis]:.3f} > {consistency_bound(factor.samples):.3f} (what "
               f"{CONSISTENCY_LEVEL:.0%} of consistent sources stay under on {factor.samples} captures): "
               f"{sources[axis]} alone" for axis, name in enumerate("xyz") if factor.inconsistent()[axis]]
    if refused.inconsistent:
        reasons.append(f"{refused.count} of {refused.samples} captures refused by the rejection test > "
                       f"{refused.bound} (what {TAIL_LEVEL:.0%} of consistent sources stay under): "
                       f"{'/'.join(sources)}")
    if not reasons:
        return sources, "the sources agree within their sigmas on every axis"
    return sources, f"{'; '.join(reasons)} ({evidence})"


def applied_factor(estimates: list[Estimates], vicon: Source | None, rejection: Sigma | None,
                   measured: VarianceFactor, offset: SessionOffset) -> VarianceFactor:
    """The factor that scales the sigmas, measured on the differences with the session
    offset removed: what is fused is what varies between captures, and its excess over the
    sigmas is common to both sources. The offset's own uncertainty is added in
    ``fuse_capture``.

    On an axis kept from one source each source's share of the excess is judged from this
    factor, not the one as measured (``kept_axes``): the kept source carries its own offset,
    whose size its calibrated sigma already holds, and given the measured difference of the
    two offsets, the share expected of the kept one is ``o_k^2 / (o_k^2 + o_v^2)`` of it (the
    offsets' prior variances): at 3-5 m motion capture's (its wand's scale, about 1 mm) is
    several times the robots' (about 0.45 mm in depth), so the expected square of the kept
    offset barely exceeds its prior. The rotation's factor is as measured (no offset is
    removed from the rotations)."""
    both = two_source(estimates)
    if vicon is None or rejection is None or measured.samples == 0 or not both or not offset.estimated:
        return measured
    predicted = difference_sigmas(both, vicon, rejection)
    centred = variance_factor(np.stack([offset.robots(e.kuka) for e in both]),
                              np.stack([offset.motion_capture(e.vicon) for e in both]), predicted)
    return VarianceFactor(centred.t, measured.r, measured.samples)


@dataclass(frozen=True)
class SessionFusion:
    """Everything fuse decides on the session as a whole, before any capture is fused."""

    measured: VarianceFactor  # the consistency test's (offset included)
    why: str
    offset: SessionOffset
    factor: VarianceFactor  # what scales the sigmas (``applied_factor``)
    refused: Rejections
    sources: tuple[str, str, str]
    sources_why: str
    #: each source's own factor: ``factor`` on a fused axis, its expected share on a kept one
    by_source: SourceFactors


def session_fusion(config: Config, estimates: list[Estimates], kuka: Source, vicon: Source | None,
                   rejection: Sigma | None) -> SessionFusion:
    """The session's measures in the order they depend on each other: the factor as
    measured, the offset, the factor applied, the rejection test's count, the axes' sources,
    each source's own factor (``kept_axes``)."""
    measured, why = session_factor(config, estimates, vicon, rejection)
    offset = session_offset(config, estimates, kuka, vicon)
    factor = applied_factor(estimates, vicon, rejection, measured, offset)
    refused = rejections(estimates, vicon, rejection, factor, config.fuse.rejection_k, offset,
                         config.fuse.min_scale_samples)
    sources, sources_why = axis_sources(config, estimates, kuka, vicon, measured, refused)
    by_source = kept_factors(config, estimates, kuka, vicon, rejection, factor, sources)
    return SessionFusion(measured, why, offset, factor, refused, sources, sources_why, by_source)


def kept_factors(config: Config, estimates: list[Estimates], kuka: Source, vicon: Source | None,
                 rejection: Sigma | None, factor: VarianceFactor, sources: tuple[str, str, str]) -> SourceFactors:
    """Each source's own factor (``kept_axes``): ``factor``'s on every axis but those kept
    from one source, where each takes its expected share of the excess, judged against the
    sigmas the factor was measured against (``difference_sigmas``, RMS over the captures)."""
    if vicon is None or rejection is None or all(source == "fused" for source in sources):
        return SourceFactors.common(factor.t)
    difference = np.sqrt(np.mean([s.t_m**2 for s in difference_sigmas(two_source(estimates), vicon, rejection)],
                                 axis=0))
    return source_factors(factor.t, factor.samples, sources, *predicted_errors(estimates, kuka, vicon), difference,
                          config.fuse.sigma_doubt)
