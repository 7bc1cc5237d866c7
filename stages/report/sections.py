"""The report's tables: Table 1 (with TRON's figures), Table 2 side by side per crop, the
motion-capture decisions, a row per sample, the tracking baseline, and the provenance."""

from __future__ import annotations

import html
import platform
from collections import Counter
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from core.config import Config
from manifests import Workspace, read_manifest, read_marker
from manifests.sidecars import Calibration, SolverRecord
from stages.common import tables

PACKAGES = ("speedplus-builder", "numpy", "opencv-contrib-python-headless", "mitsuba", "drjit", "onnxruntime",
            "pyarrow", "ray")


def _table(headers: list[str], rows: list[list[Any]], raw_first: bool = False) -> str:
    """An HTML table in a scrolling box (it never widens the page); cells escaped, but for
    the first column's when ``raw_first`` (a link made here)."""
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)

    def cell(index: int, value: Any) -> str:
        return f"<td>{value if raw_first and index == 0 else html.escape(str(value))}</td>"

    body = "".join("<tr>" + "".join(cell(i, c) for i, c in enumerate(row)) + "</tr>" for row in rows)
    return f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'


def table1(calibration: Calibration) -> str:
    """Table 1 of this run (mean ± standard deviation over the calibration samples) with TRON's
    reference rows, and the solver in words."""
    rows = [[label, *cells] for label, cells in tables.rows(calibration, with_paper=True)]
    return f"<p>{html.escape(solver_line(calibration.solver))}</p>" + _table(
        ["metric", *(label for _, label in tables.columns(calibration))], rows)


def solver_line(solver: SolverRecord) -> str:
    """``calibration.json``'s solver record as a sentence."""
    parts = [f"Solver: {solver.method}", f"{solver.folds}-fold cross-validation"]
    pattern = solver.pattern
    size = "x".join(str(v) for v in pattern["size"])
    parts.append(f"pattern {pattern['kind']} {size}, {1000 * pattern['square_m']:g} mm squares")
    if solver.fixtures:
        parts.append("fixtures " + ", ".join(solver.fixtures))
    return "; ".join(parts) + ". Mean ± standard deviation over the calibration samples."


def _mean(row: dict[str, Any] | None) -> str:
    if row is None:
        return "-"
    return f"{row['mean_score_speed']:.4f} [{row['mean_score_speed_low']:.3f}, {row['mean_score_speed_high']:.3f}]"


def _pair(synthetic: dict[str, Any] | None, testbed: dict[str, Any] | None, text: Any) -> str:
    return " / ".join("-" if row is None else text(row) for row in (synthetic, testbed))


DEFINITIONS = (
    "E_T: the label's position error (mm); E_R: its rotation error (deg); E_p: the reprojection error of the "
    "calibration board's corners (px). e_q = 2 arccos |<q_pred, q_true>| (rad); e_t = |t_true - t_pred| / |t_true|. "
    "SPEED score: e_q + e_t. SPEED+ score: the same, each term set to zero under its threshold (0.169 deg, "
    "2.173e-3). Failed: e_q over 10 deg or e_t over 10%, or no pose (scored as the worst case, pi + 1). An image's "
    "score in the means: its mean over the poses decoded under several RANSAC seeds (evaluate.ransac_seeds). "
    "Intervals: 95%, bootstrap over the images, stratified by configuration; they hold the decoder's spread too.")


def table2(scores: list[dict[str, Any]], models: list[str], crop: str) -> str:
    """Table 2 for one crop, a row per configuration and model (any number of models stays
    in view): mean SPEED score with its interval on the twins and the testbed images, the
    gap between them, medians, failures and images without a pose."""
    by_group = {row["group"]: row for row in scores}
    rows = []
    for configuration, count, *_ in tables.table2_groups(scores, models[0], crop):
        view, light = configuration.split(", ")
        for model in models:
            synthetic = by_group.get(f"{model}/{crop}/synthetic/{view}/{light}")
            testbed = by_group.get(f"{model}/{crop}/testbed/{view}/{light}")
            if synthetic is None and testbed is None:
                continue
            gap = ("-" if synthetic is None or testbed is None
                   else f"{testbed['mean_score_speed'] - synthetic['mean_score_speed']:+.4f}")
            rows.append([configuration, model, count, _mean(synthetic), _mean(testbed), gap,
                         _pair(synthetic, testbed, lambda r: f"{r['median_score_speed']:.3f}"),
                         _pair(synthetic, testbed, lambda r: f"{100 * r['failure_share']:.0f}%"),
                         f"{_no_pose(synthetic)} / {_no_pose(testbed)}"])
    header = ["configuration (view, light)", "model", "images", "synthetic: mean [95%]", "testbed: mean [95%]",
              "gap", "median (syn / test)", "failed (syn / test)", "no pose (syn / test)"]
    how = {"oracle_box": "oracle crop: boxes from the labels", "self": "each model's own crop: the detector's box "
           "(without a detector, a search over windows of the whole image), then passes around what it found",
           "full": "the whole image"}.get(crop, crop)
    notes = []
    if crop == "self":
        for model in models:
            row = by_group.get(f"{model}/{crop}/testbed/all/all")
            twin = by_group.get(f"{model}/{crop}/synthetic/all/all")
            if row and twin:
                notes.append(f"<li>{html.escape(model)}: the boxes it found overlap the labels' by a mean IoU of "
                             f"{twin['mean_box_iou']:.2f} on the twins, {row['mean_box_iou']:.2f} on the testbed "
                             "images</li>")
    return (f"<p>Mean SPEED scores, {html.escape(how)}; gap: testbed minus synthetic.</p>" + _table(header, rows)
            + (f"<ul>{''.join(notes)}</ul>" if notes else ""))


def comparisons_section(comparisons: list[dict[str, Any]]) -> str:
    """Each model against the reference on the same images: the paired mean difference of
    the SPEED scores with its interval per configuration, and what the interval says."""
    if not comparisons:
        return "<p>One model: nothing to compare.</p>"
    rows, sentences = [], []
    for row in comparisons:
        words = tables.verdict(row["mean_difference_speed_low"], row["mean_difference_speed_high"], row["count"])
        rows.append([f"{row['model']} ({row['crop']})", f"{row['reference']} ({row['reference_crop']})",
                     row["domain"], f"{row['view']}, {row['light']}", row["count"],
                     f"{row['mean_difference_speed']:+.4f} [{row['mean_difference_speed_low']:+.4f}, "
                     f"{row['mean_difference_speed_high']:+.4f}]", f"{100 * row['better_share']:.0f}%", words])
        if row["view"] == "all":
            reference = f"{row['reference']} ({row['reference_crop']})"
            claim = (f"{words} against {reference}" if words.startswith("too few") else
                     f"{words} {'from' if words == 'not shown different' else 'than'} {reference} at 95%")
            sentences.append(f"<li>{html.escape(row['model'])} ({html.escape(row['crop'])}) on the "
                             f"{html.escape(row['domain'])} images: {html.escape(claim)}, mean SPEED difference "
                             f"{row['mean_difference_speed']:+.3f} [{row['mean_difference_speed_low']:+.3f}, "
                             f"{row['mean_difference_speed_high']:+.3f}]</li>")
    header = ["model (crop)", "reference (crop)", "domain", "configuration", "images",
              "mean SPEED difference [95%]", "images where better", "than the reference, at 95%"]
    return ("<p>Model minus reference on the same images: below zero, the model scores lower (better). Paired "
            f"bootstrap, stratified by configuration; no claim under {tables.MIN_COMPARED} images.</p>"
            + f"<ul>{''.join(sentences)}</ul>" + _table(header, rows))


def per_sample_table(labels: list[dict[str, Any]], poses: dict[str, dict], predictions: list[dict[str, Any]],
                     runs: list[tuple[str, str]]) -> str:
    """A row per label: its configuration, label source and sigma, the motion-capture
    decision, and each model's SPEED score per crop on the twin and the testbed image."""
    score = {(p["model"], p["crop"], p["domain"] == "synthetic", p["sample_id"]): p["score_speed"]
             for p in predictions}
    rows = []
    for label in sorted(labels, key=lambda r: r["sample_id"]):
        sample_id = label["sample_id"]
        pose = poses.get(sample_id, {})
        decision = "accepted" if pose.get("vicon_accepted") else (pose.get("reject_reason") or "-")
        cells: list[Any] = [f'<a href="#sample-{html.escape(sample_id)}">{html.escape(sample_id)}</a>',
                            label["view"], label["domain"], label["label_source"],
                            f"{1000 * float(np.linalg.norm(label['sigma_t_m'])):.2f}",
                            f"{np.degrees(label['sigma_r_rad']):.3f}", decision]
        for model, crop in runs:
            twin, testbed = (score.get((model, crop, synthetic, sample_id)) for synthetic in (True, False))
            cells.append(" / ".join("-" if v is None else f"{v:.3f}" for v in (twin, testbed)))
        rows.append(cells)
    header = ["sample", "view", "light", "label source", "sigma t [mm]", "sigma r [deg]", "motion capture",
              *(f"{model} ({crop.replace('_', ' ')}): twin / testbed" for model, crop in runs)]
    return ("<p>SPEED score of each model on the twin / the testbed image; sigma t: the norm of the "
            "label's per-axis translation sigma (full scale).</p>" + _table(header, rows, raw_first=True))


def _no_pose(row: dict[str, Any] | None) -> str:
    return "-" if row is None else f"{100 * (1 - row['pose_found_share']):.0f}%"


def rejection_table(poses: list[dict[str, Any]], labels: list[dict[str, Any]]) -> str:
    reasons = Counter()
    for row in poses:
        reason = row["reject_reason"] or "accepted"
        reasons[reason.split(" differs")[0] + (" differs" if " differs" in reason else "")] += 1
    sources = Counter(row["label_source"] for row in labels)
    rows = [[reason, count] for reason, count in reasons.most_common()]
    rows += [[f"labels from {source}", count] for source, count in sources.items()]
    return _table(["motion-capture decision / label source", "samples"], rows)


def provenance(config: Config, workspace: Workspace) -> str:
    versions = []
    for package in PACKAGES:
        try:
            versions.append([package, metadata.version(package)])
        except metadata.PackageNotFoundError:
            versions.append([package, "not installed"])
    versions.append(["python", platform.python_version()])
    timings = []
    for name in ("plan", "captures", "calibration_samples", "poses", "labels", "renders", "predictions"):
        marker = read_marker(workspace, name)
        if marker:
            timings.append([marker.stage or name, name, marker.rows, marker.seconds, marker.completed_at or None,
                            marker.fingerprint])
    config_text = workspace.config_path.read_text() if workspace.config_path.exists() else ""
    return (_table(["package", "version"], versions)
            + _table(["stage", "manifest", "rows", "seconds", "completed", "fingerprint"], timings)
            + f"<details><summary>configuration (W/config.toml)</summary><pre>{html.escape(config_text)}</pre>"
              "</details>")


def tracking_section(config: Config, workspace: Workspace, figure_dir: Path) -> list[tuple[str, str]]:
    """A trajectory plan's tracking baseline: per sequence, domain and model, the mean SPEED
    score per frame against tracked, and the scores against time."""
    if config.plan.mode != "trajectory":
        return []
    tracks = read_manifest(workspace, "tracks").to_pylist()
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for row in tracks:
        groups.setdefault((row["sequence_id"], row["domain"], row["model"], row["crop"]), []).append(row)
    rows = [[sequence, domain, f"{model} ({crop.replace('_', ' ')})", len(group),
             f"{np.mean([r['frame_score_speed'] for r in group]):.4f}",
             f"{np.mean([r['score_speed'] for r in group]):.4f}",
             f"{sum(r['rotation_used'] for r in group)} / {sum(r['position_used'] for r in group)}"]
            for (sequence, domain, model, crop), group in sorted(groups.items())]
    from stages.report import figures  # matplotlib: not for the commands that only resolve the report

    figure = figures.tracking_errors(tracks, figure_dir / "tracking.png")
    return [("Tracking: per frame against a navigation filter", _table(
        ["sequence", "domain", "model (crop)", "frames", "mean SPEED per frame", "mean SPEED tracked",
         "measurements used (attitude / position)"], rows)
        + f'<img src="figures/{figure}" alt="SPEED score against time per sequence and domain">')]
