"""The yardstick ``bench honesty`` judges the sigmas by: what honest sigmas show on a
facility whose labels share the errors of one calibration (``bench/honest_odds.py``)."""

import numpy as np
import pytest
from scipy.stats import norm

from bench.honest_odds import FacilityModel, HonestDraws, draw, pooled_range

CAPTURES = 48


def model(shared_m: float, own_m: float, vicon_m: float = 0.0, weight: float = 0.0,
          offset_removed: bool = False) -> FacilityModel:
    """A facility of 48 captures whose robots err in depth by one parameter shared by every
    capture (``shared_m`` 1-sigma, the same at each) and by their own noise ``own_m``;
    sideways by their own 1 mm alone."""
    jacobian = np.zeros((CAPTURES, 3, 13))
    jacobian[:, 2, 12] = 1.0  # a parameter past the 12 joint offsets, which the lost motion drives
    return FacilityModel(jacobian, np.diag([0.0] * 12 + [shared_m**2]), np.zeros((CAPTURES, 12)), np.arange(12),
                         np.tile([1e-3, 1e-3, own_m], (CAPTURES, 1)), np.full((CAPTURES, 3), vicon_m),
                         np.full((CAPTURES, 3), weight), offset_removed)


def test_independent_errors_keep_every_honest_facility_in_its_bands():
    odds = draw(model(0.0, 1e-3), 4000, 1).probabilities()
    assert np.all(odds["rms under"] < 0.01) and np.all(odds["rms over"] < 0.01)
    assert np.all(odds["inside under"] < 0.02)


def test_one_shared_draw_makes_a_facility_a_lottery():
    """All of the depth error shared: a facility's rms is |N(0, 1)|, under 0.7 with
    probability 2 Phi(0.7) - 1 and over 1.4 with 2 (1 - Phi(1.4)); lateral axes untouched."""
    odds = draw(model(1e-3, 0.0), 8000, 2).probabilities()
    assert odds["rms under"][2] == pytest.approx(2 * norm.cdf(0.7) - 1, abs=0.02)
    assert odds["rms over"][2] == pytest.approx(2 * (1 - norm.cdf(1.4)), abs=0.01)
    assert odds["rms under"][0] < 0.01


def test_fusing_with_the_offset_removed_keeps_the_shared_error():
    """Motion capture's difference from the robots, its median removed, carries the robots'
    shared error into both sources: fused, the labels still share it, as fuse's sigma says
    (``offset_variance``); fused as measured, the shared part is averaged like the rest."""
    kept = draw(model(1e-3, 0.2e-3, vicon_m=1e-3, weight=0.5, offset_removed=True), 4000, 3).probabilities()
    averaged = draw(model(1e-3, 0.2e-3, vicon_m=1e-3, weight=0.5), 4000, 3).probabilities()
    assert kept["rms under"][2] > 0.4 > averaged["rms under"][2]


def test_the_seen_rms_is_placed_among_honest_facilities():
    honest = draw(model(0.5e-3, 0.5e-3), 4000, 4)
    median = np.median(np.sqrt(honest.mean_square), axis=0)
    assert honest.percentile(median) == pytest.approx([0.5, 0.5, 0.5], abs=0.01)
    assert np.all(honest.percentile(2 * median) > 0.97) and np.all(honest.percentile(0.5 * median) < 0.03)


def test_the_pooled_range_narrows_with_facilities_and_holds_one():
    honest: HonestDraws = draw(model(0.5e-3, 0.5e-3), 4000, 5)
    few, many = pooled_range([honest] * 4), pooled_range([honest] * 25)
    assert np.all(many["rms"][0] < 1.0) and np.all(many["rms"][1] > 1.0)
    assert np.all(np.diff(many["rms"], axis=0) < np.diff(few["rms"], axis=0))


def test_the_bench_the_docs_cite_runs_on_a_kept_acquisition(smoke_labelled, tmp_path, monkeypatch):
    """``python -m bench honesty`` (the guide's rehearsal and the accuracy figures' command)
    on one kept smoke acquisition: recalibrated with this code's method and the paper's, its
    rows judged against the truth (it crashed on ``dataclasses.replace(Config)`` once, and
    nothing ran it)."""
    import json
    import shutil

    import bench.common
    from bench import honesty

    root = tmp_path / "honesty"
    shutil.copytree(smoke_labelled.root, root / "seed5")
    monkeypatch.setattr(bench.common, "RESULTS", tmp_path / "results")
    honesty.main("5", str(root))
    rows = json.loads((tmp_path / "results" / "honesty.json").read_text())["rows"]
    seed = next(row for row in rows if row["seed"] == 5)
    assert 0 < seed["(b) mean E_T label (mm)"] < 20 and 0 <= seed["(b) under SPEED+ thresholds"] <= 1
    assert "pooled, all" in rows[-1].values()
    axes = json.loads((tmp_path / "results" / "honesty_axes.json").read_text())["rows"]
    assert [row["axis"] for row in axes] == ["x", "y", "z"]
