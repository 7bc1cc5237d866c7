"""The report stage: a static HTML page, ``W/report/index.html``, with the paper's tables
and figures for this run (no server, no network: open it from the file system).

Sections: Table 1 (in-sample, cross-validated, against the truth when there is one),
calibration residuals, the label pose distribution, rejection statistics, wireframe
overlays of the labels on testbed images, synthetic/testbed pairs with their scores,
Table 2, per-sample scores, rotation-error CDFs, and the run's provenance.
"""

from __future__ import annotations

import html
import platform
from collections import Counter
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from manifests import Workspace, read_manifest, read_success
from manifests.files import write_bytes_atomic
from manifests.schema import DOMAINS
from manifests.sidecars import Calibration, read_calibration
from pipeline.config import Config
from stages.common import tables
from stages.common.image_io import read_image, to_uint8, write_png_atomic
from stages.common.sidecars import calibrated_camera
from stages.common.target import feature_edges
from stages.common.workspace_target import workspace_target
from stages.report import figures

REPORT_DIR = "report"
PACKAGES = ("speedplus-builder", "numpy", "opencv-contrib-python-headless", "mitsuba", "drjit", "onnxruntime",
            "pyarrow", "ray")


def _table(headers: list[str], rows: list[list[Any]]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def table1(calibration: Calibration) -> str:
    rows = [[label, *cells] for label, cells in tables.rows(calibration, with_paper=False)]
    return _table(["metric", "KUKA-only", "Vicon-only", "fused"], rows)


def _cell(row: dict[str, Any] | None, key: str) -> str:
    return "-" if row is None else f"{row[key]:.4f}"


def table2(scores: list[dict[str, Any]], models: list[str], crop: str) -> str:
    """Table 2 of every model side by side for one crop, and how much of the domain gap (testbed
    minus synthetic mean SPEED score) each model other than the first closes per light."""
    rows = []
    for configuration, count, *_ in tables.table2_groups(scores, models[0], crop):
        view, light = configuration.split(", ")
        cells: list[Any] = [configuration, count]
        for model in models:
            by_group = {row["group"]: row for row in scores}
            synthetic = by_group.get(f"{model}/{crop}/synthetic/{view}/{light}")
            testbed = by_group.get(f"{model}/{crop}/testbed/{view}/{light}")
            gap = ("-" if synthetic is None or testbed is None
                   else f"{testbed['mean_score_speed'] - synthetic['mean_score_speed']:+.4f}")
            cells += [_cell(synthetic, "mean_score_speed"), _cell(testbed, "mean_score_speed"), gap,
                      f"{_no_pose(synthetic)} / {_no_pose(testbed)}"]
        rows.append(cells)
    header = ["configuration (view, light)", "images"]
    for model in models:
        header += [f"{model}: synthetic", f"{model}: testbed", f"{model}: gap", f"{model}: no pose (syn / test)"]
    how = {"oracle_box": "oracle crop: boxes from the labels", "self": "each model's own crop: a search over windows "
           "of the whole image, then passes around what it found", "full": "the whole image"}.get(crop, crop)
    closing = []
    by_group = {row["group"]: row for row in scores}
    for model in models[1:]:
        for light in ("lightbox", "sunlamp"):
            gaps = []
            for name in (models[0], model):
                synthetic = by_group.get(f"{name}/{crop}/synthetic/all/{light}")
                testbed = by_group.get(f"{name}/{crop}/testbed/all/{light}")
                if synthetic and testbed:
                    gaps.append(testbed["mean_score_speed"] - synthetic["mean_score_speed"])
            if len(gaps) == 2:
                closed = f"{100 * (gaps[0] - gaps[1]) / gaps[0]:.0f}%" if gaps[0] > 0 else "-"
                closing.append(f"<li>{html.escape(light)}: gap {gaps[0]:.3f} ({html.escape(models[0])}) against "
                               f"{gaps[1]:.3f} ({html.escape(model)}): {closed} of it closed</li>")
    if crop == "self":
        for model in models:
            row = by_group.get(f"{model}/{crop}/testbed/all/all")
            twin = by_group.get(f"{model}/{crop}/synthetic/all/all")
            if row and twin:
                closing.append(f"<li>{html.escape(model)}: the boxes it found overlap the labels' by a mean IoU of "
                               f"{twin['mean_box_iou']:.2f} on the twins, {row['mean_box_iou']:.2f} on the testbed "
                               "images</li>")
    return (f"<p>Mean SPEED scores, {html.escape(how)}; gap: testbed minus synthetic. An image without a pose "
            "(non-finite model output) scores the worst case, pi + 1.</p>" + _table(header, rows)
            + (f"<ul>{''.join(closing)}</ul>" if closing else ""))


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
        marker = read_success(workspace, name)
        if marker:
            timings.append([marker.get("stage", name), name, marker.get("rows"), marker.get("seconds"),
                            marker.get("completed_at"), marker.get("fingerprint")])
    config_text = workspace.config_path.read_text() if workspace.config_path.exists() else ""
    return (_table(["package", "version"], versions)
            + _table(["stage", "manifest", "rows", "seconds", "completed", "fingerprint"], timings)
            + f"<details><summary>configuration (W/config.toml)</summary><pre>{html.escape(config_text)}</pre>"
              "</details>")


def _write_png(path: Path, image: np.ndarray) -> str:
    write_png_atomic(path, image)
    return path.name


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
    figure = figures.tracking_errors(tracks, figure_dir / "tracking.png")
    return [("Tracking: per frame against a navigation filter", _table(
        ["sequence", "domain", "model (crop)", "frames", "mean SPEED per frame", "mean SPEED tracked",
         "measurements used (attitude / position)"], rows)
        + f'<img src="figures/{figure}" alt="SPEED score against time per sequence and domain">')]


def run(config: Config, workspace: Workspace) -> None:
    out = workspace.root / REPORT_DIR
    figure_dir, thumb_dir = out / "figures", out / "thumbs"
    calibration = read_calibration(workspace)
    labels = read_manifest(workspace, "labels").to_pylist()
    poses = read_manifest(workspace, "poses").to_pylist()
    renders = {row["sample_id"]: row for row in read_manifest(workspace, "renders").to_pylist()}
    captures = {row["sample_id"]: row for row in read_manifest(workspace, "captures").to_pylist()}
    predictions = read_manifest(workspace, "predictions").to_pylist()
    scores = read_manifest(workspace, "scores").to_pylist()
    samples = read_manifest(workspace, "calibration_samples").to_pylist()
    camera = calibrated_camera(workspace)

    models = list(dict.fromkeys(Path(text).stem for text in config.evaluate.models
                                if any(r["model"] == Path(text).stem for r in predictions)))
    models += sorted({r["model"] for r in predictions} - set(models))
    crops = [c for c in ("oracle_box", "full", "self") if any(r["crop"] == c for r in predictions)]
    # the first model on its contract's crop: the per-sample pictures
    primary = [r for r in predictions if models and r["model"] == models[0] and crops and r["crop"] == crops[0]]
    score_of = {(row["domain"], row["sample_id"]): row for row in primary}
    made = {
        "residuals": figures.calibration_residuals(samples, figure_dir / "calibration_residuals.png"),
        "poses": figures.pose_distribution(labels, figure_dir / "pose_distribution.png"),
        "scores": figures.per_sample_scores(primary, figure_dir / "per_sample_scores.png"),
        "cdf": figures.rotation_cdf(predictions, models, figure_dir / "rotation_cdf.png"),
    }
    # a few samples of each configuration for the picture sections
    chosen: list[dict[str, Any]] = []
    for view in dict.fromkeys(row["view"] for row in labels):  # the target's views, in the plan's order
        for light in DOMAINS:
            chosen += [row for row in labels if row["view"] == view and row["domain"] == light][:2]
    overlays, pairs = [], []
    wireframe = feature_edges(workspace_target(config, workspace))
    for label in chosen:
        sample_id = label["sample_id"]
        capture = to_uint8(read_image(workspace.fetch(captures[sample_id]["image_path"]), "bgr"))
        drawn = figures.overlay(capture, label, camera.camera_matrix, camera.dist, wireframe)
        name = _write_png(thumb_dir / f"overlay_{sample_id}.png", figures.thumbnail(drawn))
        overlays.append(f'<figure><img src="thumbs/{name}" alt="wireframe of {sample_id}"><figcaption>{sample_id}: '
                        f'{label["view"]}, {label["domain"]}, {label["label_source"]}</figcaption></figure>')
        if sample_id in renders:
            twin = to_uint8(read_image(workspace.fetch(renders[sample_id]["image_path"]), "bgr"))
            pair = np.hstack([figures.thumbnail(twin), figures.thumbnail(figures.brighten(capture))])
            name = _write_png(thumb_dir / f"pair_{sample_id}.png", pair)
            synthetic, testbed = score_of.get(("synthetic", sample_id)), score_of.get((label["domain"], sample_id))
            caption = " / ".join(f"{r['score_speed']:.3f}" if r else "-" for r in (synthetic, testbed))
            pairs.append(f'<figure><img src="thumbs/{name}" alt="twin and capture of {sample_id}"><figcaption>'
                         f'{sample_id} ({label["view"]}, {label["domain"]}): SPEED score twin / testbed {caption}'
                         '</figcaption></figure>')
    sections = [
        ("Table 1: calibration accuracy", f"<p>Solver: {html.escape(str(calibration.solver))}. Mean ± "
         "standard deviation over the calibration samples.</p>" + table1(calibration)),
        ("Calibration residuals", f'<img src="figures/{made["residuals"]}" alt="calibration residuals">'),
        ("Pose distribution of the labels", f'<img src="figures/{made["poses"]}" alt="pose distribution">'),
        ("Motion-capture rejection and label sources", rejection_table(poses, labels)),
        ("Labels on testbed images (wireframe, brightened)", '<div class="grid">' + "".join(overlays) + "</div>"),
        ("Synthetic twins and testbed images", '<div class="grid">' + "".join(pairs) + "</div>"),
        *((f"Table 2: domain gap of the models ({crop.replace('_', ' ')})", table2(scores, models, crop))
          for crop in crops),
        (f"Per-sample scores ({models[0] if models else '-'})",
         f'<img src="figures/{made["scores"]}" alt="per-sample scores">'),
        ("Rotation-error CDFs", f'<img src="figures/{made["cdf"]}" alt="rotation error CDF">'),
        *tracking_section(config, workspace, figure_dir),
        ("Provenance", provenance(config, workspace)),
    ]
    body = "".join(f"<section><h2>{html.escape(title)}</h2>{content}</section>" for title, content in sections)
    name = workspace.location.rsplit("/", 1)[-1]
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>SPEED+ builder report: {html.escape(name)}</title>
<style>
body {{ font-family: sans-serif; margin: 2em auto; max-width: 1200px; color: #222; background: #fff; }}
h1 {{ border-bottom: 2px solid #444; }} h2 {{ margin-top: 1.6em; color: #334; }}
table {{ border-collapse: collapse; margin: 0.5em 0; }} td, th {{ border: 1px solid #bbb; padding: 3px 8px; }}
th {{ background: #eef; }} img {{ max-width: 100%; }}
.grid {{ display: flex; flex-wrap: wrap; gap: 10px; }} figure {{ margin: 0; }}
figcaption {{ font-size: 0.85em; color: #555; }} pre {{ font-size: 0.8em; background: #f6f6f6; padding: 1em; }}
</style></head><body>
<h1>SPEED+ builder report: {html.escape(workspace.location)}</h1>
<p>Profile {html.escape(config.profile)}, models {html.escape(", ".join(models))}; {len(labels)}
labels, {len(renders)} twins, {len(predictions)} predictions.</p>
{body}
</body></html>
"""
    write_bytes_atomic(out / "index.html", page.encode())
