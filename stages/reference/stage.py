"""The train-reference stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).
"""

from __future__ import annotations

import pyarrow as pa

from core.config import Config
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest
from manifests.integrity import sha256
from stages.common.target import Target
from stages.common.workspace_target import workspace_target


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the training set (render --set train); writes ``models`` and ``W/models/``, whose
    metadata record the training set's camera (the input size) and render keys."""
    recorded = ("camera", "render.seed", "render.train_count", "render.train_resolution_scale", "render.train_spp")
    return Resolved(("train",), ("reference", *recorded), {}, ("models",))


def model_names(config: Config) -> list[str]:
    """The names of the models ``reference.variants`` trains (``W/models/<name>.onnx``)."""
    from stages.reference import train

    return [train.VARIANTS[variant][0] for variant in config.reference.variants]


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Train every variant of ``reference.variants`` missing from the ``models`` manifest."""
    from stages.reference import train

    target = workspace_target(config, workspace)
    done = read_keys(workspace, "models")
    todo = [v for v in config.reference.variants if train.VARIANTS[v][0] not in done]
    if "detector" in todo:
        _train_detector(config, workspace, target)
    todo = [v for v in todo if v != "detector"]
    data = train.load_training_set(workspace, config.reference, target, train.channels_of(config)) if todo else None
    for variant in todo:
        name = train.VARIANTS[variant][0]
        relpath = workspace.model_relpath(name)
        path = workspace.resolve(relpath)
        checkpoint = path.with_name(f"{name}.checkpoint.pt")
        card = train.run(config, data, variant, path, target, checkpoint, tag=workspace.output_fingerprint("models"))
        held = card["held_out"]
        with open_sink(workspace, "models", 1) as sink:
            sink.add({"model": name, "path": relpath, "sha256": sha256(path),
                      "training_images": card["training_images"], "held_out_images": card["held_out_images"],
                      "held_out_mean_speed_score": held["mean_speed_score"],
                      "held_out_median_rotation_error_deg": held["median_rotation_error_deg"],
                      "train_seconds": card["train_seconds"], "held_out_median_box_iou": None})
        checkpoint.unlink(missing_ok=True)
    return read_manifest(workspace, "models")


def _train_detector(config: Config, workspace: Workspace, target: Target) -> None:
    from stages.common.detector import DETECTOR_NAME
    from stages.reference import detect, train

    relpath = workspace.model_relpath(DETECTOR_NAME)
    path = workspace.resolve(relpath)
    channels = train.channels_of(config)
    card = detect.run(config, workspace, path, target, channels, train.NORMALISATION[channels])
    with open_sink(workspace, "models", 1) as sink:
        sink.add({"model": DETECTOR_NAME, "path": relpath, "sha256": sha256(path),
                  "training_images": card["training_images"], "held_out_images": card["held_out_images"],
                  "held_out_mean_speed_score": None, "held_out_median_rotation_error_deg": None,
                  "train_seconds": card["train_seconds"],
                  "held_out_median_box_iou": card["held_out"]["median_box_iou"]})
