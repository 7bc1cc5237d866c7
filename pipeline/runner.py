"""Fingerprints, resume and status of the stages declared in ``pipeline.registry``.

A stage's fingerprint hashes what determines its results: its configuration sections,
the completion markers of the manifests it reads, and the schema version. A stage whose
outputs carry the current fingerprint is done and is skipped; one interrupted part-way
resumes (the stage itself processes only missing ``sample_id``s); results made under
another fingerprint are never mixed with new ones unless ``--force`` discards them.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, fields
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from pyarrow import ArrowInvalid

from manifests import (
    SCHEMA_VERSION,
    ManifestError,
    Workspace,
    list_parts,
    part_fingerprints,
    read_manifest,
    read_success,
    remove_temporaries,
    write_success,
)
from manifests import clear as clear_manifest
from manifests.files import copy_atomic
from manifests.integrity import compact, damage, damaged_files, file_records, part_records, recover
from manifests.schema import MANIFESTS
from pipeline.config import Config
from pipeline.errors import InputError
from pipeline.progress import console
from pipeline.registry import StageEntry


class StageError(InputError):
    """A stage cannot run as asked (exit code 1); the message says what to do."""


def _section_dict(config: Config, name: str) -> dict[str, Any]:
    section = config.section(name)
    return {f.name: getattr(section, f.name) for f in fields(section)}


def fingerprint(stage: StageEntry, config: Config, workspace: Workspace) -> str | None:
    """Hex digest of the stage's inputs, or None while an input manifest is incomplete."""
    resolved = stage.resolved(config)
    inputs = {}
    for name in resolved.inputs:
        marker = read_success(workspace, name)
        if marker is None:
            return None
        inputs[name] = {"fingerprint": marker["fingerprint"], "rows": marker["rows"]}
    payload = {
        "stage": stage.name,
        "schema_version": SCHEMA_VERSION,
        "config": {name: _section_dict(config, name) for name in resolved.sections},
        "inputs": inputs,
        "extra": resolved.extra,
    }
    text = json.dumps(payload, sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def row_count(workspace: Workspace, name: str) -> int:
    """Rows in a manifest's parts, from Parquet footers (no data read); unreadable parts
    count none (readers and ``status`` report them)."""
    total = 0
    for path in list_parts(workspace, name):
        try:
            total += pq.ParquetFile(path).metadata.num_rows
        except (OSError, ArrowInvalid):
            continue
    return total


@dataclass(frozen=True)
class StageStatus:
    stage: str
    state: str  # done | partial | stale | missing | damaged
    rows: dict[str, int]
    detail: str


def status(stage: StageEntry, config: Config, workspace: Workspace) -> StageStatus:
    resolved = stage.resolved(config)
    inputs, outputs = resolved.inputs, resolved.outputs
    rows = {name: row_count(workspace, name) for name in outputs}
    current = fingerprint(stage, config, workspace)
    markers = [read_success(workspace, name) for name in outputs]
    if current is not None and all(m is not None and m["fingerprint"] == current for m in markers):
        for name, marker in zip(outputs, markers, strict=True):
            problem = damage(list_parts(workspace, name), marker)
            if problem is not None:
                return StageStatus(stage.name, "damaged", rows, f"{name}: {problem}; redo with --force")
        return StageStatus(stage.name, "done", rows, "")
    try:
        recorded = set().union(*(part_fingerprints(workspace, name) for name in outputs)) if outputs else set()
    except ManifestError as error:
        return StageStatus(stage.name, "damaged", rows, f"{error}")
    recorded |= {m["fingerprint"] for m in markers if m}
    if not recorded:
        detail = "waiting for " + ", ".join(inputs) if current is None else "not run"
        return StageStatus(stage.name, "missing", rows, detail)
    if current is None or recorded != {current}:
        return StageStatus(stage.name, "stale", rows, "made with another configuration or inputs")
    return StageStatus(stage.name, "partial", rows, "interrupted; rerun to resume")


@dataclass(frozen=True)
class StageOutcome:
    stage: str
    action: str  # ran | resumed | skipped
    rows: dict[str, int]
    seconds: float


def run_stage(stage: StageEntry, config: Config, workspace: Workspace, *, force: bool = False) -> StageOutcome:
    """Run (or resume, or skip) one stage; see the module docstring."""
    resolved = stage.resolved(config)
    inputs, outputs = resolved.inputs, resolved.outputs
    current = fingerprint(stage, config, workspace)
    if current is None:
        missing = [name for name in inputs if read_success(workspace, name) is None]
        raise StageError(f"stage {stage.name!r} needs the complete manifest(s) {', '.join(missing)} in "
                         f"{workspace.root}; run the stage(s) before it first (or `speedplus run`)")
    for name in inputs:  # before anything is discarded: a damaged input stops the stage
        problem = damage(list_parts(workspace, name), read_success(workspace, name))
        if problem is not None:
            raise StageError(f"stage {stage.name!r} needs manifest {name}, which is damaged ({problem}); redo "
                             "the stage that writes it with --force (speedplus status names it)")
    state = status(stage, config, workspace)
    if state.state == "done" and not force:
        return StageOutcome(stage.name, "skipped", state.rows, 0.0)
    replacing = state.state == "stale" and stage.replace_stale
    if state.state == "stale" and not (force or replacing):
        raise StageError(
            f"{workspace.display(workspace.manifest_dir(outputs[0]))} holds results of stage {stage.name!r} "
            "made with another configuration or other inputs; rerun with --force to discard them")
    if state.state == "damaged" and not force:
        raise StageError(f"stage {stage.name!r}: its results are damaged ({state.detail})")
    if force or replacing:
        for name in outputs:
            clear_manifest(workspace, name)
    resumed = not (force or replacing) and any(state.rows.values())
    for name in outputs:
        recover(workspace.manifest_dir(name))
        remove_temporaries(workspace, name)
        # this run's rows are checked against this run's marker, never a previous one's
        workspace.success_path(name).unlink(missing_ok=True)
        if resumed:
            _forget_rows_without_files(workspace, name, current)
    run = stage.function()
    workspace.root.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    run(config, workspace.for_run({name: current for name in outputs}, forced=force))
    seconds = time.perf_counter() - started
    rows = {name: row_count(workspace, name) for name in outputs}
    for name in outputs:
        write_success(workspace, name, {
            "stage": stage.name,
            "fingerprint": current,
            "rows": rows[name],
            "schema_version": SCHEMA_VERSION,
            "package_version": metadata.version("speedplus-builder"),
            "seconds": round(seconds, 3),
            "resumed": resumed,
            "completed_at": datetime.now(UTC).isoformat(timespec="seconds"),
            **_complete(workspace, name, current),
        })
    workspace.sync()  # a workspace on object storage: the store gets the stage's results now
    return StageOutcome(stage.name, "resumed" if resumed else "ran", rows, seconds)


def _forget_rows_without_files(workspace: Workspace, name: str, current: str) -> None:
    """A resumed stage redoes the rows whose files are gone (deleted, or never arrived),
    instead of completing a manifest that names files it does not have."""
    spec = MANIFESTS.get(name)
    if spec is None or not spec.files or not list_parts(workspace, name):
        return
    table = read_manifest(workspace, name)
    missing = []
    for row in table.select([spec.key, *spec.files]).to_pylist():
        gone = [row[c] for c in spec.files if row[c] and not workspace.has_file(row[c])]
        if gone:
            missing.append((row[spec.key], gone[0]))
    if not missing:
        return
    lost = {key for key, _ in missing}
    keep = pa.array([key not in lost for key in table.column(spec.key).to_pylist()])
    stamped = {**spec.schema().metadata, b"speedplus.fingerprint": current.encode()}
    compact(workspace.manifest_dir(name), table.filter(keep).replace_schema_metadata(stamped), spec.key)
    console.print(f"[yellow]{name}: {len(missing)} row(s) name files that are missing ({missing[0][1]}"
                  f"{', ...' if len(missing) > 1 else ''}); they are redone[/]")


def _complete(workspace: Workspace, name: str, current: str) -> dict[str, Any]:
    """Compact a finished manifest into key order and record its parts and files for the
    marker (``manifests.integrity``): same inputs, same bytes, whatever order the rows came in."""
    if name not in MANIFESTS:  # a completion marker without rows (report)
        return {}
    spec = MANIFESTS[name]
    table = read_manifest(workspace, name)
    stamped = {**spec.schema().metadata, b"speedplus.fingerprint": current.encode()}
    compact(workspace.manifest_dir(name), table.replace_schema_metadata(stamped), spec.key)
    return {"parts": part_records(list_parts(workspace, name)),
            "files": file_records(workspace, spec, table.to_pylist())}


@dataclass(frozen=True)
class Finding:
    stage: str
    manifest: str
    problems: list[str]


def verify(config: Config, workspace: Workspace, stages: tuple[StageEntry, ...]) -> list[Finding]:
    """Every completed manifest against its marker, and every file it recorded against its
    size and hash; one finding per manifest (no problems: intact)."""
    findings = []
    for stage in stages:
        for name in stage.resolved(config).outputs:
            marker = read_success(workspace, name)
            if marker is None:
                continue
            problem = damage(list_parts(workspace, name), marker)
            findings.append(Finding(stage.name, name, ([problem] if problem else [])
                                    + damaged_files(workspace, marker)))
    return findings


def model_names(workspace: Workspace) -> list[str]:
    """The models of the ``models`` manifest, by name."""
    return sorted(read_manifest(workspace, "models").column("model").to_pylist())


def publish_model(workspace: Workspace, name: str, destination: Path) -> dict[str, Any]:
    """Copy model ``name`` (``W/models/<name>.onnx`` and its card) to ``destination``,
    atomically; returns its ``models`` row."""
    rows = {row["model"]: row for row in read_manifest(workspace, "models").to_pylist()}
    if name not in rows:
        raise StageError(f"{workspace.display(workspace.manifest_dir('models'))}: no model {name!r}; run "
                         "train-reference first")
    source = workspace.fetch(rows[name]["path"])
    workspace.fetch(rows[name]["path"].removesuffix(".onnx") + ".json")
    copy_atomic(source, destination)
    copy_atomic(source.with_suffix(".json"), destination.with_suffix(".json"))
    return rows[name]
