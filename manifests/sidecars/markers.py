"""``W/markers.json``: where the virtual testbed stuck the motion-capture markers on the
mock-up (docs/architecture.md section 7), declared in the target folder or chosen on its
main body (``stages.common.markers``). Written by acquire (virtual); read by tests and by a
lab that wants to put its own markers where the virtual ones sat."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, read, save
from manifests.workspace import Workspace

MARKERS_VERSION = 1
MARKER_SOURCES = ("declared", "chosen")


@dataclass(frozen=True)
class MarkersRecord:
    """Per marker (M of them): its centre in the body frame T at mock-up scale (m) and the
    outward unit normal of the surface under it; whether the target folder declared them or
    they were chosen on the mesh, and on which part."""

    source: str
    part: str
    centres_m: tuple[tuple[float, float, float], ...]
    normals: tuple[tuple[float, float, float], ...]

    def to_json(self) -> dict[str, Any]:
        return {"version": MARKERS_VERSION, "source": self.source, "part": self.part,
                "centres_m": [list(c) for c in self.centres_m], "normals": [list(n) for n in self.normals]}

    @classmethod
    def from_fields(cls, f: Fields) -> MarkersRecord:
        f.only("version", "source", "part", "centres_m", "normals")
        columns = {}
        for key in ("centres_m", "normals"):
            rows = f.raw(key)
            if not isinstance(rows, list) or len(rows) < 3:
                raise f.fail(key, "a list of at least three [x, y, z]")
            inner = Fields({str(i): row for i, row in enumerate(rows)}, f.where, f"{key}.")
            columns[key] = tuple(tuple(inner.vector(str(i), 3)) for i in range(len(rows)))
        if len(columns["normals"]) != len(columns["centres_m"]):
            raise f.fail("normals", f"one per marker ({len(columns['centres_m'])})")
        return cls(f.text("source", MARKER_SOURCES), f.text("part"), columns["centres_m"], columns["normals"])


def write_markers(workspace: Workspace, record: MarkersRecord) -> None:
    save(workspace.markers_path, record.to_json())


def read_markers(workspace: Workspace) -> MarkersRecord:
    return read(workspace.markers_path, MARKERS_VERSION, "acquire", MarkersRecord.from_fields)
