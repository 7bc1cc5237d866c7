"""Errors that end a command with exit code 1: bad input or configuration.

Their messages name the file, row, field or key at fault and say what was expected.
"""


class InputError(ValueError):
    """Bad input or configuration (exit code 1)."""
