"""What every configuration section is made of: documented fields and the one error type."""

from __future__ import annotations

from dataclasses import MISSING, field, fields
from typing import Any

from speedplus.errors import InputError


class ConfigError(InputError):
    """Bad configuration; the message names the key (and the file) at fault."""


def param(default: Any, help: str, unit: str = "") -> Any:  # noqa: A002 - "help" reads best at call sites
    """A documented field: ``help`` becomes CLI/TOML documentation, ``unit`` is shown with it."""
    return field(default=default, metadata={"help": help, "unit": unit})



def documented(section: type) -> list[tuple[str, Any, str, str]]:
    """Every key of a configuration section (a dataclass of ``param`` fields): (name,
    default, unit, help), in declaration order; what ``speedplus keys`` prints."""
    out = []
    for item in fields(section):
        default = item.default if item.default is not MISSING else (
            item.default_factory() if item.default_factory is not MISSING else None)
        out.append((item.name, default, item.metadata.get("unit", ""), item.metadata.get("help", "")))
    return out
