"""The built-in facility folder (docs/user-guide.md, "Your own facility"): TRON's room,
kept in core/facilities/tron/ because the configuration's [testbed] defaults are read
from it."""

from __future__ import annotations

from pathlib import Path

from core.facilities import TRON_FOLDER


def builtin_folder() -> Path:
    """The TRON facility folder: facility.toml beside the KR 16-2's URDF."""
    return TRON_FOLDER
