"""Files written so that readers never see half of one (docs/architecture.md section 4):
under a temporary name no other process uses, flushed, then renamed into place."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq


def fsync_dir(directory: Path) -> None:
    """Flush a directory's entries (renames, links) to disk."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_table_file(path: Path, table: pa.Table) -> None:
    """One Parquet file (zstd), flushed to disk before the caller renames it into place."""
    with open(path, "wb") as handle:
        pq.write_table(table, handle, compression="zstd")
        handle.flush()
        os.fsync(handle.fileno())


def temporary_name(path: Path) -> Path:
    """A temporary name beside ``path`` that no other process uses."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def write_json_atomic(path: Path, payload: Any) -> None:
    """Write JSON under a temporary name and rename it: readers never see half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = temporary_name(path)
    temporary.write_text(json.dumps(payload, indent=2) + "\n")
    os.replace(temporary, path)


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write bytes under a temporary name, fsync, rename: readers never see half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = temporary_name(path)
    with open(temporary, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)


def copy_atomic(source: Path, destination: Path) -> None:
    """Copy a file under a temporary name and rename it: readers never see half a file."""
    destination.parent.mkdir(parents=True, exist_ok=True)
    temporary = temporary_name(destination)
    shutil.copyfile(source, temporary)
    os.replace(temporary, destination)
