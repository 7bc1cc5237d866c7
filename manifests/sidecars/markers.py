"""``W/markers.json``: where the virtual testbed stuck the motion-capture markers on the
mock-up (docs/architecture.md section 7), declared in the target folder or chosen on its
parts (``stages.common.markers``). Written by acquire (virtual); read by tests and by a
lab that wants to put its own markers where the virtual ones sat."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, read, save
from manifests.workspace import Workspace

MARKERS_VERSION = 2  # 2: the part of each marker (was one part for all)
MARKER_SOURCES = ("declared", "chosen")


@dataclass(frozen=True)
class MarkersRecord:
    """Per marker (M of them): its centre in the body frame T at mock-up scale (m) and the
    outward unit normal of the surface under it and the part it is stuck on; whether the
    target folder declared them or they were chosen on the mesh."""

    source: str
    parts: tuple[str, ...]
    centres_m: tuple[tuple[float, float, float], ...]
    normals: tuple[tuple[float, float, float], ...]

    def to_json(self) -> dict[str, Any]:
        return {"version": MARKERS_VERSION, "source": self.source, "parts": list(self.parts),
                "centres_m": [list(c) for c in self.centres_m], "normals": [list(n) for n in self.normals]}

    @classmethod
    def from_fields(cls, f: Fields) -> MarkersRecord:
        f.only("version", "source", "parts", "centres_m", "normals")
        columns = {}
        for key in ("centres_m", "normals"):
            rows = f.raw(key)
            if not isinstance(rows, list) or len(rows) < 3:
                raise f.fail(key, "a list of at least three [x, y, z]")
            inner = Fields({str(i): row for i, row in enumerate(rows)}, f.where, f"{key}.")
            columns[key] = tuple(tuple(inner.vector(str(i), 3)) for i in range(len(rows)))
        for key in ("normals", "parts"):
            if not isinstance(f.raw(key), list) or len(f.raw(key)) != len(columns["centres_m"]):
                raise f.fail(key, f"one per marker ({len(columns['centres_m'])})")
        parts = Fields({str(i): name for i, name in enumerate(f.raw("parts"))}, f.where, "parts.")
        names = tuple(parts.text(str(i)) for i in range(len(columns["centres_m"])))
        return cls(f.text("source", MARKER_SOURCES), names, columns["centres_m"], columns["normals"])


def write_markers(workspace: Workspace, record: MarkersRecord) -> None:
    save(workspace.markers_path, record.to_json())


def read_markers(workspace: Workspace) -> MarkersRecord:
    return read(workspace.markers_path, MARKERS_VERSION, "acquire", MarkersRecord.from_fields)
