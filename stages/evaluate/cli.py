"""The evaluate command's own options (``core.command``: the CLI puts the common ones beside
them)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from core.command import Request
from core.config import Config, Override

if TYPE_CHECKING:
    from manifests import Workspace


def options(
    model: Annotated[list[Path] | None, typer.Option(
        "--model", metavar="FILE.onnx", help="add this ONNX model to evaluate.models and score it beside the "
        "others, whose results are kept; with --force, redo only it (repeatable)")] = None,
) -> Request:
    """Run the evaluate stage: score an ONNX model on the twins and the testbed images (Table 2)."""
    if model is None:
        return Request()

    def added(config: Config, workspace: Workspace, force: bool) -> Request:
        from stages.evaluate.stage import with_added_models  # the stage's code, only when a model is added

        models, notes = with_added_models(config, workspace, model)
        redo = tuple(sorted({path.expanduser().resolve().stem for path in model})) if force else ()
        return Request(saved=(Override.of("evaluate.models", list(models), "--model"),), redo=redo,
                       notes=tuple(notes))

    return Request(then=added)
