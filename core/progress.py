"""Progress bars for per-sample loops: count, rate and ETA (rich)."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    Task,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Column
from rich.text import Text

T = TypeVar("T")

console = Console(stderr=True)


class _RateColumn(ProgressColumn):
    """Samples per second."""

    def render(self, task: Task) -> Text:
        speed = task.finished_speed or task.speed
        return Text("-/s" if speed is None else f"{speed:.1f}/s")


class _Tally:
    """Rows the running stage's loops still have to produce (for the message on Ctrl-C)."""

    pending: int | None = None


def reset() -> None:
    """Forget the previous stage's loops (the runner calls it before each stage)."""
    _Tally.pending = None


def remaining() -> int | None:
    """Rows the current stage's tracked loops had not produced yet, or None if it tracked none."""
    return _Tally.pending


#: what the count, rate, elapsed time and ETA take of a line, with the spaces between columns
_FIXED = 44


def columns(width: int) -> tuple[ProgressColumn, ...]:
    """A bar's columns for a terminal ``width`` characters wide: the count, rate, elapsed
    time and ETA whole; the description (cut with an ellipsis) and the bar share the rest."""
    left = max(width - _FIXED, 16)
    bar = max(min(40, left // 3), 5)
    described = Column(max_width=left - bar, no_wrap=True, overflow="ellipsis")
    return (TextColumn("[bold]{task.description}", table_column=described), BarColumn(bar_width=bar),
            MofNCompleteColumn(), _RateColumn(), TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn())


def track(items: Iterable[T], total: int, description: str, rows: Sequence[int] | None = None) -> Iterator[T]:
    """Iterate ``items`` showing ``description``, n/total, a bar, rate, elapsed and ETA.
    ``rows``: the output rows each item makes (default one each), for ``remaining``."""
    weights = list(rows) if rows is not None else [1] * total
    _Tally.pending = (_Tally.pending or 0) + sum(weights)
    with Progress(*columns(console.width), console=console, transient=False,
                  disable=total == 0 or not sys.stderr) as progress:
        task = progress.add_task(description, total=total)
        for index, item in enumerate(items):
            yield item
            _Tally.pending -= weights[index] if index < len(weights) else 0
            progress.advance(task)


def note(message: str) -> None:
    """One line of progress (a step without a per-item loop), on standard error."""
    console.print(f"[dim]{message}[/]", highlight=False)
