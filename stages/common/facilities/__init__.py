"""Built-in facility folders (docs/user-guide.md, "Your own facility"): TRON's room."""

from __future__ import annotations

from pathlib import Path


def builtin_folder() -> Path:
    """The TRON facility folder: facility.toml beside the KR 16-2's URDF."""
    return Path(__file__).resolve().parent / "tron"
