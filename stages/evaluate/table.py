"""The paper's Table 2 from the predictions: mean scores per domain and configuration."""

from __future__ import annotations

from itertools import product
from typing import Any

import numpy as np
from rich import box
from rich.table import Table

from manifests import to_table
from manifests.schema import SCORES
from stages.common.tables import TESTBED, table2_groups


def _group(rows: list[dict[str, Any]], model: str, crop: str, domain: str, view: str,
           light: str) -> dict[str, Any] | None:
    chosen = [r for r in rows if r["model"] == model and r["crop"] == crop
              and (r["domain"] == "synthetic") == (domain == "synthetic")
              and view in ("all", r["view"]) and light in ("all", r["light"])]
    if not chosen:
        return None
    err_q = np.degrees([r["err_q_rad"] for r in chosen])
    return {"group": f"{model}/{crop}/{domain}/{view}/{light}", "model": model, "crop": crop, "domain": domain,
            "view": view, "light": light, "count": len(chosen),
            "pose_found_share": float(np.mean([r["pose_found"] for r in chosen])),
            "mean_score_speed": float(np.mean([r["score_speed"] for r in chosen])),
            "mean_score_speedplus": float(np.mean([r["score_speedplus"] for r in chosen])),
            "mean_err_q_deg": float(err_q.mean()), "median_err_q_deg": float(np.median(err_q)),
            "mean_err_t_norm": float(np.mean([r["err_t_norm"] for r in chosen])),
            "mean_box_iou": float(np.mean([r["box_iou"] for r in chosen])) if crop == "self" else None}


def summarise(predictions: list[dict[str, Any]], views: tuple[str, ...]) -> Any:
    """The ``scores`` table: for every model and crop, every (domain, view, light)
    combination present (``views``: the target's, in order), and 'all'. Means over the
    predictions in ``prediction_id`` order: the order rows were written in (which follows
    the workers) must not reach the last bits."""
    predictions = sorted(predictions, key=lambda r: r["prediction_id"])
    rows = []
    for model, crop in sorted({(r["model"], r["crop"]) for r in predictions}):
        for domain, view, light in product(("synthetic", "testbed"), (*views, "all"), (*TESTBED, "all")):
            group = _group(predictions, model, crop, domain, view, light)
            if group is not None:
                rows.append(group)
    return to_table(rows, SCORES)


def print_table2(scores: Any, model: str, crop: str) -> Table:
    """Configuration (view, light) x {synthetic, testbed}: mean SPEED (and SPEED+) scores of
    one model and crop, in 80 columns (abbreviated headers, a legend below)."""
    how = {"oracle_box": "oracle crop", "self": "its own crop", "full": "whole image"}.get(crop, crop)
    table = Table(title=f"Table 2: {model} ({how}), mean SPEED score", box=box.SIMPLE_HEAD, title_justify="left",
                  caption="syn / test: the twins / the testbed images; +: SPEED+ score; no pose: share of images "
                  "without one (syn / test)", caption_justify="left")
    table.add_column("view", overflow="fold")  # a long view name folds; the numbers never shrink
    table.add_column("light", no_wrap=True)
    for column, width in (("n", 3), ("syn", 6), ("test", 6), ("syn+", 6), ("test+", 6), ("no pose", 9)):
        table.add_column(column, no_wrap=True, justify="right", min_width=width)

    def cell(row: dict[str, Any] | None, key: str) -> str:
        return "-" if row is None else f"{row[key]:.4f}"

    def no_pose(row: dict[str, Any] | None) -> str:
        return "-" if row is None else f"{100 * (1 - row['pose_found_share']):.0f}%"

    for configuration, count, synthetic, testbed in table2_groups(scores.to_pylist(), model, crop):
        view, light = configuration.split(", ")
        table.add_row(view, light, str(count), cell(synthetic, "mean_score_speed"),
                      cell(testbed, "mean_score_speed"), cell(synthetic, "mean_score_speedplus"),
                      cell(testbed, "mean_score_speedplus"), f"{no_pose(synthetic)} / {no_pose(testbed)}")
    return table
