"""The paper's Table 2 from the predictions: mean scores per domain and configuration."""

from __future__ import annotations

from collections.abc import Callable
from itertools import product
from typing import Any

import numpy as np
from rich import box
from rich.console import Group
from rich.table import Table

from manifests import to_table
from manifests.schema import SCORES
from stages.common.tables import TESTBED, table2_groups
from stages.evaluate.intervals import failed, mean_interval, seed_means


def _group(rows: list[dict[str, Any]], model: str, crop: str, domain: str, view: str,
           light: str) -> dict[str, Any] | None:
    chosen = [r for r in rows if r["model"] == model and r["crop"] == crop
              and (r["domain"] == "synthetic") == (domain == "synthetic")
              and view in ("all", r["view"]) and light in ("all", r["light"])]
    if not chosen:
        return None
    err_q = np.degrees([r["err_q_rad"] for r in chosen])
    group = f"{model}/{crop}/{domain}/{view}/{light}"
    strata = [f"{r['view']}, {r['light']}" for r in chosen]
    speed_values = seed_means(chosen, "speed")
    speed = mean_interval(speed_values, strata, f"{group}/speed")
    speedplus = mean_interval(seed_means(chosen, "speedplus"), strata, f"{group}/speedplus")
    return {"group": group, "model": model, "crop": crop, "domain": domain,
            "view": view, "light": light, "count": len(chosen),
            "pose_found_share": float(np.mean([r["pose_found"] for r in chosen])),
            "refused_share": float(np.mean([r.get("pose_refused") is not None for r in chosen])),
            "mean_score_speed": speed.value, "mean_score_speed_low": speed.low, "mean_score_speed_high": speed.high,
            "median_score_speed": float(np.median(speed_values)),
            "mean_score_speedplus": speedplus.value, "mean_score_speedplus_low": speedplus.low,
            "mean_score_speedplus_high": speedplus.high,
            "failure_share": float(np.mean(failed([r["err_q_rad"] for r in chosen],
                                                   [r["err_t_norm"] for r in chosen]))),
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


def figure(value: float, decimals: int) -> str:
    """A score in a column that holds whatever a model scores: two decimals fewer from 10 on
    (a random model scores 10 and more), so the numbers never squeeze the names."""
    return f"{value:.{decimals if abs(value) < 10 else decimals - 2}f}"


def print_table2(scores: Any, model: str, crop: str) -> Group:
    """Configuration (view, light) x {synthetic, testbed} of one model and crop, in 80
    columns: the mean SPEED score and its 95% interval; then the medians, the SPEED+ means
    and the shares of failures (an image without a pose among them)."""
    how = {"oracle_box": "oracle crop", "self": "its own crop", "full": "whole image"}.get(crop, crop)
    means = Table(title=f"Table 2: {model} ({how}), mean SPEED score [95% interval]", box=box.SIMPLE_HEAD,
                  title_justify="left", caption="syn / test: the twins / the testbed images; intervals: "
                  "bootstrap over the images, stratified by configuration", caption_justify="left")
    more = Table(title=f"{model} ({how}): medians, SPEED+ and failures, syn/test", box=box.SIMPLE_HEAD,
                 title_justify="left", caption="median: SPEED score; SPEED+: mean SPEED+ score; failed: rotation over "
                 "10 deg or translation over 10% of the range, or no pose (scored as the worst case)",
                 caption_justify="left")
    for table in (means, more):
        table.add_column("view", overflow="fold")  # a long view name folds; the numbers never shrink
        table.add_column("light", no_wrap=True)
        table.add_column("n", no_wrap=True, justify="right", min_width=3)
    for column in ("syn", "test"):
        means.add_column(column, no_wrap=True, justify="right", min_width=20)
    for column in ("median", "SPEED+", "failed"):
        more.add_column(column, no_wrap=True, justify="right")

    def interval(row: dict[str, Any] | None) -> str:
        if row is None:
            return "-"
        return (f"{figure(row['mean_score_speed'], 4)} [{figure(row['mean_score_speed_low'], 3)}, "
                f"{figure(row['mean_score_speed_high'], 3)}]")

    def pair(synthetic: dict[str, Any] | None, testbed: dict[str, Any] | None, show: Callable[[dict], str]) -> str:
        return "/".join("-" if row is None else show(row) for row in (synthetic, testbed))

    for configuration, count, synthetic, testbed in table2_groups(scores.to_pylist(), model, crop):
        view, light = configuration.split(", ")
        means.add_row(view, light, str(count), interval(synthetic), interval(testbed))
        more.add_row(view, light, str(count), pair(synthetic, testbed, lambda r: figure(r['median_score_speed'], 3)),
                     pair(synthetic, testbed, lambda r: figure(r['mean_score_speedplus'], 3)),
                     pair(synthetic, testbed, lambda r: f"{100 * r['failure_share']:.0f}%"))
    return Group(means, more)
