"""The paper's tables for this run, built once and shown by the stages that print them
(calibrate, evaluate) and by the report: Table 1, E_T [mm], E_R [deg], E_p [px] per source
and fused; Table 2, mean scores per configuration (view, light) on twins and testbed."""

from __future__ import annotations

from itertools import product
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from manifests.schema import DOMAINS
from manifests.sidecars import Calibration, Metrics, MetricSet

TESTBED = DOMAINS

#: TRON's Table 1 (in-sample, mean +- std), for comparison.
PAPER = {"kuka": ((2.429, 0.866), (0.637, 0.120), (5.176, 2.397)),
         "vicon": ((1.208, 0.678), (0.172, 0.083), (4.175, 2.718)),
         "fused": ((0.815, 0.494), (0.169, 0.077), (2.758, 1.716))}
COLUMNS = (("kuka", "KUKA-only"), ("vicon", "Vicon-only"), ("fused", "Data fusion"))


def columns(calibration: Calibration) -> tuple[tuple[str, str], ...]:
    """Table 1's columns (source, label), the sources named as the facility names them
    (TRON: the paper's "KUKA-only", "Vicon-only")."""
    if not calibration.session.names:
        return COLUMNS
    return tuple((source, label if source == "fused" else f"{calibration.session.name(source)} only")
                 for source, label in COLUMNS)


def _cell(metric: MetricSet | None, key: str, scale: float) -> str:
    if metric is None:
        return "-"
    mean, std = metric.value(key)
    return f"{mean * scale:.3f} ± {std * scale:.3f}"


def rows(calibration: Calibration, with_paper: bool = True) -> list[tuple[str, list[str]]]:
    """Table 1's rows: (metric label, a cell per column of ``COLUMNS``), then the paper's
    figures unless ``with_paper`` is false."""
    out = []
    for kind, label in (("in_sample", "in-sample"), ("cross_validated", "cross-validated"), ("truth", "vs truth")):
        for key, unit, scale in (("E_T_m", "E_T [mm]", 1000.0), ("E_R_rad", "E_R [deg]", float(np.degrees(1.0))),
                                 ("E_p_px", "E_p [px]", 1.0)):
            cells = []
            for source, _ in COLUMNS:
                metrics = _column_metrics(calibration, source)
                cell = _cell(metrics.kind(kind) if metrics else None, key, scale)
                cells.append(cell + (_folds_note(metrics) if kind == "cross_validated" and metrics else ""))
            out.append((f"{unit} {label}", cells))
    if not with_paper:
        return out
    for index, unit in enumerate(("E_T [mm]", "E_R [deg]", "E_p [px]")):
        out.append((f"{unit} paper (TRON)", [f"{PAPER[s][index][0]:.3f} ± {PAPER[s][index][1]:.3f}"
                                             for s, _ in COLUMNS]))
    return out


def _folds_note(metrics: Metrics) -> str:
    """Beside a cross-validated mean: how many folds it is over, when some could not be judged."""
    cross = metrics.cross_validation
    if cross.undetermined_folds and cross.folds:
        return f" ({cross.folds - len(cross.undetermined_folds)} of {cross.folds} folds)"
    if metrics.cross_validated is None:
        return " (no fold determined)"
    return ""


def _column_metrics(calibration: Calibration, column: str) -> Metrics | None:
    if column == "fused":
        return calibration.fused.metrics if calibration.fused else None
    entry = calibration.source(column)
    return entry.metrics if entry else None


def print_table(calibration: Calibration) -> None:
    table = Table(title="Table 1: calibration accuracy (mean ± std over calibration samples)")
    table.add_column("metric")
    for _, label in columns(calibration):
        table.add_column(label, justify="right")
    for label, cells in rows(calibration):
        table.add_row(escape(label), *cells)
    Console().print(table)
    for source, label in columns(calibration):
        metrics = _column_metrics(calibration, source) if source != "fused" else None
        cross = metrics.cross_validation if metrics is not None else None
        if cross is not None and cross.undetermined_folds:
            judged = ("the refusal check used the others" if cross.judged
                      else "too few were determined to judge: the in-sample fit alone was")
            Console().print(f"{label}: fold(s) {', '.join(map(str, cross.undetermined_folds))} of {cross.folds} "
                            "could not determine the offsets and are left out of the cross-validated means; "
                            f"{judged}", highlight=False)
    fused = calibration.fused
    if fused and (fused.metrics.truth or fused.metrics.cross_validated):
        kind = "truth" if fused.metrics.truth else "cross_validated"
        same = {**fused.sources_on_the_same_samples, "fused": fused.metrics}
        Console().print(f"On the {fused.samples} captures both sources measured, E_T {kind.replace('_', '-')}: "
                        + ", ".join(f"{label} {same[name].kind(kind).E_T_m[0] * 1000:.4f} mm"
                                    for name, label in columns(calibration)))


def table2_groups(scores: list[dict[str, Any]], model: str, crop: str) -> list[tuple[str, int, dict[str, Any] | None,
                                                                                  dict[str, Any] | None]]:
    """Table 2's rows of one model and crop: (configuration "view, light", images, synthetic
    row, testbed row) of the ``scores`` rows, for every view x light present, then "all, all"."""
    by_group = {row["group"]: row for row in scores}
    views = list(dict.fromkeys(row["view"] for row in scores if row["view"] != "all"))  # the target's, in order
    out = []
    for view, light in [*product(views, TESTBED), ("all", "all")]:
        synthetic = by_group.get(f"{model}/{crop}/synthetic/{view}/{light}")
        testbed = by_group.get(f"{model}/{crop}/testbed/{view}/{light}")
        if synthetic is None and testbed is None:
            continue
        out.append((f"{view}, {light}", (testbed or synthetic)["count"], synthetic, testbed))
    return out


#: images under which a comparison claims nothing: a bootstrap over fewer resamples a
#: handful of values, and its 95% interval is not one
MIN_COMPARED = 8


def verdict(low: float, high: float, count: int) -> str:
    """What a 95% interval of ``model - reference`` (scores: lower is better) over ``count``
    images says: better, worse, not shown different, or too few images to tell."""
    if count < MIN_COMPARED:
        return f"too few images to tell ({count} < {MIN_COMPARED})"
    if high < 0:
        return "better"
    if low > 0:
        return "worse"
    return "not shown different"
