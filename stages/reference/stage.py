"""The train-reference stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).
"""

from __future__ import annotations

import pyarrow as pa

from core.config import Config, Override, with_overrides
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest, read_marker
from manifests.integrity import sha256
from speedplus.errors import InputError
from stages.common.target import Target
from stages.common.workspace_target import workspace_target


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the training set (render --set train); writes ``models`` and ``W/models/``, whose
    metadata record the training set's camera (the input size) and render keys."""
    recorded = ("camera", "render.seed", "render.train_count", "render.train_resolution_scale", "render.train_spp")
    return Resolved(("train",), ("reference", *recorded), {}, ("models",))


def training_set(config: Config) -> tuple[Override, ...]:
    """The render settings of the training set train-reference renders and trains on: its
    recipe's (``reference.images``, ``reference.resolution_scale``), for the command only."""
    return (Override.of("render.set", "train", "train-reference"),
            Override.of("render.train_count", config.reference.images, "reference.images"),
            Override.of("render.train_resolution_scale", config.reference.resolution_scale,
                        "reference.resolution_scale"))


def status_views(config: Config, workspace: Workspace) -> list[tuple[str, Config]]:
    """``status`` judges the models under the training set they were trained on, as the
    command runs them (else a training set sized by ``render --count`` made them stale)."""
    return [("train-reference", with_overrides(config, training_set(config)))]


def refuse_replacing(config: Config, workspace: Workspace, force: bool) -> None:
    """A training set of another size than the recipe's (``render --set train --count N``)
    is the user's: replaced only with --force, and the refusal says how to train on it."""
    marker = read_marker(workspace, "train")
    if marker is None or marker.rows == config.reference.images or force:
        return
    raise InputError(f"{workspace.display(workspace.manifest_dir('train'))} holds a training set of {marker.rows} "
                     f"images, and reference.images asks for {config.reference.images}: train on those with "
                     f"`speedplus train-reference -w {workspace.location} --set reference.images={marker.rows}`, or "
                     f"replace them by {config.reference.images} with --force")


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
