"""The report's picture sections: every labelled sample (testbed, twin, wireframe overlay)
and every calibration capture (detected against reprojected corners, worst first), as
thumbnails that link to the full-size images (the workspace's own files, or full-size
overlays written beside the page)."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from manifests import Workspace
from stages.common import geometry as g
from stages.common.image_io import read_image, to_uint8, write_png_atomic
from stages.common.lens import LensCamera


def _link(href: str, thumb: str, alt: str) -> str:
    return f'<a href="{html.escape(href)}"><img src="{html.escape(thumb)}" alt="{html.escape(alt)}"></a>'


def _write(path: Path, image: np.ndarray) -> str:
    write_png_atomic(path, image)
    return path.name


def sample_gallery(workspace: Workspace, out: Path, labels: list[dict[str, Any]], captures: dict[str, dict],
                   renders: dict[str, dict], camera: LensCamera, wireframe: Any,
                   scored: tuple[str, list[dict[str, Any]]] = ("", [])) -> str:
    """A figure per label: the testbed image (brightened), its twin and the label's
    wireframe on the image, each a thumbnail linking to the full-size picture; its caption
    gives both SPEED scores of ``scored`` (a model and crop's name, its predictions)."""
    from stages.report import figures  # matplotlib: not for the commands that only resolve the report

    name, predictions = scored
    score = {(p["sample_id"], p["domain"] == "synthetic"): p["score_speed"] for p in predictions}
    figures_html = []
    for label in sorted(labels, key=lambda r: r["sample_id"]):
        sample_id = label["sample_id"]
        capture_path = captures[sample_id]["image_path"]
        capture = to_uint8(read_image(workspace.fetch(capture_path), "bgr"))
        brightened = figures.brighten(capture)
        drawn = figures.overlay(capture, label, camera.camera_matrix, camera.dist, wireframe, brightened)
        full = _write(out / "overlays" / f"{sample_id}.png", drawn)
        cells = [_link(f"../{capture_path}", "thumbs/" + _write(out / "thumbs" / f"testbed_{sample_id}.png",
                                                                 figures.thumbnail(brightened, 240)),
                       f"testbed image {sample_id}")]
        if sample_id in renders:
            twin_path = renders[sample_id]["image_path"]
            twin = to_uint8(read_image(workspace.fetch(twin_path), "bgr"))
            cells.append(_link(f"../{twin_path}", "thumbs/" + _write(out / "thumbs" / f"twin_{sample_id}.png",
                                                                      figures.thumbnail(twin, 240)),
                               f"twin of {sample_id}"))
        cells.append(_link(f"overlays/{full}", "thumbs/" + _write(out / "thumbs" / f"overlay_{sample_id}.png",
                                                                  figures.thumbnail(drawn, 240)),
                           f"label wireframe on {sample_id}"))
        caption = f'{sample_id}: {label["view"]}, {label["domain"]}, {label["label_source"]}'
        if (sample_id, False) in score or (sample_id, True) in score:
            caption += "; " + name + " SPEED score: " + ", ".join(
                f"{where} {score[(sample_id, twin)]:.3f}" for where, twin in (("testbed", False), ("twin", True))
                if (sample_id, twin) in score)
        figures_html.append(f'<figure id="sample-{html.escape(sample_id)}" class="sample">{"".join(cells)}'
                            f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    return ("<p>Every labelled sample: the testbed image (brightened), its synthetic twin and the label's "
            "wireframe on the image; each links to the full-size picture.</p>"
            f'<div class="grid">{"".join(figures_html)}</div>')


def calibration_overlays(workspace: Workspace, out: Path, samples: list[dict[str, Any]], captures: dict[str, dict],
                         camera: LensCamera) -> str:
    """Every calibration capture with its detected corners (green) and the same corners
    reprojected through the calibrated robots' estimate (red), worst first."""
    from stages.report import figures

    entries = []
    for sample in samples:
        if sample["corners_px"] is None:
            continue
        detected = np.asarray(sample["corners_px"], float)
        reprojected, rms = None, None
        if sample["kuka_cam_from_target_q"] is not None:
            pose = g.transform_from_qt(sample["kuka_cam_from_target_q"], sample["kuka_cam_from_target_t"])
            reprojected = g.project(pose, np.asarray(sample["corners_target_m"], float), camera.camera_matrix,
                                    camera.dist)
            rms = float(np.sqrt(np.mean(np.sum((reprojected - detected) ** 2, axis=1))))
        entries.append((-(rms if rms is not None else np.inf), sample, detected, reprojected, rms))
    figures_html = []
    for _, sample, detected, reprojected, rms in sorted(entries, key=lambda e: (e[0], e[1]["sample_id"])):
        sample_id = sample["sample_id"]
        image = to_uint8(read_image(workspace.fetch(captures[sample_id]["image_path"]), "bgr"))
        drawn = figures.corners(image, detected, reprojected)
        full = _write(out / "calibration" / f"{sample_id}.png", drawn)
        thumb = _write(out / "thumbs" / f"calibration_{sample_id}.png", figures.thumbnail(drawn, 240))
        state = "used" if sample["used"] else f"not used: {sample['reason']}"
        error = "no robots' estimate" if rms is None else f"{rms:.2f} px RMS through the robots"
        figures_html.append(f'<figure class="sample">{_link(f"calibration/{full}", f"thumbs/{thumb}", sample_id)}'
                            f"<figcaption>{html.escape(sample_id)}: {len(detected)} corners, {html.escape(error)}; "
                            f"{html.escape(state)}</figcaption></figure>")
    return ("<p>Each calibration capture, worst first: the detected pattern corners (green) and the same corners "
            "reprojected through the calibrated robots' estimate of the pose (red), with the calibrated camera.</p>"
            f'<div class="grid">{"".join(figures_html)}</div>')
