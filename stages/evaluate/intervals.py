"""How far Table 2's figures would move with another draw of images: bootstrap (BCa)
intervals, stratified by configuration (view x light), for means and for paired
differences between two models on the same images (Efron and Tibshirani, An Introduction
to the Bootstrap, 1993, chapters 13 and 3.3 (stratified sampling); a paired difference is
the bootstrap of the per-image differences, which cancels what two models share: the
image's difficulty).

A figure's configuration mix is part of the experiment (the plan fixes how many images each
configuration gets), so each resample draws every configuration's mean from that
configuration's images only: ``n - 1`` draws of its ``n`` (McCarthy and Snowden 1985: the
mean of ``n`` draws would show ``(n - 1) / n`` of its mean's variance, 0.92 for 12 images),
so that a resample stays among the values seen (a mean score is never negative). A
configuration of one image adds no spread.

The decoder draws too (RANSAC). An image's value is its score averaged over the poses
decoded under ``evaluate.ransac_seeds`` seeds, an estimate of its expected score over the
decoder's draws; resampling the images resamples their draws with them, which is the
nearly unbiased way to bootstrap such two-stage data (Davison and Hinkley, Bootstrap
Methods and their Application, 1997, section 3.8: resampling the draws again within each
image would count their spread twice). So each interval holds the decoder's spread, and
averaging seeds makes the figure itself move less from one seed to another. The
resamples are seeded from the figure's name, so an interval is the same bytes whatever
the order the figures are computed in or the images come in.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

#: resamples per interval: the 2.5% and 97.5% points of 4000 move by about 1% of the
#: interval's width between seeds
RESAMPLES = 4000
LEVEL = 0.95
#: an estimate that no longer says where the target is (SPEED+'s and SPNv2's practice is
#: to report these as misses): rotation error over 10 deg or translation over 10% of the range
FAILURE_ROTATION_DEG = 10.0
FAILURE_TRANSLATION = 0.10


@dataclass(frozen=True)
class Interval:
    """A statistic and its ``LEVEL`` percentile-bootstrap interval."""

    value: float
    low: float
    high: float


def seed_of(name: str) -> int:
    """A resampling seed from a figure's name (stable across runs and processes)."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")


def _resampled_means(values: np.ndarray, strata: Sequence[str], seed: int) -> np.ndarray:
    """(RESAMPLES,) means of stratified resamples of ``values`` (N,)."""
    rng = np.random.default_rng(seed)
    labels = np.asarray(strata)
    total = np.zeros(RESAMPLES)
    for stratum in sorted(set(strata)):
        members = np.sort(values[labels == stratum])  # the multiset decides, not the order
        draws = max(len(members) - 1, 1)
        picks = rng.integers(0, len(members), size=(RESAMPLES, draws))
        total += len(members) * members[picks].mean(axis=1)
    return total / len(values)


def mean_interval(values: Sequence[float], strata: Sequence[str], name: str) -> Interval:
    """The mean of ``values`` (N,) and its stratified bootstrap interval; ``strata`` (N,)
    the configuration of each value, ``name`` the figure's (it seeds the resamples)."""
    values = np.asarray(values, float)
    if len(values) == 0:
        raise ValueError(f"{name}: no values")
    # one canonical order (stratum, value): the last bits never depend on the rows' order
    order = np.lexsort((values, np.asarray(strata)))
    values, strata = values[order], [strata[i] for i in order]
    mean = math.fsum(values) / len(values)
    means = _resampled_means(values, strata, seed_of(name))
    low, high = np.quantile(means, _bca_levels(values, strata, means, mean))
    return Interval(mean, float(min(low, mean)), float(max(high, mean)))


def _bca_levels(values: np.ndarray, strata: Sequence[str], means: np.ndarray, mean: float) -> tuple[float, float]:
    """The BCa interval's quantile levels (Efron 1987; Efron and Tibshirani 14.3): the
    percentile interval corrected for the resamples' median bias ``z0`` and for the skew of
    the mean's law (the acceleration ``a``, from each value's influence, its deviation from
    its stratum's mean). Scores are skewed (a few misses far out), and on 12 images a
    configuration the plain percentile interval covers about 90%, not 95%."""
    # the standard normal of the standard library: scipy.stats would cost every evaluate 0.5 s
    # of imports, and the two agree to 1.3e-15 on these levels
    norm = NormalDist()
    labels = np.asarray(strata)
    influence = values.copy()
    for stratum in set(strata):
        chosen = labels == stratum
        influence[chosen] -= values[chosen].mean()
    spread = float(np.sum(influence**2))
    if spread == 0.0:
        return (1 - LEVEL) / 2, (1 + LEVEL) / 2
    acceleration = float(np.sum(influence**3)) / (6.0 * spread**1.5)
    below = float(np.mean(means < mean)) + 0.5 * float(np.mean(means == mean))
    z0 = float(norm.inv_cdf(np.clip(below, 1.0 / RESAMPLES, 1.0 - 1.0 / RESAMPLES)))
    levels = []
    for tail in ((1 - LEVEL) / 2, (1 + LEVEL) / 2):
        z = z0 + norm.inv_cdf(tail)
        with np.errstate(divide="ignore"):  # a * z = 1: the level goes to its bound, as under numpy's division
            shifted = z0 + float(np.divide(z, 1.0 - acceleration * z))
        levels.append(float(norm.cdf(shifted)))
    return levels[0], levels[1]


def paired_interval(model: Sequence[float], reference: Sequence[float], strata: Sequence[str],
                    name: str) -> Interval:
    """Mean of ``model - reference`` over the same images (N,) and its stratified bootstrap
    interval: below zero where the model scores lower (better) than the reference."""
    difference = np.asarray(model, float) - np.asarray(reference, float)
    return mean_interval(difference, strata, name)


def seed_means(rows: Sequence[dict], key: str) -> np.ndarray:
    """Each prediction's score ``key`` (``speed`` or ``speedplus``) averaged over the poses
    decoded under its RANSAC seeds (N,); a row without them (written before they were
    recorded), its one score."""
    return np.array([math.fsum(row[f"score_{key}_seeds"]) / len(row[f"score_{key}_seeds"])
                     if row.get(f"score_{key}_seeds") else row[f"score_{key}"] for row in rows], float)


def failed(err_q_rad: Sequence[float], err_t_norm: Sequence[float]) -> np.ndarray:
    """(N,) bool: the estimate missed (``FAILURE_ROTATION_DEG``, ``FAILURE_TRANSLATION``)."""
    return ((np.degrees(np.asarray(err_q_rad, float)) > FAILURE_ROTATION_DEG)
            | (np.asarray(err_t_norm, float) > FAILURE_TRANSLATION))
