"""The train-reference command's own options (``core.command``: the CLI puts the common ones
beside them). It renders the training set its recipe asks for, then trains."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from core.command import Request, key_help
from core.config import Config, Override
from stages.reference.config import ReferenceConfig

if TYPE_CHECKING:
    from manifests import Workspace


def options(
    out_dir: Annotated[Path | None, typer.Option(
        "--out", help="also copy each ONNX model and its card (.json) to this folder as <target>_<model>.onnx; "
        "a file there that this workspace did not make is replaced only with --force")] = None,
    steps: Annotated[int | None, typer.Option("--steps", help=key_help(ReferenceConfig, "max_steps"))] = None,
) -> Request:
    """Run the train-reference stage: render the synthetic training set its recipe asks for
    (section [reference]), train the reference keypoint CNNs on it and the detector of their
    own crop (reference.variants: plain, augmented, detector) and export them to ONNX with
    their contracts (W/models/<name>.onnx, which evaluate then uses); with --out, copy them
    there too, named by target."""

    def recipe(config: Config, workspace: Workspace, force: bool) -> Request:
        from stages.reference.publish import publish_destinations, published
        from stages.reference.stage import model_names, refuse_replacing, training_set

        refuse_replacing(config, workspace, force)  # before anything is rendered or trained
        destinations = {} if out_dir is None else publish_destinations(  # refused before training
            config, workspace, list(model_names(config)), out_dir.expanduser().resolve(), force)
        transient = training_set(config)
        if steps is not None:
            transient += (Override.of("reference.max_steps", steps, "--steps"),)
        return Request(transient=transient, stages=("render", "train-reference"),
                       report=lambda ws: [_line(ws, name, path, row, name in destinations)
                                          for name, path, row in published(ws, destinations)])

    return Request(then=recipe)


def _line(workspace: Workspace, name: str, path: Path, row: dict, copied: bool) -> str:
    """What train-reference says of one model: where it is and its held-out figures."""
    where = path if copied else workspace.display(path)
    held = (f"median box IoU {row['held_out_median_box_iou']:.3f}" if row["held_out_mean_speed_score"] is None
            else f"mean SPEED score {row['held_out_mean_speed_score']:.4f}, median rotation error "
                 f"{row['held_out_median_rotation_error_deg']:.2f} deg")
    return (f"{where}: trained on {row['training_images']} images in {row['train_seconds']:.0f} s; "
            f"held-out synthetic: {held}")
