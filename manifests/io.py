"""Atomic part writer, validating reader and completion markers of manifests.

A manifest is a directory of Parquet parts and nothing else, so that every Parquet reader
(pandas, pyarrow.dataset, polars, DuckDB) reads the folder as it is. Each part is written
under a temporary name in ``W/manifests/_state/staging/<name>/``, fsynced, linked to its
final name (a link never replaces an existing part) and the directory fsynced: a crash
leaves either a whole part or a temporary file outside the folder. Every part records the
fingerprint of the stage run that wrote it, so a resumed run can refuse to mix results
made under another configuration. A completed manifest is compacted and checked against
its marker (``manifests.integrity``).
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from manifests.files import fsync_dir, write_table_file
from manifests.integrity import damage
from manifests.marker import read_marker
from manifests.schema import MANIFESTS, NAME_PATTERN, READABLE_VERSIONS, SCHEMA_VERSION, Column, ManifestSpec
from manifests.workspace import PART_TEMPLATE, PathEscapeError, Workspace, check_relative
from speedplus.errors import InputError

QUATERNION_TOLERANCE = 1e-6
_PART_RE = re.compile(r"^part-(\d{5})\.parquet$")


class ManifestError(InputError):
    """Invalid manifest content; the message names the file, row and column."""

    def __init__(self, source: str, message: str, *, row: int | None = None, column: str | None = None,
                 sample_id: str | None = None) -> None:
        where = [source]
        if row is not None:
            where.append(f"row {row}" + (f" (sample_id {sample_id})" if sample_id else ""))
        if column is not None:
            where.append(f"column {column!r}")
        super().__init__(", ".join(where) + ": " + message)
        self.source, self.row, self.column = source, row, column
        self._arguments = (source, message, row, column, sample_id)

    def __reduce__(self) -> tuple[Any, ...]:  # crosses process boundaries (engines)
        source, message, row, column, sample_id = self._arguments
        return _manifest_error, (source, message, row, column, sample_id)


def _manifest_error(source: str, message: str, row: int | None, column: str | None,
                    sample_id: str | None) -> ManifestError:
    return ManifestError(source, message, row=row, column=column, sample_id=sample_id)


def spec_for(name_or_spec: str | ManifestSpec) -> ManifestSpec:
    if isinstance(name_or_spec, ManifestSpec):
        return name_or_spec
    try:
        return MANIFESTS[name_or_spec]
    except KeyError:
        raise KeyError(f"unknown manifest {name_or_spec!r}; known: {', '.join(MANIFESTS)}") from None


# ------------------------------------------------------------------------------ validation
def _row_fail(table: pa.Table, source: str, row: int, column: str, message: str) -> ManifestError:
    sample_id = None
    if "sample_id" in table.column_names and table.column("sample_id").type == pa.string():
        sample_id = table.column("sample_id")[row].as_py()
    return ManifestError(source, message, row=row, column=column, sample_id=sample_id)


def _list_values(array: pa.Array, rows: np.ndarray) -> tuple[np.ndarray, pa.Array]:
    """Child values of the given rows of a (nested) list column, as (len(rows), -1) floats."""
    subset = array.take(pa.array(rows, type=pa.int64()))
    flat = subset
    while pa.types.is_list(flat.type) or pa.types.is_fixed_size_list(flat.type) or pa.types.is_large_list(flat.type):
        flat = flat.flatten()
    return flat, subset


def _leaf_lengths(subset: pa.Array) -> np.ndarray | None:
    """Values per row of a list column whose rows differ in length, else None."""
    if not pa.types.is_list(subset.type):
        return None
    counts = np.asarray(pc.list_value_length(subset).to_numpy(zero_copy_only=False), dtype=np.int64)
    if len(counts) == 0 or (counts == counts[0]).all():
        return None
    inner, size = subset.type.value_type, 1
    while pa.types.is_fixed_size_list(inner):
        size, inner = size * inner.list_size, inner.value_type
    return counts * size


def _check_floats(table: pa.Table, source: str, column: Column, rows: np.ndarray, values: np.ndarray,
                  lengths: np.ndarray | None = None) -> None:
    """Every value finite; ``values`` hold ``lengths`` (per row) values each, else the same count."""
    finite = np.isfinite(values)
    if finite.all():
        return
    if lengths is None:
        bad = ~finite.reshape(len(rows), -1).all(axis=1)
        row = int(rows[np.argmax(bad)])
    else:  # rows of different lengths (a list of corners): find the row by its offsets
        row = int(rows[np.searchsorted(np.cumsum(lengths), int(np.argmax(~finite)), side="right")])
    raise _row_fail(table, source, row, column.name, "value is not finite (NaN or infinity)")


def _validate_column(table: pa.Table, source: str, column: Column) -> None:
    array = table.column(column.name).combine_chunks()
    if array.type != column.type:
        raise ManifestError(source, f"type is {array.type}, expected {column.type}", column=column.name)
    nulls = np.asarray(array.is_null().to_numpy(zero_copy_only=False), dtype=bool)
    if not column.nullable and nulls.any():
        raise _row_fail(table, source, int(np.argmax(nulls)), column.name, "null in a column that may not be null")
    rows = np.flatnonzero(~nulls)
    if len(rows) == 0:
        return
    dtype = array.type
    if pa.types.is_floating(dtype):
        _check_floats(table, source, column, rows, np.asarray(array.to_numpy(zero_copy_only=False), float)[rows])
    elif pa.types.is_fixed_size_list(dtype) or pa.types.is_list(dtype):
        flat, _ = _list_values(array, rows)
        if flat.null_count:
            inner_null = np.asarray(flat.is_null().to_numpy(zero_copy_only=False), dtype=bool)
            if len(inner_null) % len(rows) == 0:
                first = int(np.argmax(inner_null.reshape(len(rows), -1).any(axis=1)))
            else:  # variable-length lists: locate the row by its offsets
                lengths = np.asarray(pc.list_value_length(array.take(pa.array(rows))).to_numpy(), dtype=int)
                first = int(np.searchsorted(np.cumsum(lengths), int(np.argmax(inner_null)), side="right"))
            raise _row_fail(table, source, int(rows[first]), column.name, "null value (or a null element in the list)")
        if pa.types.is_floating(flat.type):
            values = np.asarray(flat.to_numpy(zero_copy_only=False), dtype=float)
            lengths = _leaf_lengths(array.take(pa.array(rows)))
            if lengths is not None:  # rows of their own lengths (a capture's detected corners)
                _check_floats(table, source, column, rows, values, lengths)
            else:
                values = values.reshape(len(rows), -1)
                _check_floats(table, source, column, rows, values)
            if column.kind == "quaternion":
                norm = np.linalg.norm(values, axis=1)
                bad = np.abs(norm - 1.0) > QUATERNION_TOLERANCE
                if bad.any():
                    i = int(np.argmax(bad))
                    raise _row_fail(table, source, int(rows[i]), column.name,
                                    f"quaternion norm {norm[i]:.9f} is not 1 (tolerance {QUATERNION_TOLERANCE:g})")
                negative = values[:, 0] < 0
                if negative.any():
                    i = int(np.argmax(negative))
                    raise _row_fail(table, source, int(rows[i]), column.name,
                                    "quaternion has w < 0; store the canonical sign (w >= 0)")
    if column.kind == "enum":
        values = array.to_pylist()
        for row in rows:
            if values[row] not in column.allowed:
                raise _row_fail(table, source, int(row), column.name,
                                f"value {values[row]!r} is not one of {', '.join(column.allowed)}")
    if column.kind == "name":
        values = array.to_pylist()
        for row in rows:
            if not isinstance(values[row], str) or not NAME_PATTERN.fullmatch(values[row]):
                raise _row_fail(table, source, int(row), column.name,
                                f"value {values[row]!r} is not a name (a-z, 0-9, _ and -)")
    if column.kind == "path":
        values = array.to_pylist()
        for row in rows:
            try:
                check_relative(values[row])
            except PathEscapeError as error:
                raise _row_fail(table, source, int(row), column.name, str(error)) from None


def validate_table(table: pa.Table, spec: ManifestSpec, source: str) -> None:
    """Raise ``ManifestError`` unless ``table`` satisfies ``spec`` (columns, types, nulls,
    finite values, unit canonical quaternions, enumerations, workspace paths, unique keys)."""
    expected = [c.name for c in spec.columns]
    missing = [name for name in expected if name not in table.column_names]
    if missing:
        raise ManifestError(source, f"missing column(s) {', '.join(missing)}")
    unexpected = [name for name in table.column_names if name not in expected]
    if unexpected:
        raise ManifestError(source, f"unexpected column(s) {', '.join(unexpected)}")
    for column in spec.columns:
        _validate_column(table, source, column)
    seen: dict[str, int] = {}
    for row, key in enumerate(table.column(spec.key).to_pylist()):
        if not key:
            raise _row_fail(table, source, row, spec.key, "empty key")
        if key in seen:
            raise _row_fail(table, source, row, spec.key, f"duplicate key {key!r} (first at row {seen[key]})")
        seen[key] = row


# ----------------------------------------------------------------------------------- write
def _python(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def to_table(rows: Iterable[Mapping[str, Any]], spec: ManifestSpec) -> pa.Table:
    """Rows (dicts of column -> value; numpy arrays allowed) as a table of ``spec``'s schema."""
    rows = list(rows)
    schema = spec.schema()
    columns = {}
    for field in schema:
        try:
            columns[field.name] = pa.array([_python(row[field.name]) for row in rows], type=field.type)
        except KeyError:
            raise ManifestError(f"manifest {spec.name}", "row lacks this column", column=field.name) from None
        except (pa.ArrowInvalid, pa.ArrowTypeError) as error:
            raise ManifestError(f"manifest {spec.name}", f"cannot convert to {field.type}: {error}",
                                column=field.name) from None
    return pa.Table.from_pydict(columns, schema=schema)


def list_parts(workspace: Workspace, name: str) -> list[Path]:
    directory = workspace.manifest_dir(name)
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.iterdir() if _PART_RE.match(p.name))


def write_part(workspace: Workspace, spec: ManifestSpec | str, rows: pa.Table | Iterable[Mapping[str, Any]],
               fingerprint: str) -> Path | None:
    """Validate and atomically write one part; returns its path (None for no rows)."""
    spec = spec_for(spec)
    table = rows if isinstance(rows, pa.Table) else to_table(rows, spec)
    if table.num_rows == 0:
        return None
    validate_table(table, spec, f"new part of manifest {spec.name}")
    table = table.replace_schema_metadata({**spec.schema().metadata, b"speedplus.fingerprint": fingerprint.encode()})
    directory = workspace.manifest_dir(spec.name)
    directory.mkdir(parents=True, exist_ok=True)
    staging = workspace.staging_dir(spec.name)
    staging.mkdir(parents=True, exist_ok=True)
    existing = [int(_PART_RE.match(p.name).group(1)) for p in list_parts(workspace, spec.name)]
    index = max(existing, default=-1) + 1
    temporary = staging / f"part-{index:05d}.parquet.{os.getpid()}.tmp"
    write_table_file(temporary, table)
    while True:  # link, unlike rename, never replaces a part another process may have written
        final = directory / PART_TEMPLATE.format(index=index)
        try:
            os.link(temporary, final)
            break
        except FileExistsError:
            index += 1
    temporary.unlink()
    fsync_dir(directory)
    return final


#: in a manifest's folder: its rows are a refused stage's diagnostics (calibrate's per-image
#: reasons), kept for the user to read, not results; the stage replaces them when it runs
DIAGNOSTICS_FILE = "REFUSED"


def mark_diagnostics(workspace: Workspace, name: str) -> None:
    """Say that manifest ``name`` holds a refusal's diagnostics (``DIAGNOSTICS_FILE``)."""
    directory = workspace.manifest_dir(name)
    if directory.is_dir():
        (directory / DIAGNOSTICS_FILE).write_text("the rows of a refused stage, kept as its diagnostics\n")


def is_diagnostics(workspace: Workspace, name: str) -> bool:
    return (workspace.manifest_dir(name) / DIAGNOSTICS_FILE).is_file()


def clear(workspace: Workspace, name: str) -> None:
    """Remove a manifest entirely (used by ``--force``)."""
    shutil.rmtree(workspace.manifest_dir(name), ignore_errors=True)


def remove_temporaries(workspace: Workspace, name: str) -> int:
    """Delete temporary files left by an interrupted writer; returns how many."""
    staging = workspace.staging_dir(name)
    if not staging.is_dir():
        return 0
    stale = [p for p in staging.iterdir() if p.name.endswith(".tmp")]
    for path in stale:
        path.unlink()
    return len(stale)


class PartSink:
    """Buffers rows and writes them as parts of ``part_rows`` rows (the last one shorter).

    Used as a context manager; on exit, even through an exception or Ctrl-C, the complete
    rows already buffered are written, so finished work is never lost.
    """

    def __init__(self, workspace: Workspace, spec: ManifestSpec | str, fingerprint: str, part_rows: int) -> None:
        self.workspace, self.spec, self.fingerprint = workspace, spec_for(spec), fingerprint
        self.part_rows = part_rows
        self.rows: list[Mapping[str, Any]] = []
        self.written = 0

    def add(self, row: Mapping[str, Any]) -> None:
        self.rows.append(row)
        if len(self.rows) >= self.part_rows:
            self.flush()

    def flush(self) -> None:
        if self.rows:
            rows, self.rows = self.rows, []
            write_part(self.workspace, self.spec, rows, self.fingerprint)
            self.written += len(rows)

    def __enter__(self) -> PartSink:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.flush()


def open_sink(workspace: Workspace, name: str, part_rows: int) -> PartSink:
    """A ``PartSink`` for the manifest the running stage writes (fingerprint from the runner)."""
    return PartSink(workspace, name, workspace.output_fingerprint(name), part_rows)


# ------------------------------------------------------------------------------------ read
def _upgraded(table: pa.Table, spec: ManifestSpec) -> pa.Table | None:
    """An older version's part in this version's columns, or None when it differs by more
    than nullable columns added since: the same columns in order, by name and type, with
    each added column filled with nulls."""
    have = [(f.name, f.type) for f in table.schema]
    kept = [(c.name, c.field().type) for c in spec.columns if c.name in table.column_names]
    added = [c for c in spec.columns if c.name not in table.column_names]
    if have != kept or not all(c.nullable for c in added):
        return None
    columns = [table.column(c.name) if c.name in table.column_names else pa.nulls(table.num_rows, c.field().type)
               for c in spec.columns]
    return pa.Table.from_arrays(columns, schema=pa.schema([c.field() for c in spec.columns],
                                                          metadata=table.schema.metadata))


def _read_part(path: Path, spec: ManifestSpec, source: str) -> pa.Table:
    try:
        table = pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as error:
        raise ManifestError(source, f"not a readable Parquet file ({error})") from None
    metadata = table.schema.metadata or {}
    version = metadata.get(b"speedplus.schema_version", b"").decode()
    if version != SCHEMA_VERSION:
        upgraded = _upgraded(table, spec) if version in READABLE_VERSIONS else None
        if upgraded is None:
            raise ManifestError(source, f"schema version {version or 'missing'}, this program reads "
                                        f"{SCHEMA_VERSION}; rerun the stage with --force")
        table = upgraded
    manifest = metadata.get(b"speedplus.manifest", b"").decode()
    if manifest != spec.name:
        raise ManifestError(source, f"part of manifest {manifest or 'unknown'!r}, expected {spec.name!r}")
    return table


def part_fingerprints(workspace: Workspace, name: str) -> set[str]:
    """Fingerprints recorded in the parts of a manifest (reads footers only)."""
    found = set()
    for path in list_parts(workspace, name):
        try:
            metadata = pq.read_schema(path).metadata or {}
        except (OSError, pa.ArrowInvalid) as error:
            raise ManifestError(workspace.display(path), f"not a readable Parquet file ({error}); redo the stage "
                                "that writes it with --force") from None
        found.add(metadata.get(b"speedplus.fingerprint", b"").decode())
    return found


def read_manifest(workspace: Workspace, name: str | ManifestSpec, *, validate: bool = True) -> pa.Table:
    """All parts of a manifest as one table (schema metadata stripped of per-part fields).

    With ``validate`` every part is checked (see ``validate_table``) and keys must be unique
    across parts; errors name the part file, the row within it and the column.
    """
    spec = spec_for(name)
    parts = list_parts(workspace, spec.name)
    check_layout(workspace, spec.name)
    marker = read_marker(workspace, spec.name)
    problem = damage(parts, marker) if marker is not None else None
    if problem is not None:
        raise ManifestError(workspace.display(workspace.manifest_dir(spec.name)),
                            f"damaged: {problem}; redo the stage that writes it with --force (speedplus status "
                            "names it)")
    tables = []
    seen: dict[str, str] = {}
    for path in parts:
        source = workspace.display(path)
        table = _read_part(path, spec, source)
        if validate:
            validate_table(table, spec, source)
            for row, key in enumerate(table.column(spec.key).to_pylist()):
                if key in seen:
                    raise ManifestError(source, f"key {key!r} also in {seen[key]}", row=row, column=spec.key)
                seen[key] = source
        try:  # the spec's field types and nullability, whatever wrote the part
            tables.append(table.select(spec.schema().names).cast(spec.schema()))
        except (pa.ArrowInvalid, pa.ArrowTypeError, KeyError) as error:
            raise ManifestError(source, f"columns do not match the manifest's schema ({error})") from None
    if not tables:  # not Schema.empty_table(), which imports pandas: 0.3 s of a command's start
        return pa.Table.from_batches([], schema=spec.schema())
    return pa.concat_tables(tables)


def read_keys(workspace: Workspace, name: str | ManifestSpec) -> set[str]:
    """Keys (sample_ids) present in a manifest's parts, after validating them."""
    spec = spec_for(name)
    return set(read_manifest(workspace, spec).column(spec.key).to_pylist())


# ------------------------------------------------------------------------- completion marker
def check_layout(workspace: Workspace, name: str) -> None:
    """Refuse a manifest written before schema 1.6, whose marker sat inside its folder."""
    legacy = workspace.legacy_marker_path(name)
    if legacy.exists():
        raise ManifestError(workspace.display(legacy), f"written by an older version of this program (schema before "
                            f"{SCHEMA_VERSION}: the completion marker sat inside the data folder, which polars and "
                            "DuckDB cannot read); redo the stage that writes it with --force, or start a new "
                            "workspace")
