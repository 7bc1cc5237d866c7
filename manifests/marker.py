"""The completion marker of a manifest, ``W/manifests/_state/<name>.json`` (docs/architecture.md
section 4): written by the runner when the stage that makes the manifest completes, its one
record of what it made (fingerprint, rows, parts and files with their SHA-256, timing, the
configuration it was made with). Read with ``read_marker``, which checks every key a reader
relies on and names the file and the key; a marker written before a key existed reads with
that key's default.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from typing import Any

from manifests.files import write_json_atomic
from manifests.workspace import Workspace
from speedplus.errors import FileError

PART_NAME = re.compile(r"^part-(\d{5})\.parquet$")


class MarkerError(FileError):
    """A completion marker that is not JSON or lacks a key readers rely on; the message
    starts with the file."""


@dataclass(frozen=True)
class PartRecord:
    """One Parquet part of the manifest: ``part-NNNNN.parquet``, its rows, its SHA-256 (hex)."""

    name: str
    rows: int
    sha256: str


@dataclass(frozen=True)
class FileRecord:
    """A workspace file the manifest's rows name: its size [bytes] and SHA-256 (hex)."""

    bytes: int
    sha256: str


@dataclass(frozen=True)
class CompletionMarker:
    """What a completed stage recorded about one of its manifests. ``parts`` and ``files``
    are None in a marker without rows (the report's) or written before they were recorded;
    ``members`` is set for a stage with members (evaluate: model -> digest)."""

    fingerprint: str
    rows: int
    stage: str = ""
    schema_version: str = ""
    package_version: str = ""
    seconds: float | None = None
    resumed: bool = False
    completed_at: str = ""
    made_with: dict[str, Any] | None = None
    parts: tuple[PartRecord, ...] | None = None
    files: dict[str, FileRecord] | None = None
    members: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON object, keys sorted; absent parts, files and members left out."""
        out: dict[str, Any] = {"fingerprint": self.fingerprint, "rows": self.rows, "stage": self.stage,
                               "schema_version": self.schema_version, "package_version": self.package_version,
                               "seconds": self.seconds, "resumed": self.resumed, "completed_at": self.completed_at,
                               "made_with": self.made_with}
        if self.members:
            out["members"] = dict(sorted(self.members.items()))
        if self.parts is not None:
            out["parts"] = [{"name": p.name, "rows": p.rows, "sha256": p.sha256} for p in self.parts]
        if self.files is not None:
            out["files"] = {path: {"bytes": f.bytes, "sha256": f.sha256} for path, f in self.files.items()}
        return dict(sorted(out.items()))

    @classmethod
    def from_json(cls, data: Any, where: str) -> CompletionMarker:
        """A marker from its JSON object; a MarkerError naming ``where`` and the key."""
        def fail(key: str, expected: str) -> MarkerError:
            return MarkerError(where, f"key {key}: expected {expected}; redo the stage that writes it with --force")

        if not isinstance(data, dict):
            raise fail("(top level)", "a JSON object")
        if not isinstance(data.get("fingerprint"), str):
            raise fail("fingerprint", "a string")
        if not isinstance(data.get("rows"), int) or isinstance(data["rows"], bool) or data["rows"] < 0:
            raise fail("rows", "a row count")
        parts = data.get("parts")
        if parts is not None and (not isinstance(parts, list) or not all(
                isinstance(p, dict) and isinstance(p.get("name"), str) and PART_NAME.match(p["name"])
                and isinstance(p.get("rows"), int) and isinstance(p.get("sha256"), str) for p in parts)):
            raise fail("parts", "a list of {name: part-NNNNN.parquet, rows, sha256}")
        files = data.get("files")
        if files is not None and (not isinstance(files, dict) or not all(
                isinstance(f, dict) and isinstance(f.get("bytes"), int) and isinstance(f.get("sha256"), str)
                for f in files.values())):
            raise fail("files", "an object of {bytes, sha256} by workspace path")
        made_with, members = data.get("made_with"), data.get("members", {})
        if not isinstance(members, dict) or not all(isinstance(v, str) for v in members.values()):
            raise fail("members", "an object of digests by member")
        seconds = data.get("seconds")
        return cls(data["fingerprint"], data["rows"], str(data.get("stage", "")), str(data.get("schema_version", "")),
                   str(data.get("package_version", "")),
                   float(seconds) if isinstance(seconds, int | float) else None, bool(data.get("resumed", False)),
                   str(data.get("completed_at", "")), made_with if isinstance(made_with, dict) else None,
                   None if parts is None else tuple(PartRecord(p["name"], p["rows"], p["sha256"]) for p in parts),
                   None if files is None else {k: FileRecord(v["bytes"], v["sha256"]) for k, v in files.items()},
                   dict(members))


def write_marker(workspace: Workspace, name: str, marker: CompletionMarker) -> None:
    """Write a manifest's completion marker (atomically)."""
    write_json_atomic(workspace.marker_path(name), marker.to_json())


def read_marker(workspace: Workspace, name: str) -> CompletionMarker | None:
    """A manifest's completion marker, or None while the stage has not completed."""
    path = workspace.marker_path(name)
    if not path.exists():
        return None
    where = workspace.display(path)
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise MarkerError(where, f"not valid JSON ({error}); redo the stage that writes it with --force") from None
    return CompletionMarker.from_json(data, where)
