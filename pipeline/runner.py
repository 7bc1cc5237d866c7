"""Stage registry, fingerprints, resume and status.

A stage's fingerprint hashes what determines its results: its configuration sections,
the completion markers of the manifests it reads, and the schema version. A stage whose
outputs carry the current fingerprint is done and is skipped; one interrupted part-way
resumes (the stage itself processes only missing ``sample_id``s); results made under
another fingerprint are never mixed with new ones unless ``--force`` discards them.
"""

from __future__ import annotations

import hashlib
import importlib
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
    read_success,
    remove_temporaries,
    write_success,
)
from manifests import clear as clear_manifest
from pipeline.config import Config
from pipeline.errors import InputError


class StageError(InputError):
    """A stage cannot run as asked (exit code 1); the message says what to do."""


class NotBuiltError(Exception):
    """The stage exists in the design but not yet in this program (exit code 3)."""


@dataclass(frozen=True)
class StageSpec:
    """A stage. Its module provides ``run(config, workspace)``; it may also provide
    ``dependencies(config) -> (inputs, sections, extra)`` and ``outputs(config)`` when
    they depend on the configuration (e.g. acquire's backend)."""

    name: str
    module: str | None  # importable module with run(config, workspace); None: not built yet
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    sections: tuple[str, ...]
    summary: str

    def resolve(self, config: Config) -> tuple[tuple[str, ...], tuple[str, ...], dict[str, Any], tuple[str, ...]]:
        """(inputs, config sections, extra fingerprint content, outputs) for this configuration."""
        inputs, sections, extra, outputs = self.inputs, self.sections, {}, self.outputs
        if self.module is not None:
            module = importlib.import_module(self.module)
            if hasattr(module, "dependencies"):
                inputs, sections, extra = module.dependencies(config)
            if hasattr(module, "outputs"):
                outputs = module.outputs(config)
        return inputs, sections, extra, outputs


STAGES: tuple[StageSpec, ...] = (
    StageSpec("plan", "stages.plan", (), ("plan",), ("plan", "camera", "testbed"),
              "relative poses, view, light and robot/rail commands"),
    StageSpec("acquire", "stages.acquire", ("plan",), ("captures", "truth"),
              ("acquire", "virtual", "camera", "testbed"), "drive the testbed: telemetry, motion capture and images"),
    StageSpec("calibrate", "stages.calibrate", ("captures",), ("calibration_samples",), ("calibrate", "testbed"),
              "RWHE calibration per source and Table 1"),
    StageSpec("fuse", "stages.fuse", ("captures", "calibration_samples"), ("poses",), ("fuse", "testbed"),
              "per-source poses, rejection, Bayesian fusion"),
    StageSpec("label", "stages.label", ("poses",), ("labels",), ("label", "testbed"),
              "SPEED+ labels, keypoints, boxes"),
    StageSpec("render", "stages.render", ("labels",), ("renders",), ("render", "testbed"),
              "Mitsuba 3 synthetic twins (or, with --set train, the training set)"),
    StageSpec("evaluate", "stages.evaluate", ("renders", "labels"), ("predictions", "scores"), ("evaluate",),
              "ONNX model scores on twins and testbed images (Table 2)"),
    StageSpec("report", "stages.report", ("labels", "renders", "predictions", "scores"), ("report",), (),
              "static HTML report (W/report/index.html)"),
)
STAGE_NAMES = tuple(stage.name for stage in STAGES)


def train_reference(config: Config, workspace: Workspace, model_path: Path, max_steps: int | None = None
                    ) -> dict[str, Any]:
    """Train the reference model (``stages.reference``) on the workspace's training set and
    export it to ``model_path``; returns its card. Like the stages, reached only from here."""
    module = importlib.import_module("stages.reference.train")
    return module.run(config, workspace, model_path, max_steps=max_steps)


def stage_spec(name: str) -> StageSpec:
    for stage in STAGES:
        if stage.name == name:
            return stage
    raise StageError(f"unknown stage {name!r}; stages: {', '.join(STAGE_NAMES)}")


def _section_dict(config: Config, name: str) -> dict[str, Any]:
    section = config.section(name)
    return {f.name: getattr(section, f.name) for f in fields(section)}


def fingerprint(stage: StageSpec, config: Config, workspace: Workspace) -> str | None:
    """Hex digest of the stage's inputs, or None while an input manifest is incomplete."""
    input_names, sections, extra, _ = stage.resolve(config)
    inputs = {}
    for name in input_names:
        marker = read_success(workspace, name)
        if marker is None:
            return None
        inputs[name] = {"fingerprint": marker["fingerprint"], "rows": marker["rows"]}
    payload = {
        "stage": stage.name,
        "schema_version": SCHEMA_VERSION,
        "config": {name: _section_dict(config, name) for name in sections},
        "inputs": inputs,
        "extra": extra,
    }
    text = json.dumps(payload, sort_keys=True, default=list)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def row_count(workspace: Workspace, name: str) -> int:
    """Rows in a manifest's parts, from Parquet footers (no data read)."""
    return sum(pq.ParquetFile(path).metadata.num_rows for path in list_parts(workspace, name))


@dataclass(frozen=True)
class StageStatus:
    stage: str
    state: str  # done | partial | stale | missing | not built
    rows: dict[str, int]
    detail: str


def status(stage: StageSpec, config: Config, workspace: Workspace) -> StageStatus:
    inputs, _, _, outputs = stage.resolve(config)
    rows = {name: row_count(workspace, name) for name in outputs}
    current = fingerprint(stage, config, workspace)
    markers = [read_success(workspace, name) for name in outputs]
    recorded = set().union(*(part_fingerprints(workspace, name) for name in outputs)) if outputs else set()
    recorded |= {m["fingerprint"] for m in markers if m}
    if stage.module is None and not recorded:
        return StageStatus(stage.name, "not built", rows, "not implemented yet")
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


def run_stage(stage: StageSpec, config: Config, workspace: Workspace, *, force: bool = False) -> StageOutcome:
    """Run (or resume, or skip) one stage; see the module docstring."""
    if stage.module is None:
        raise NotBuiltError(f"stage {stage.name!r} is not built yet")
    inputs, _, _, outputs = stage.resolve(config)
    current = fingerprint(stage, config, workspace)
    if current is None:
        missing = [name for name in inputs if read_success(workspace, name) is None]
        raise StageError(f"stage {stage.name!r} needs the complete manifest(s) {', '.join(missing)} in "
                         f"{workspace.root}; run the stage(s) before it first (or `speedplus run`)")
    state = status(stage, config, workspace)
    if state.state == "done" and not force:
        return StageOutcome(stage.name, "skipped", state.rows, 0.0)
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
    module = importlib.import_module(stage.module)
    workspace.root.mkdir(parents=True, exist_ok=True)
    workspace.active_fingerprints = {name: current for name in outputs}
    started = time.perf_counter()
    try:
        module.run(config, workspace)
    finally:
        workspace.active_fingerprints = {}
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
