"""The train-reference stage: the reference keypoint CNN (torch) trained on the synthetic
training set (the ``train`` manifest), exported to ONNX with the evaluation contract as
``W/models/reference.onnx`` and its model card ``W/models/reference.json``, recorded as a
row of the ``models`` manifest. Training checkpoints after every epoch
(``W/models/reference.checkpoint.pt``), so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import pyarrow as pa

from manifests import Workspace, open_sink, read_manifest
from manifests.integrity import sha256
from pipeline.config import Config

MODEL_NAME = "reference"


def run(config: Config, workspace: Workspace) -> pa.Table:
    from stages.reference import train

    relpath = workspace.model_relpath(MODEL_NAME)
    path = workspace.resolve(relpath)
    checkpoint = path.with_name(f"{MODEL_NAME}.checkpoint.pt")
    card = train.run(config, workspace, path, checkpoint, tag=workspace.output_fingerprint("models"))
    held = card["held_out"]
    with open_sink(workspace, "models", 1) as sink:
        sink.add({"model": MODEL_NAME, "path": relpath, "sha256": sha256(path),
                  "training_images": card["training_images"], "held_out_images": card["held_out_images"],
                  "held_out_mean_speed_score": held["mean_speed_score"],
                  "held_out_median_rotation_error_deg": held["median_rotation_error_deg"],
                  "train_seconds": card["train_seconds"]})
    checkpoint.unlink(missing_ok=True)
    return read_manifest(workspace, "models")
