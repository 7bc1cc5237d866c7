"""What a stage's own command-line options ask of a command (docs/architecture.md section 2).

A stage whose command takes options beyond the common ones (workspace, profile, --config,
--set, --force, and the engine's) has a ``cli`` module in its package: its ``options(...)``
takes them as typer-annotated parameters and returns a ``Request``. The CLI
(``pipeline/cli.py``) puts the common options beside them and runs the request; it knows
no stage's options. A parameter named as a common one (render's ``set_``) takes its place.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from core.config.facility import FacilityConfig, TargetConfig
from core.config.loading import Override, parse_override
from core.config.model import FACILITY_SECTIONS, Config

if TYPE_CHECKING:
    from manifests import Workspace


@dataclass(frozen=True)
class Request:
    """A command's run, as its options ask it."""

    #: set in the configuration and saved in ``W/config.toml`` (as ``--set`` is)
    saved: tuple[Override, ...] = ()
    #: set for this run only (what the command does: render's image set, export's format)
    transient: tuple[Override, ...] = ()
    #: the stages run, in order (empty: the command's own stage)
    stages: tuple[str, ...] = ()
    #: members redone alone under ``--force`` (evaluate's models by name)
    redo: tuple[str, ...] = ()
    #: what depends on the configuration as resolved (``config``, ``workspace``, ``force``),
    #: asked before anything changes: the rest of the request (evaluate's added models,
    #: train-reference's recipe and destinations); it may refuse
    then: Callable[[Config, Workspace, bool], Request] | None = None
    #: after the stages succeeded: the lines to print (train-reference's models)
    report: Callable[[Workspace], list[str]] | None = None
    #: lines to print before the run (the models an added one replaces)
    notes: tuple[str, ...] = ()

    def merged(self, more: Request) -> Request:
        """This request with ``more``'s overrides, notes and members after its own, and
        ``more``'s stages and report where it names them."""
        return Request(self.saved + more.saved, self.transient + more.transient, more.stages or self.stages,
                       self.redo + more.redo, more.then, more.report or self.report, self.notes + more.notes)


def key_help(section: type, key: str) -> str:
    """An option's help: the help and unit of the configuration key it sets, and the key."""
    for item in fields(section):
        if item.name == key:
            unit = item.metadata.get("unit", "")
            return f"{item.metadata['help']}{f' [{unit}]' if unit else ''} ({_section_name(section)}.{key})"
    raise KeyError(f"{section.__name__} has no key {key!r}")


def _section_name(section: type) -> str:
    """``[name]`` of a section dataclass, from the module that declares it (``SECTIONS``)."""
    import sys

    declared = getattr(sys.modules[section.__module__], "SECTIONS", FACILITY_SECTIONS)
    name = next((name for name, kind in declared.items() if kind is section), None)
    if name is None:
        raise KeyError(f"{section.__name__} is not in its module's SECTIONS")
    return name


def overrides(texts: list[str] | None) -> tuple[Override, ...]:
    """``--set`` texts as overrides."""
    return tuple(parse_override(text) for text in texts or [])


def absolute(dotted: str, path: Path | None, option: str) -> tuple[Override, ...]:
    """A folder option as the override of its key, absolute: the saved configuration must
    name the same folder from any directory."""
    return () if path is None else (Override.of(dotted, str(path.expanduser().resolve()), option),)


TargetOption = Annotated[Path | None, typer.Option(
    "--target", help=key_help(TargetConfig, "path") + "; the plan copies it into W/target")]
FacilityOption = Annotated[Path | None, typer.Option(
    "--facility", help=key_help(FacilityConfig, "path") + "; check one with speedplus facility DIR")]


def folders(target: Path | None, facility: Path | None = None) -> tuple[Override, ...]:
    """``--target DIR`` and ``--facility DIR`` as the overrides ``target.path`` and
    ``facility.path``."""
    return absolute("target.path", target, "--target") + absolute("facility.path", facility, "--facility")
