"""Built-in facility folders (docs/user-guide.md, "Your own facility"): TRON's room, whose
``facility.toml`` is also where the ``[testbed]`` and ``[virtual]`` defaults of its geometry
come from (core/config/facility.py)."""

from __future__ import annotations

from pathlib import Path

#: the TRON facility folder: facility.toml beside the KR 16-2's URDF
TRON_FOLDER = Path(__file__).resolve().parent / "tron"
