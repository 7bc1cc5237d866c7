"""The geometry proof of the twins (virtual testbed only): how well each twin's mask covers
the mock-up's silhouette in the testbed capture of the same sample.

The silhouette comes from the virtual testbed's own scene at the TRUE poses of the capture
(``VirtualTestbed.silhouette``), through the true lens; the twin comes from the label
through the calibrated camera. IoU near 1 at the true pose proves that plan, testbed,
labels and render share one set of conventions; at the label it measures label error in
pixels' terms. Reads the hidden truth: for tests, benchmarks and the report only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from core.config import Config
from manifests import Workspace, read_manifest
from stages.common.image_io import read_image
from stages.common.json_arrays import calibrated_camera
from stages.common.workspace_target import workspace_target
from stages.render.jobs import RenderJob
from stages.render.worker import RenderWorker


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (H, W)."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def twin_overlap(config: Config, workspace: Workspace, *, at_truth: bool = True) -> list[dict[str, Any]]:
    """Per rendered twin: IoU with the testbed silhouette of the twin as rendered (at the
    label) and, with ``at_truth``, of a twin rendered at the true pose."""
    from stages.acquire.virtual import VirtualTestbed

    testbed = VirtualTestbed(config, workspace)
    plan = {row["sample_id"]: row for row in read_manifest(workspace, "plan").to_pylist()}
    truth = {row["sample_id"]: row for row in read_manifest(workspace, "truth").to_pylist()}
    labels = {row["sample_id"]: row for row in read_manifest(workspace, "labels").to_pylist()}
    target = workspace_target(config, workspace)
    scale = target.mockup_scale
    worker = RenderWorker(calibrated_camera(workspace), target, 16, 1, 2) if at_truth else None
    rows = []
    for render in read_manifest(workspace, "renders").to_pylist():
        sample_id = render["sample_id"]
        silhouette = testbed.silhouette(plan[sample_id])
        twin = read_image(workspace.resolve(render["mask_path"]), "gray") > 127
        row = {"sample_id": sample_id, "label_source": labels[sample_id]["label_source"],
               "domain": labels[sample_id]["domain"], "view": labels[sample_id]["view"],
               "silhouette_px": int(silhouette.sum()), "iou_label": iou(twin, silhouette)}
        if worker is not None:
            true_row = truth[sample_id]
            job = RenderJob(sample_id, "twin", tuple(true_row["cam_from_target_q"]),
                            tuple(np.asarray(true_row["cam_from_target_t"]) / scale), (0.0, 0.0, -1.0), 1.0, False,
                            render["seed"])
            row["iou_truth"] = iou(worker.surfaces.through_lens(job.cam_from_target(), worker.camera).mask, silhouette)
        rows.append(row)
    return rows
