"""Errors that end a command with exit code 1: bad input or configuration.

Their messages name the file, row, field or key at fault and say what was expected.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class InputError(ValueError):
    """Bad input or configuration (exit code 1)."""


class FileError(InputError):
    """Bad content of one file; the message starts with the file (and row)."""

    def __init__(self, path: object, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path, self.message = str(path), message

    def __reduce__(self) -> tuple[type, tuple[str, str]]:  # crosses process boundaries (engines)
        return type(self), (self.path, self.message)


class RefusalError(InputError):
    """A stage refuses its inputs after looking at them, and leaves what it found out
    (``keep``: manifests written as diagnostics, such as calibrate's per-image reasons).
    A refused command otherwise leaves the workspace as it was; these manifests are kept
    only where the workspace held no results of them before."""

    def __init__(self, message: str, keep: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.keep = keep


def unknown_keys(unknown: Iterable[str], known: Iterable[str]) -> str:
    """The unknown keys of a file, each with the known key it most likely meant:
    ``lenght_unit (did you mean length_unit?)``; every file format's message uses it."""
    choices = sorted(known)
    said = []
    for key in sorted(unknown):
        close = difflib.get_close_matches(key, choices, n=1)
        said.append(f"{key} (did you mean {close[0]}?)" if close else key)
    return ", ".join(said)
