"""The render command's own options (``core.command``: the CLI puts the common ones beside
them). Its ``--set`` also names the image set, for this run only."""

from __future__ import annotations

from typing import Annotated

import typer

from core.command import Request, key_help, overrides
from core.config import Override
from stages.render.config import RenderConfig


def options(
    set_: Annotated[list[str] | None, typer.Option(
        "--set", "-s", help="twin (one per label) or train (the training set); or, like every command, "
        "section.key=value to override one key (repeatable)")] = None,
    count: Annotated[int | None, typer.Option("--count", help=key_help(RenderConfig, "train_count"))] = None,
) -> Request:
    """Run the render stage: Mitsuba 3 twins of the labels, or the training set."""
    saved = overrides([value for value in set_ or [] if "=" in value])
    if count is not None:
        saved += (Override.of("render.train_count", count, "--count"),)
    return Request(saved=saved, transient=tuple(Override.of("render.set", value, "--set")
                                                for value in set_ or [] if "=" not in value))
