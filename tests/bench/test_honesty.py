"""The statistics ``bench honesty`` judges the sigmas by: errors that share a facility's
calibration, and what honest sigmas give under that sharing."""

import numpy as np
import pytest
from scipy.stats import norm

from bench.honesty import common_share, honest_odds


@pytest.mark.parametrize("share", [0.0, 0.3, 0.8])
def test_common_share_recovers_the_shared_variance(share: float) -> None:
    rng = np.random.default_rng(7)
    facilities = [np.sqrt(share) * rng.standard_normal() + np.sqrt(1 - share) * rng.standard_normal(48)
                  for _ in range(400)]
    assert common_share(facilities) == pytest.approx(share, abs=0.08)


def test_common_share_ignores_the_sigma_scale() -> None:
    """A share, not a variance: sigmas twice too small leave it unchanged."""
    rng = np.random.default_rng(8)
    facilities = [0.7 * rng.standard_normal() + 0.7 * rng.standard_normal(48) for _ in range(300)]
    assert common_share([2 * u for u in facilities]) == pytest.approx(common_share(facilities), abs=1e-12)


def test_independent_errors_keep_every_honest_facility_in_its_band() -> None:
    odds = honest_odds(0.0, 48, 13)
    assert odds["facility outside rms-band"] < 0.01
    assert 0.93 < odds["pooled rms 2.5%"] < 1.0 < odds["pooled rms 97.5%"] < 1.07


def test_one_shared_draw_makes_a_facility_a_lottery() -> None:
    """All of the error common: a facility's rms is |N(0, 1)|, inside 0.7-1.4 with
    probability 2 (Phi(1.4) - Phi(0.7)); its labels are all inside 1.96 sigma or none."""
    odds = honest_odds(1.0, 48, 13)
    assert odds["facility outside rms-band"] == pytest.approx(1 - 2 * (norm.cdf(1.4) - norm.cdf(0.7)), abs=0.01)
    assert odds["facility outside inside-band"] == pytest.approx(0.05, abs=0.006)
    assert odds["pooled rms 2.5%"] < 0.7 and odds["pooled rms 97.5%"] > 1.3
