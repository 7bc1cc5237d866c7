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

import pyarrow.parquet as pq

from manifests import (
    SCHEMA_VERSION,
    Workspace,
    list_parts,
    part_fingerprints,
    read_manifest,
    read_success,
    remove_temporaries,
    write_success,
)
from manifests import clear as clear_manifest
from manifests.io import copy_atomic
from pipeline.config import Config
from pipeline.errors import InputError
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
    """Rows in a manifest's parts, from Parquet footers (no data read)."""
    return sum(pq.ParquetFile(path).metadata.num_rows for path in list_parts(workspace, name))


@dataclass(frozen=True)
class StageStatus:
    stage: str
    state: str  # done | partial | stale | missing
    rows: dict[str, int]
    detail: str


def status(stage: StageEntry, config: Config, workspace: Workspace) -> StageStatus:
    resolved = stage.resolved(config)
    inputs, outputs = resolved.inputs, resolved.outputs
    rows = {name: row_count(workspace, name) for name in outputs}
    current = fingerprint(stage, config, workspace)
    markers = [read_success(workspace, name) for name in outputs]
    recorded = set().union(*(part_fingerprints(workspace, name) for name in outputs)) if outputs else set()
    recorded |= {m["fingerprint"] for m in markers if m}
    if not recorded:
        detail = "waiting for " + ", ".join(inputs) if current is None else "not run"
        return StageStatus(stage.name, "missing", rows, detail)
    if current is None or recorded != {current}:
        return StageStatus(stage.name, "stale", rows, "made with another configuration or inputs")
    if all(m is not None and m["fingerprint"] == current for m in markers):
        return StageStatus(stage.name, "done", rows, "")
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
    state = status(stage, config, workspace)
    if state.state == "done" and not force:
        return StageOutcome(stage.name, "skipped", state.rows, 0.0)
    force = force or (state.state == "stale" and stage.replace_stale)
    if state.state == "stale" and not force:
        raise StageError(
            f"{workspace.display(workspace.manifest_dir(outputs[0]))} holds results of stage {stage.name!r} "
            "made with another configuration or other inputs; rerun with --force to discard them")
    if force:
        for name in outputs:
            clear_manifest(workspace, name)
    resumed = not force and any(state.rows.values())
    for name in outputs:
        remove_temporaries(workspace, name)
    run = stage.function()
    workspace.root.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    run(config, workspace.for_run({name: current for name in outputs}))
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
        })
    return StageOutcome(stage.name, "resumed" if resumed else "ran", rows, seconds)


def publish_model(workspace: Workspace, name: str, destination: Path) -> dict[str, Any]:
    """Copy model ``name`` (``W/models/<name>.onnx`` and its card) to ``destination``,
    atomically; returns its ``models`` row."""
    rows = {row["model"]: row for row in read_manifest(workspace, "models").to_pylist()}
    if name not in rows:
        raise StageError(f"{workspace.display(workspace.manifest_dir('models'))}: no model {name!r}; run "
                         "train-reference first")
    source = workspace.resolve(rows[name]["path"])
    copy_atomic(source, destination)
    copy_atomic(source.with_suffix(".json"), destination.with_suffix(".json"))
    return rows[name]
