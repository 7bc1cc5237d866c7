"""The report stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

Sections, listed in a table of contents with anchors: Table 1 (with TRON's rows),
calibration residuals and every calibration capture's corners (worst first), the label pose
distribution, the motion-capture decisions, Table 2 per crop, a row per sample, the
per-sample scores and rotation-error CDFs, every sample's pictures (testbed, twin, label
wireframe; thumbnails linking to the full-size images), the tracking baseline of a
trajectory plan, and the run's provenance. Tables scroll inside their box: the page fits
a 1280-pixel window.
"""

from __future__ import annotations

import html
import re
from pathlib import Path

from core.config import Config
from core.stage_io import Resolved
from manifests import Workspace, read_manifest, read_marker
from manifests.facility import read_facility_spec
from manifests.files import write_bytes_atomic
from manifests.sidecars import read_calibration, read_session
from manifests.workspace import REPORT_DIR, REPORT_PAGE
from stages.common.json_arrays import calibrated_camera
from stages.common.robots.facility import presented_share
from stages.common.target import feature_edges
from stages.common.workspace_target import workspace_target
from stages.report.answer import gap_sentence, labels_sentence
from stages.report.gallery import calibration_overlays, sample_gallery
from stages.report.sections import (
    DEFINITIONS,
    comparisons_section,
    per_sample_table,
    provenance,
    rejection_table,
    table1,
    table2,
    tracking_section,
)

STYLE = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1200px; padding: 0 1em; color: #222; background: #fff; }
h1 { border-bottom: 2px solid #444; font-size: 1.5em; overflow-wrap: anywhere; } h2 { margin-top: 1.6em; color: #334; }
.scroll { max-width: 100%; overflow-x: auto; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
td, th { border: 1px solid #bbb; padding: 3px 6px; } th { background: #eef; }
img { max-width: 100%; } nav ol { columns: 2; }
.grid { display: flex; flex-wrap: wrap; gap: 10px; } figure { margin: 0; }
figure.sample img { width: 240px; margin-right: 2px; }
figcaption { font-size: 0.85em; color: #555; max-width: 740px; overflow-wrap: anywhere; }
pre { font-size: 0.8em; background: #f6f6f6; padding: 1em; white-space: pre-wrap; }
"""


def _anchor(title: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", title.lower()).strip("-")


def page(workspace: Workspace, summary: str, sections: list[tuple[str, str]]) -> str:
    """The HTML page: a title, the summary, a table of contents and every section."""
    toc = "".join(f'<li><a href="#{_anchor(title)}">{html.escape(title)}</a></li>' for title, _ in sections)
    body = "".join(f'<section id="{_anchor(title)}"><h2>{html.escape(title)}</h2>{content}</section>'
                   for title, content in sections)
    name = workspace.location.rsplit("/", 1)[-1]
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>SPEED+ builder report: {html.escape(name)}</title>
<style>{STYLE}</style></head><body>
<h1>SPEED+ builder report: {html.escape(workspace.location)}</h1>
<p>{summary}</p>
<nav><h2>Contents</h2><ol>{toc}</ol></nav>
{body}
</body></html>
"""



def facility_sentence(config: Config, workspace: Workspace) -> str:
    """On a facility folder, what share of SO(3) x the range it presented (the dataset is
    uniform over that share, not over all of it), as the plan and ``status`` say it."""
    if not config.facility.path or read_marker(workspace, "plan") is None:
        return ""  # TRON's room presents every pose the plan draws; a replay has no plan
    rows = read_manifest(workspace, "plan").select(["session", "redraws", "view", "sequence_id"]).to_pylist()
    return " " + html.escape(presented_share(rows, read_facility_spec(Path(config.facility.path)).name)) + "."


VIEW_NOTE = ("<p><code>speedplus view W</code> writes <code>W/view.rrd</code>, which the Rerun viewer opens "
             "(<code>rerun W/view.rrd</code>): the room, the arms at each planned pose on the <em>capture</em> "
             "timeline, the camera's frustum with its image, motion capture's lines of sight, and each label's target "
             "against the true one, green where it meets both SPEED+ thresholds and red where it misses one. It is "
             "made on demand, not with the report: a recording's bytes carry the time it was written.</p>")
RESIDUALS_CAPTION = ("Each calibration capture: how far each source's calibrated pose lies from the pattern's own "
                     "(PnP) pose, the figures Table 1's in-sample rows average.")
POSES_CAPTION = "The labels' poses: positions at full scale and the attitudes' Euler angles, over the dataset."
SCORES_CAPTION = ("Each label's SPEED score on its synthetic twin against its testbed image (the paper's Figure 12): "
                  "above the diagonal, the testbed image scored worse.")
CDF_CAPTION = ("The share of images under each rotation error, per configuration and crop: solid on the testbed "
               "images, dashed on their twins, a colour per model.")


def _figure(name: str, alt: str, caption: str) -> str:
    return (f'<figure><img src="figures/{name}" alt="{html.escape(alt)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def sigmas_note(mockup_scale: float | None) -> str:
    """Why a label's sigma reads larger than Table 1's millimetres."""
    scale = (f"divided by the mock-up's scale ({mockup_scale:g}: {1 / mockup_scale:.3g} times larger)"
             if mockup_scale else "at the target's full scale")
    return ("<p>Table 1 is the calibration's error on its own captures, at mock-up scale. A label's sigma (the "
            f"per-sample table, sigma t) is that label's uncertainty at full scale: the calibration's error carried "
            f"to the dataset's ranges and {html.escape(scale)}, so it reads larger than Table 1's figures.</p>")


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads everything a run made (a trajectory plan's tracks too); writes ``W/report/``
    (its marker: ``report``)."""
    tracks = ("tracks",) if config.plan.mode == "trajectory" else ()
    return Resolved(("labels", "renders", "predictions", "scores", "comparisons", *tracks),
                    ("evaluate.models", "plan.mode", "facility.path"), {"profile": config.profile}, ("report",))


def run(config: Config, workspace: Workspace) -> None:
    from stages.report import figures  # matplotlib, 0.4 s: not for the commands that only resolve this stage

    out = workspace.root / REPORT_DIR
    figure_dir = out / "figures"
    calibration = read_calibration(workspace)
    labels = read_manifest(workspace, "labels").to_pylist()
    poses = {row["sample_id"]: row for row in read_manifest(workspace, "poses").to_pylist()}
    renders = {row["sample_id"]: row for row in read_manifest(workspace, "renders").to_pylist()}
    captures = {row["sample_id"]: row for row in read_manifest(workspace, "captures").to_pylist()}
    predictions = read_manifest(workspace, "predictions").to_pylist()
    scores = read_manifest(workspace, "scores").to_pylist()
    comparisons = read_manifest(workspace, "comparisons").to_pylist()
    samples = read_manifest(workspace, "calibration_samples").to_pylist()
    camera = calibrated_camera(workspace)

    models = list(dict.fromkeys(Path(text).stem for text in config.evaluate.models
                                if any(r["model"] == Path(text).stem for r in predictions)))
    models += sorted({r["model"] for r in predictions} - set(models))
    crops = [c for c in ("oracle_box", "full", "self") if any(r["crop"] == c for r in predictions)]
    runs = [(model, crop) for model in models for crop in crops
            if any(r["model"] == model and r["crop"] == crop for r in predictions)]
    # the first model on its contract's crop: the per-sample figure
    primary = [r for r in predictions if models and r["model"] == models[0] and crops and r["crop"] == crops[0]]
    made = {
        "residuals": figures.calibration_residuals(
            samples, figure_dir / "calibration_residuals.png",
            (calibration.session.name("kuka"), calibration.session.name("vicon"))),
        "poses": figures.pose_distribution(labels, figure_dir / "pose_distribution.png"),
        "scores": figures.per_sample_scores(primary, figure_dir / "per_sample_scores.png"),
        "cdf": figures.rotation_cdf(predictions, models, figure_dir / "rotation_cdf.png"),
    }
    wireframe = feature_edges(workspace_target(config, workspace))
    scale = read_session(workspace).mockup_scale
    sections = [
        ("How good the labels are", labels_sentence(config, workspace, calibration, labels, list(poses.values()))
         + gap_sentence(scores, models, crops)),
        ("What the figures mean", f"<p>{html.escape(DEFINITIONS)}</p>"),
        *((f"Table 2: domain gap of the models ({crop.replace('_', ' ')})", table2(scores, models, crop))
          for crop in crops),
        ("Each model against the reference", comparisons_section(comparisons)),
        ("Table 1: calibration accuracy", table1(calibration) + sigmas_note(scale)),
        ("Calibration residuals", _figure(made["residuals"], "calibration residuals", RESIDUALS_CAPTION)),
        ("Pose distribution of the labels", _figure(made["poses"], "pose distribution", POSES_CAPTION)),
        ("In 3D: the facility, the plan and the labels' errors", VIEW_NOTE),
        ("Motion-capture rejection and label sources", rejection_table(list(poses.values()), labels)),
        ("Every sample", per_sample_table(labels, poses, predictions, runs)),
        (f"Per-sample scores ({models[0] if models else '-'})",
         _figure(made["scores"], "per-sample scores", SCORES_CAPTION)),
        ("Rotation-error CDFs", _figure(made["cdf"], "rotation error CDF", CDF_CAPTION)),
        ("Calibration captures", calibration_overlays(workspace, out, samples, captures, camera)),
        ("Pictures of every sample", sample_gallery(workspace, out, labels, captures, renders, camera, wireframe,
                                                     (f"{models[0]} ({crops[0]})" if primary else "", primary))),
        *tracking_section(config, workspace, figure_dir),
        ("Provenance", provenance(config, workspace)),
    ]
    summary = (f"Profile {html.escape(config.profile)}, models {html.escape(', '.join(models))}; {len(labels)} "
               f"labels, {len(renders)} twins, {len(predictions)} predictions.{facility_sentence(config, workspace)}")
    write_bytes_atomic(out / REPORT_PAGE, page(workspace, summary, sections).encode())
