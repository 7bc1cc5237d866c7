"""The comparisons table: a model against the reference on the same images only."""

import numpy as np
import pytest

from stages.evaluate.comparisons import compare


def row(model, sample, domain, score):
    return {"prediction_id": f"{model}:oracle_box:{domain}:{sample}", "model": model, "crop": "oracle_box",
            "domain": domain, "sample_id": sample, "view": "solar_panel", "light": "lightbox",
            "score_speed": score, "score_speedplus": score}


def test_only_images_both_scored_are_paired_and_a_reference_without_images_gives_no_rows():
    rng = np.random.default_rng(4)
    theirs = [row("reference", f"img{i:06d}", "lightbox", s) for i, s in enumerate(rng.gamma(1, 0.2, 6))]
    mine = [row("mine", f"img{i:06d}", "lightbox", s) for i, s in enumerate(rng.gamma(1, 0.2, 8))]
    table = {r["group"]: r for r in compare(theirs + mine, ("solar_panel", "rear_panel"),
                                            ["mine", "reference"]).to_pylist()}
    overall = table["mine/oracle_box/reference/oracle_box/testbed/all/all"]
    assert overall["count"] == 6
    expected = np.mean([m["score_speed"] - t["score_speed"] for m, t in zip(mine, theirs, strict=False)])
    assert overall["mean_difference_speed"] == pytest.approx(expected)
    assert compare(mine, ("solar_panel", "rear_panel"), ["reference", "mine"]).num_rows == 0
