"""The acquire command's own options (``core.command``: the CLI puts the common ones
beside them)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from core.command import Request, TargetOption, absolute, folders, key_help
from core.config import Override
from stages.acquire.config import AcquireConfig


def options(
    backend: Annotated[str | None, typer.Option("--backend", help=key_help(AcquireConfig, "backend"))] = None,
    format_: Annotated[str | None, typer.Option("--format", help=key_help(AcquireConfig, "format"))] = None,
    source: Annotated[Path | None, typer.Option("--source", help=key_help(AcquireConfig, "source"))] = None,
    target: TargetOption = None,
) -> Request:
    """Run the acquire stage: drive the testbed (virtual) or ingest a recorded session (replay)."""
    chosen = tuple(Override.of(key, value, option) for key, value, option in (
        ("acquire.backend", backend, "--backend"), ("acquire.format", format_, "--format")) if value is not None)
    return Request(saved=chosen + absolute("acquire.source", source, "--source") + folders(target))
