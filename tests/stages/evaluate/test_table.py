"""Table 2 in a terminal of 80 columns: every view and light name whole, nothing cut, every
mean with its interval."""

import itertools

import numpy as np
from rich.console import Console

from stages.evaluate.table import figure, print_table2, summarise


def predictions(views):
    rng = np.random.default_rng(0)
    rows = []
    for index, (view, light, domain) in enumerate(itertools.product(views, ("lightbox", "sunlamp"),
                                                                    ("synthetic", "lightbox"))):
        domain = light if domain != "synthetic" else "synthetic"
        err_q, err_t = rng.uniform(0, 0.3), rng.uniform(0, 0.1)
        rows.append({"prediction_id": f"reference_augmented:oracle_box:{domain}:img{index:06d}",
                     "model": "reference_augmented", "sample_id": f"img{index:06d}", "domain": domain, "view": view,
                     "light": light, "crop": "oracle_box", "box_iou": None, "pose_found": True, "err_q_rad": err_q,
                     "err_t_norm": err_t, "score_speed": err_q + err_t, "score_speedplus": err_q + err_t})
    return rows


def render(views):
    scores = summarise(predictions(views), views)
    console = Console(width=80, record=True)
    console.print(print_table2(scores, "reference_augmented", "oracle_box"))
    return scores, console.export_text()


def test_table2_fits_80_columns_with_every_name_whole():
    views = ("solar_panel", "rear_panel")
    _, text = render(views)
    assert max(len(line) for line in text.splitlines()) <= 80 and "…" not in text
    for name in (*views, "lightbox", "sunlamp", "reference_augmented"):
        assert name in text
    # a line per configuration in each of the two tables (means with intervals; medians, SPEED+, failures)
    assert sum(" lightbox " in line for line in text.splitlines()) == 4


def test_a_long_view_name_folds_and_no_number_is_cut():
    scores, text = render(("solar_panel", "rear_panel_with_a_long_name"))
    assert max(len(line) for line in text.splitlines()) <= 80 and "…" not in text
    shown = [r for r in scores.to_pylist() if (r["view"] == "all") == (r["light"] == "all")]  # Table 2's rows
    assert len(shown) == 10
    for row in shown:
        assert f"{figure(row['mean_score_speed'], 4)} [{figure(row['mean_score_speed_low'], 3)}, " in text
        assert f"{figure(row['median_score_speed'], 3)}/" in text or f"/{figure(row['median_score_speed'], 3)}" in text


def test_scores_of_ten_or_more_fold_no_name():
    """A random model scores 10 and more: its intervals widen the numbers, never the names."""
    rows = predictions(("solar_panel", "rear_panel"))
    for row in rows:
        row.update(score_speed=10.0 + 3 * row["score_speed"], score_speedplus=10.0 + 3 * row["score_speedplus"])
    scores = summarise(rows, ("solar_panel", "rear_panel"))
    console = Console(width=80, record=True)
    console.print(print_table2(scores, "reference_augmented", "oracle_box"))
    text = console.export_text()
    assert max(len(line) for line in text.splitlines()) <= 80 and "…" not in text
    assert sum("solar_panel" in line for line in text.splitlines()) == 4, text
