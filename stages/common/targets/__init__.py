"""The targets shipped with the program, each a target folder (``manifests.target``):
``tango`` (the default: SPEED+'s spacecraft, made by ``make_tango``)."""

from __future__ import annotations

from pathlib import Path

from manifests.target import TARGET_FILE

BUILTIN_ROOT = Path(__file__).parent
DEFAULT_TARGET = "tango"


def builtin_names() -> tuple[str, ...]:
    return tuple(sorted(p.parent.name for p in BUILTIN_ROOT.glob(f"*/{TARGET_FILE}")))


def builtin_folder(name: str = DEFAULT_TARGET) -> Path:
    """The folder of a shipped target; ``KeyError`` names the ones there are."""
    if name not in builtin_names():
        raise KeyError(f"no built-in target {name!r}; built in: {', '.join(builtin_names())}")
    return BUILTIN_ROOT / name
