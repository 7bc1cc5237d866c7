"""What a completed manifest is, and how damage is noticed (docs/architecture.md section 4).

When a stage completes, the runner rewrites each output manifest in key order with fixed
part boundaries (``compact``: the bytes no longer depend on the order workers finished in,
on ``run.part_rows`` or on interruptions), then records in its completion marker every
part's name, rows and SHA-256, and the size and SHA-256 of every workspace file its rows
name (``ManifestSpec.files``: images, masks, models). Readers compare the parts with the
marker (``damage``); ``speedplus verify`` also re-hashes the files (``damaged_files``).
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from manifests.files import fsync_dir, write_table_file
from manifests.marker import CompletionMarker, FileRecord, PartRecord
from manifests.schema import ManifestSpec
from manifests.workspace import PART_TEMPLATE, Workspace

#: rows per part of a completed manifest (one part for every manifest of the shipped profiles)
COMPACT_ROWS = 100_000


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def part_records(parts: list[Path]) -> tuple[PartRecord, ...]:
    """Name, rows (from the Parquet footer) and SHA-256 of each part."""
    return tuple(PartRecord(p.name, pq.ParquetFile(p).metadata.num_rows, sha256(p)) for p in parts)


def file_records(workspace: Workspace, spec: ManifestSpec, rows: list[dict[str, Any]]) -> dict[str, FileRecord]:
    """Size and SHA-256 of every existing workspace file the rows name in ``spec.files`` (for
    a file a worker uploaded to the store: what it reported, its size checked by the driver)."""
    out = {}
    for row in rows:
        for column in spec.files:
            relpath = row.get(column)
            if relpath and relpath not in out:
                stored = workspace.stored_record(relpath)  # a worker wrote it to the store directly
                if stored is not None:
                    out[relpath] = FileRecord(stored["bytes"], stored["sha256"])
                    continue
                path = workspace.fetch(relpath)
                if path.is_file():
                    out[relpath] = FileRecord(path.stat().st_size, sha256(path))
    return out


def damage(parts: list[Path], marker: CompletionMarker) -> str | None:
    """What differs between a manifest's parts and its completion marker, or None. Markers
    written before parts were recorded are trusted as they are."""
    if marker.parts is None:
        return None
    recorded = {entry.name: entry for entry in marker.parts}
    present = {p.name: p for p in parts}
    for name in sorted(set(recorded) - set(present)):
        return f"{name} is missing"
    for name in sorted(set(present) - set(recorded)):
        return f"{name} was not written by the stage that completed it"
    for name, path in sorted(present.items()):
        if sha256(path) != recorded[name].sha256:
            return f"{name} changed since the stage completed"
    return None


def damaged_files(workspace: Workspace, marker: CompletionMarker) -> list[str]:
    """The recorded files that are missing or differ in size or content, as messages."""
    problems = []
    for relpath, record in sorted((marker.files or {}).items()):
        path = workspace.fetch(relpath)
        if not path.is_file():
            problems.append(f"{relpath} is missing")
        elif path.stat().st_size != record.bytes or sha256(path) != record.sha256:
            problems.append(f"{relpath} changed since it was written")
    return problems


def _staging(directory: Path) -> tuple[Path, Path]:
    return directory.with_name(f".{directory.name}.compact"), directory.with_name(f".{directory.name}.old")


def recover(directory: Path) -> None:
    """Finish or undo a compaction a crash interrupted (the writer holds the workspace lock)."""
    staging, old = _staging(directory)
    if old.exists():
        if not directory.exists():  # crashed between the two renames: the staging copy is complete
            os.rename(staging, directory)
        shutil.rmtree(old)
    shutil.rmtree(staging, ignore_errors=True)


def compact(directory: Path, table: pa.Table, key: str) -> None:
    """Replace the parts in ``directory`` (created if missing) by ``table`` sorted by ``key``, in parts of
    ``COMPACT_ROWS``, atomically: written aside, then swapped by two renames (``recover``
    completes a swap a crash interrupted)."""
    staging, old = _staging(directory)
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    ordered = table.sort_by(key)
    # a manifest without rows keeps one empty part: readers still find a dataset with its schema
    for index, start in enumerate(range(0, max(ordered.num_rows, 1), COMPACT_ROWS)):
        write_table_file(staging / PART_TEMPLATE.format(index=index), ordered.slice(start, COMPACT_ROWS))
    for entry in directory.iterdir() if directory.is_dir() else ():  # other files (a marker) stay with it
        if not entry.name.startswith(("part-", ".part-")):
            shutil.copy2(entry, staging / entry.name)
    fsync_dir(staging)
    directory.mkdir(parents=True, exist_ok=True)
    os.rename(directory, old)
    os.rename(staging, directory)
    shutil.rmtree(old)
    fsync_dir(directory.parent)
