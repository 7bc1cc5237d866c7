"""What every configuration section is made of: documented fields and the one error type."""

from __future__ import annotations

from dataclasses import field
from typing import Any

from speedplus.errors import InputError


class ConfigError(InputError):
    """Bad configuration; the message names the key (and the file) at fault."""


def param(default: Any, help: str, unit: str = "") -> Any:  # noqa: A002 - "help" reads best at call sites
    """A documented field: ``help`` becomes CLI/TOML documentation, ``unit`` is shown with it."""
    return field(default=default, metadata={"help": help, "unit": unit})

