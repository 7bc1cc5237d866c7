"""Is a model better than the reference, and where? Paired differences of their scores on
the same images, per domain and configuration, with paired-bootstrap intervals
(``intervals.paired_interval``): the ``comparisons`` manifest and its terminal table.

The reference is the model named ``reference`` when it was scored (the shipped plain
model, or the one train-reference made), else the first of ``evaluate.models``. A model is
compared on its own crop with the reference's same crop, or with the reference's first crop
when the reference has not that one (a whole-image model against the reference's oracle crop).
"""

from __future__ import annotations

from itertools import product
from typing import Any

import numpy as np
from rich import box
from rich.table import Table

from manifests import to_table
from manifests.schema import COMPARISONS
from stages.common.tables import TESTBED
from stages.evaluate.intervals import Interval, paired_interval, seed_means

REFERENCE = "reference"


def reference_model(models: list[str]) -> str | None:
    """The model the others are compared with, of ``models`` (evaluate's order)."""
    return REFERENCE if REFERENCE in models else (models[0] if models else None)


def _pairs(predictions: list[dict[str, Any]], model: str, crop: str, reference: str,
           reference_crop: str) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """(model's row, reference's row) of every image both scored, in ``prediction_id`` order."""
    theirs = {(r["domain"], r["sample_id"]): r for r in predictions if r["model"] == reference
              and r["crop"] == reference_crop}
    mine = sorted((r for r in predictions if r["model"] == model and r["crop"] == crop),
                  key=lambda r: r["prediction_id"])
    return [(r, theirs[(r["domain"], r["sample_id"])]) for r in mine if (r["domain"], r["sample_id"]) in theirs]


def _row(pairs: list[tuple[dict[str, Any], dict[str, Any]]], names: dict[str, str], domain: str, view: str,
         light: str) -> dict[str, Any] | None:
    chosen = [(m, r) for m, r in pairs if (m["domain"] == "synthetic") == (domain == "synthetic")
              and view in ("all", m["view"]) and light in ("all", m["light"])]
    if not chosen:
        return None
    group = "/".join((names["model"], names["crop"], names["reference"], names["reference_crop"], domain, view,
                      light))
    strata = [f"{m['view']}, {m['light']}" for m, _ in chosen]
    figures: dict[str, Interval] = {}
    for key in ("speed", "speedplus"):
        mine, theirs = seed_means([m for m, _ in chosen], key), seed_means([r for _, r in chosen], key)
        figures[key] = paired_interval(mine, theirs, strata, f"{group}/{key}")
        if key == "speed":
            better = float(np.mean(mine < theirs))
    row = {"group": group, **names, "domain": domain, "view": view, "light": light, "count": len(chosen),
           "better_share": better}
    for key, interval in figures.items():
        row.update({f"mean_difference_{key}": interval.value, f"mean_difference_{key}_low": interval.low,
                    f"mean_difference_{key}_high": interval.high})
    return row


def compare(predictions: list[dict[str, Any]], views: tuple[str, ...], models: list[str]) -> Any:
    """The ``comparisons`` table: every (model, crop) but the reference's against it, for
    each (domain, view, light) present and 'all'; ``models`` in evaluate's order."""
    reference = reference_model(models)
    rows: list[dict[str, Any]] = []
    if reference is None:
        return to_table(rows, COMPARISONS)
    reference_crops = list(dict.fromkeys(r["crop"] for r in predictions if r["model"] == reference))
    if not reference_crops:  # the reference scored no image: nothing to pair with
        return to_table(rows, COMPARISONS)
    for model in models:
        if model == reference:
            continue
        for crop in list(dict.fromkeys(r["crop"] for r in predictions if r["model"] == model)):
            reference_crop = crop if crop in reference_crops else reference_crops[0]
            pairs = _pairs(predictions, model, crop, reference, reference_crop)
            names = {"model": model, "crop": crop, "reference": reference, "reference_crop": reference_crop}
            for domain, view, light in product(("synthetic", "testbed"), (*views, "all"), (*TESTBED, "all")):
                if (view == "all") != (light == "all"):
                    continue  # Table 2's rows: each configuration, and all of them
                row = _row(pairs, names, domain, view, light)
                if row is not None:
                    rows.append(row)
    return to_table(rows, COMPARISONS)


def signed(value: float) -> str:
    """A difference with its sign: one decimal from 10 on, so the names keep their width."""
    return f"{value:+.{3 if abs(value) < 10 else 1}f}"


def print_comparison(comparisons: Any, model: str, crop: str) -> Table:
    """One model and crop against the reference, per configuration: the mean SPEED score
    difference and its 95% interval, on the twins and on the testbed images."""
    rows = [r for r in comparisons.to_pylist() if r["model"] == model and r["crop"] == crop]
    reference = f"{rows[0]['reference']} ({rows[0]['reference_crop']})" if rows else "the reference"
    table = Table(title=f"{model} ({crop}) minus {reference}: mean SPEED score difference [95% interval]",
                  box=box.SIMPLE_HEAD, title_justify="left", caption="below zero: the model scores lower "
                  "(better); paired over the same images, bootstrap stratified by configuration",
                  caption_justify="left")
    longest = max((len(r["view"]) for r in rows), default=4)
    table.add_column("view", overflow="fold", min_width=min(longest, 14))
    table.add_column("light", no_wrap=True)
    table.add_column("n", no_wrap=True, justify="right")
    for domain in ("synthetic", "testbed"):
        table.add_column("syn" if domain == "synthetic" else "test", no_wrap=True, justify="right")
    by_key = {(r["domain"], r["view"], r["light"]): r for r in rows}
    configurations = list(dict.fromkeys((r["view"], r["light"]) for r in rows if r["view"] != "all"))
    for view, light in [*configurations, ("all", "all")]:
        cells, count = [], 0
        for domain in ("synthetic", "testbed"):
            row = by_key.get((domain, view, light))
            count = max(count, row["count"] if row else 0)
            cells.append("-" if row is None else " ".join((
                signed(row["mean_difference_speed"]), f"[{signed(row['mean_difference_speed_low'])},",
                f"{signed(row['mean_difference_speed_high'])}]")))
        table.add_row(view, light, str(count), *cells)
    return table
