"""Errors that end a command with exit code 1: bad input or configuration.

Their messages name the file, row, field or key at fault and say what was expected.
"""


class InputError(ValueError):
    """Bad input or configuration (exit code 1)."""


class RefusalError(InputError):
    """A stage refuses its inputs after looking at them, and leaves what it found out
    (``keep``: manifests written as diagnostics, such as calibrate's per-image reasons).
    A refused command otherwise leaves the workspace as it was; these manifests are kept
    only where the workspace held no results of them before."""

    def __init__(self, message: str, keep: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.keep = keep
