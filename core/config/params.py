"""What every configuration section is made of: documented fields and the one error type."""

from __future__ import annotations

from dataclasses import MISSING, field, fields
from typing import Any

from speedplus.errors import InputError


class ConfigError(InputError):
    """Bad configuration; the message names the key (and the file) at fault."""


def param(default: Any, help: str, unit: str = "", applies: tuple[str, ...] = ()) -> Any:  # noqa: A002
    """A documented field: ``help`` becomes CLI/TOML documentation, ``unit`` is shown with it.
    ``applies``: the outputs of its stage the key shapes, where a stage makes several (the
    render stage's ``twin`` and ``train`` sets); empty: all of them."""
    return field(default=default, metadata={"help": help, "unit": unit, "applies": applies})


def keys_for(section: type, output: str) -> tuple[str, ...]:
    """The keys of ``section`` (a dataclass of ``param`` fields) that shape ``output``: a
    stage's fingerprint holds these and no others (docs/architecture.md section 1)."""
    return tuple(item.name for item in fields(section)
                 if not item.metadata.get("applies") or output in item.metadata["applies"])



def at_least(section: str, values: Any, minimums: dict[str, int]) -> None:
    """Each key of ``values`` (a section) at least its minimum; the message names
    ``section.key`` and its value."""
    for key, minimum in minimums.items():
        value = getattr(values, key)
        if value < minimum:
            raise ConfigError(f"{section}.{key}: expected at least {minimum}, got {value!r}")


def unit_quaternion(dotted: str, q: Any) -> None:
    """A quaternion (4,) of norm 1 (within 1e-6); the message names the key and its norm."""
    import numpy as np

    norm = float(np.linalg.norm(np.asarray(q, float)))
    if abs(norm - 1.0) > 1e-6:
        raise ConfigError(f"{dotted}: quaternion norm {norm:.6f} is not 1")


def documented(section: type) -> list[tuple[str, Any, str, str]]:
    """Every key of a configuration section (a dataclass of ``param`` fields): (name,
    default, unit, help), in declaration order; what ``speedplus keys`` prints."""
    out = []
    for item in fields(section):
        default = item.default if item.default is not MISSING else (
            item.default_factory() if item.default_factory is not MISSING else None)
        out.append((item.name, default, item.metadata.get("unit", ""), item.metadata.get("help", "")))
    return out
