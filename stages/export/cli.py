"""The export command's own options (``core.command``: the CLI puts the common ones beside
them). The format and folder are this export's alone: set for this run, never saved."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from core.command import Request, absolute, key_help
from core.config import Override
from stages.export.config import ExportConfig


def options(
    format_: Annotated[str, typer.Option("--format", help=key_help(ExportConfig, "format"))] = "speedplus",
    out_dir: Annotated[Path | None, typer.Option("--out", help=key_help(ExportConfig, "out"))] = None,
) -> Request:
    """Run the export stage: the labels and their images as a SPEED+, BOP or SHIRT dataset, the
    plan as robot programs (robot) or the captures as a logger's session (session), in
    W/export/<format> or --out. The format and folder are this export's alone (a later export
    in another format never reuses them); `status` reports each format's export."""
    return Request(transient=(Override.of("export.format", format_, "--format"),
                              *absolute("export.out", out_dir, "--out")))
