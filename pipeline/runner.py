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
from collections.abc import Callable
from dataclasses import dataclass, fields
from datetime import UTC, datetime
from importlib import metadata
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
from pyarrow import ArrowInvalid

from core import progress
from core.config import Config
from core.engines import EngineError, single_threaded_blas
from core.progress import console
from manifests import (
    SCHEMA_VERSION,
    ManifestError,
    Workspace,
    list_parts,
    part_fingerprints,
    read_manifest,
    read_marker,
    remove_temporaries,
    write_marker,
)
from manifests import clear as clear_manifest
from manifests.integrity import compact, damage, damaged_files, file_records, part_records, recover
from manifests.io import is_diagnostics
from manifests.marker import CompletionMarker, FileRecord, MarkerError, PartRecord
from manifests.schema import MANIFESTS
from pipeline.registry import STAGES, StageEntry
from speedplus.errors import InputError


class StageError(InputError):
    """A stage cannot run as asked (exit code 1); the message says what to do."""


def _section_dict(config: Config, name: str) -> dict[str, Any]:
    section = config.section(name)
    return {f.name: getattr(section, f.name) for f in fields(section)}


def _declared(config: Config, declared: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """The values of what a stage declares it depends on: whole sections (``plan``) or single
    keys of another stage's section (``plan.mode``), as {section: {key: value}}."""
    sections: dict[str, dict[str, Any]] = {}
    for name in declared:
        section, _, key = name.partition(".")
        values = _section_dict(config, section)
        sections.setdefault(section, {}).update(values if not key else {key: values[key]})
    return sections


def fingerprint_payload(stage: StageEntry, config: Config, workspace: Workspace) -> dict[str, Any] | None:
    """What the stage's fingerprint hashes (recorded in its markers, so that ``status`` can say
    why results are stale), or None while an input manifest is incomplete."""
    resolved = stage.resolved(config, workspace)
    inputs = {}
    for name in resolved.inputs:
        marker = read_marker(workspace, name)
        if marker is None:
            return None
        inputs[name] = {"fingerprint": marker.fingerprint, "rows": marker.rows}
    sections = _declared(config, resolved.sections)
    if resolved.member_key is not None:  # members are tracked one by one (markers' "members")
        section, key = resolved.member_key.split(".")
        sections[section].pop(key)
    from stages.common.workspace_target import digest  # the shared layer; meshes load there only

    target = digest(config, workspace if stage.target_folder == "workspace" else None)
    return json.loads(json.dumps({
        "stage": stage.name,
        "schema_version": SCHEMA_VERSION,
        "config": sections,
        "inputs": inputs,
        "extra": resolved.extra,
        "target": target,
    }, sort_keys=True, default=list))


def _digest(payload: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def fingerprint(stage: StageEntry, config: Config, workspace: Workspace) -> str | None:
    """Hex digest of the stage's inputs, or None while an input manifest is incomplete."""
    payload = fingerprint_payload(stage, config, workspace)
    return None if payload is None else _digest(payload)


def _flat(value: Any, prefix: str) -> dict[str, Any]:
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for key, item in value.items():
            out.update(_flat(item, f"{prefix}.{key}" if prefix else str(key)))
        return out
    return {prefix: value}


def _short(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def differences(recorded: Any, current: dict[str, Any] | None, most: int = 4) -> str:
    """Why results made under ``recorded`` are not those of ``current`` (two fingerprint
    payloads): the configuration keys that changed (old -> new) and the inputs whose marker
    changed; a short sentence for ``status`` and for the refusal."""
    if not isinstance(recorded, dict):  # a marker of an older version, or hand-edited
        return "made with another configuration or inputs (which keys was not recorded)"
    if current is None:
        return "an input manifest is incomplete: waiting for it to be redone"
    said = []
    # a stage's extra content holds configuration too (render's keys of one image set)
    old = {**_flat(recorded.get("config", {}), ""), **_flat(recorded.get("extra", {}), "")}
    new = {**_flat(current.get("config", {}), ""), **_flat(current.get("extra", {}), "")}
    keys = sorted(k for k in old.keys() | new.keys() if old.get(k, "absent") != new.get(k, "absent"))
    said += [f"{key} {_short(old.get(key, 'absent'))} -> {_short(new.get(key, 'absent'))}" for key in keys[:most]]
    if len(keys) > most:
        said.append(f"and {len(keys) - most} more key(s)")
    old_in, new_in = recorded.get("inputs", {}), current.get("inputs", {})
    said += [f"input {name} was redone" for name in sorted(old_in.keys() | new_in.keys())
             if old_in.get(name) != new_in.get(name)]
    if "target" in recorded and recorded.get("target") != current.get("target"):
        said.append("the target's files changed (its target.toml or mesh)")
    if recorded.get("schema_version") != current.get("schema_version"):
        said.append(f"schema {recorded.get('schema_version')} -> {current.get('schema_version')}")
    return "; ".join(said) or "made with another configuration or inputs"


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
    #: stale only because members changed (evaluate: a model's file): redone one by one
    members_changed: tuple[str, ...] = ()
    #: its rows are a refusal's diagnostics (``manifests.io.DIAGNOSTICS_FILE``): replaced freely
    diagnostics: bool = False

    def replaced(self, stage: StageEntry) -> bool:
        """Stale results the stage replaces without --force."""
        return self.state == "stale" and (stage.replace_stale or self.diagnostics)


def status(stage: StageEntry, config: Config, workspace: Workspace) -> StageStatus:
    resolved = stage.resolved(config, workspace)
    inputs, outputs = resolved.inputs, resolved.outputs
    rows = {name: row_count(workspace, name) for name in outputs}
    current = fingerprint(stage, config, workspace)
    try:
        markers = [read_marker(workspace, name) for name in outputs]
    except MarkerError as error:  # damaged: --force, which this status lets through, writes it anew
        return StageStatus(stage.name, "damaged", rows, f"{error}")
    if current is not None and all(m is not None and m.fingerprint == current for m in markers):
        for name, marker in zip(outputs, markers, strict=True):
            problem = damage(list_parts(workspace, name), marker)
            if problem is not None:
                return StageStatus(stage.name, "damaged", rows, f"{name}: {problem}; redo with --force")
        return _member_status(stage.name, resolved.members, markers, rows)
    try:
        recorded = set().union(*(part_fingerprints(workspace, name) for name in outputs)) if outputs else set()
    except ManifestError as error:
        return StageStatus(stage.name, "damaged", rows, f"{error}")
    recorded |= {m.fingerprint for m in markers if m}
    if not recorded:
        detail = "waiting for " + ", ".join(inputs) if current is None else "not run"
        return StageStatus(stage.name, "missing", rows, detail)
    if current is None or recorded != {current}:
        if not any(markers) and all(is_diagnostics(workspace, name) or not rows[name] for name in outputs):
            return StageStatus(stage.name, "stale", rows, "the diagnostics of its last refusal, made with another "
                               "configuration (its message said why); replaced when the stage runs",
                               diagnostics=True)
        made = next((m.made_with for m in markers if m and m.fingerprint != current), None)
        return StageStatus(stage.name, "stale", rows,
                           differences(made, fingerprint_payload(stage, config, workspace)))
    return StageStatus(stage.name, "partial", rows,
                       "incomplete (interrupted, or refused: see its message); rerun to resume")


def _member_status(name: str, members: dict[str, str], markers: list[CompletionMarker | None],
                   rows: dict[str, int]) -> StageStatus:
    """Done, unless a member (evaluate: a model) is new (partial: it is added) or changed
    (stale: ``--force`` with its name redoes it alone)."""
    scored = markers[0].members if markers and markers[0] else {}
    changed = sorted(m for m, digest in members.items() if m in scored and scored[m] != digest)
    if changed:
        return StageStatus(name, "stale", rows, f"{', '.join(changed)} changed since scored (another file's bytes); "
                                                "redo it alone with --force and its --model", tuple(changed))
    new = sorted(m for m in members if m not in scored)
    if new:
        return StageStatus(name, "partial", rows, f"{', '.join(new)} not scored yet; rerun to add it")
    return StageStatus(name, "done", rows, "")


@dataclass(frozen=True)
class StageOutcome:
    stage: str
    action: str  # ran | resumed | skipped
    rows: dict[str, int]
    seconds: float


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a stage: what it kept (the CLI's one line, exit 130)."""

    def __init__(self, stage: str, kept: int, total: int | None) -> None:
        super().__init__(stage)
        self.stage, self.kept, self.total = stage, kept, total

    def __str__(self) -> str:
        of = f" of {self.total}" if self.total is not None else ""
        return f"interrupted: {self.kept}{of} rows kept ({self.stage}); run the same command to resume"


def redone_inputs(stage: StageEntry, config: Config, workspace: Workspace) -> list[str]:
    """The inputs redone since the stage's results were made, when nothing else differs (its
    configuration, extras, target and schema are those it was made with); else none."""
    return _changed_only(stage, config, workspace, "inputs")


def _changed_only(stage: StageEntry, config: Config, workspace: Workspace, part: str) -> list[str]:
    """The keys of the fingerprint payload's ``part`` (``inputs``, ``extra``) that differ from
    what every output's results were made with, when all the rest is the same; else none."""
    markers = [read_marker(workspace, name) for name in stage.resolved(config, workspace).outputs]
    recorded = [None if marker is None else marker.made_with for marker in markers]
    current = fingerprint_payload(stage, config, workspace)
    if current is None or not recorded or not all(isinstance(r, dict) for r in recorded):
        return []
    same = tuple(k for k in ("stage", "schema_version", "config", "inputs", "extra", "target") if k != part)
    if any({k: r.get(k) for k in same} != {k: current.get(k) for k in same} for r in recorded):
        return []
    new = current.get(part, {})
    return sorted({key for r in recorded for old in (r.get(part, {}),) for key in old.keys() | new.keys()
                   if old.get(key) != new.get(key)})


def outdated_inputs(stage: StageEntry, config: Config, workspace: Workspace) -> list[tuple[str, StageStatus]]:
    """(input manifest, the status of the stage that writes it) for each input whose own
    stage is stale under ``config``: made with other keys (``plan.seed``), another target or
    facility folder, or other inputs of its own. A stage never builds on those: its results
    would follow a configuration the workspace no longer has. A member that changed
    (evaluate's model file) is tracked by its own stage, one by one, and is not counted.
    The stage that wrote an input is the one its completion marker names; an input this
    configuration does not have that stage write (render's training set while ``render.set``
    is ``twin``) is not judged here."""
    out = []
    for name in stage.resolved(config, workspace).inputs:
        marker = read_marker(workspace, name)
        made = marker.made_with if marker is not None else None
        writer = made.get("stage") if isinstance(made, dict) else None
        producer = next((entry for entry in STAGES if entry.name == writer and entry.name != stage.name), None)
        if producer is None or name not in producer.resolved(config, workspace).outputs:
            continue
        state = status(producer, config, workspace)
        if state.state == "stale" and not state.members_changed:
            out.append((name, state))
    return out


def _refuse_outdated_inputs(stage: StageEntry, config: Config, workspace: Workspace) -> None:
    outdated = outdated_inputs(stage, config, workspace)
    if outdated:
        said = "; ".join(f"{name} (stage {state.stage}: {state.detail})" for name, state in outdated)
        first = outdated[0][1].stage
        raise StageError(f"stage {stage.name!r} reads {said}, made with another configuration than this "
                         f"command's. Redo {'them' if len(outdated) > 1 else 'it'} first (`speedplus {first} -w "
                         f"{workspace.location} --force`, with this command's --set and --config), or the whole "
                         f"chain (`speedplus run -w {workspace.location} --force`)")


def run_stage(stage: StageEntry, config: Config, workspace: Workspace, *, force: bool = False,
              on_start: Callable[[], None] | None = None, redo: tuple[str, ...] = (),
              follow: bool = False, command: str = "run") -> StageOutcome:
    """Run (or resume, or skip) one stage; see the module docstring. ``on_start`` is called
    once every check has passed, just before anything in the workspace changes. ``redo``
    with ``force``: redo only these members (evaluate's models) and keep the others'.
    ``follow`` (a chain of stages): results stale only because an input was redone (an
    earlier stage's ``--force``) are redone, saying so, instead of refused. ``command``: the
    command the user ran, which a refusal tells them to run again with --force (the stage's
    own where it is ``run``)."""
    resolved = stage.resolved(config, workspace)
    inputs, outputs = resolved.inputs, resolved.outputs
    made_with = fingerprint_payload(stage, config, workspace)
    current = None if made_with is None else _digest(made_with)
    if current is None:
        missing = [name for name in inputs if read_marker(workspace, name) is None]
        made = {MANIFESTS[name].made_by for name in missing if name in MANIFESTS and MANIFESTS[name].made_by}
        how = ("; ".join(f"make it first: `{maker} -w {workspace.location}`" for maker in sorted(made))
               if made else f"run the stage(s) before it first (or `speedplus run -w {workspace.location}`)")
        if made and any(name not in MANIFESTS or not MANIFESTS[name].made_by for name in missing):
            how += f"; and run the stages before it (`speedplus run -w {workspace.location}`)"
        raise StageError(f"stage {stage.name!r} needs the complete manifest(s) {', '.join(missing)} in "
                         f"{workspace.root}; {how}")
    for name in inputs:  # before anything is discarded: a damaged input stops the stage
        problem = damage(list_parts(workspace, name), read_marker(workspace, name))
        if problem is not None:
            raise StageError(f"stage {stage.name!r} needs manifest {name}, which is damaged ({problem}); redo "
                             "the stage that writes it with --force (speedplus status names it)")
    _refuse_outdated_inputs(stage, config, workspace)
    stage.check(config, workspace)
    unknown = sorted(set(redo) - set(resolved.members))
    if unknown:
        raise StageError(f"stage {stage.name!r}: nothing named {', '.join(unknown)} to redo (members: "
                         f"{', '.join(sorted(resolved.members)) or 'none'})")
    state = status(stage, config, workspace)
    if state.state == "done" and not force:
        return StageOutcome(stage.name, "skipped", state.rows, 0.0)
    force, state, forget = _member_redo(stage.name, state, resolved, force, redo)
    replacing = state.replaced(stage)
    if state.state == "stale" and follow and not (force or replacing):
        redone = redone_inputs(stage, config, workspace)
        if redone:
            console.print(f"{stage.name}: its input{'s' if len(redone) > 1 else ''} {', '.join(redone)} "
                          f"{'were' if len(redone) > 1 else 'was'} redone; redoing it")
            replacing = True
    if state.state == "stale" and follow and not (force or replacing):
        retrained = _retrained(stage, config, workspace, state, resolved)
        if retrained:
            console.print(f"{stage.name}: {', '.join(retrained)} retrained in this workspace; redoing "
                          f"{'their results' if state.members_changed else 'it'}")
            if state.members_changed:
                force, state, forget = _member_redo(stage.name, state, resolved, True, state.members_changed)
            else:
                replacing = True
    if state.state == "stale" and not (force or replacing):
        again = stage.name if command == "run" else command
        after = (f"; a later `speedplus run -w {workspace.location}` redoes the stages after it"
                 if stage.chained and command in ("run", stage.name) else "")
        raise StageError(
            f"{workspace.display(workspace.manifest_dir(outputs[0]))} holds results of stage {stage.name!r} "
            f"made with another configuration or other inputs ({state.detail}); rerun it with --force to discard "
            f"them (`speedplus {again} -w {workspace.location} --force`, with this command's options, --set and "
            f"--config{after})")
    if state.state == "damaged" and not force:
        raise StageError(f"stage {stage.name!r}: its results are damaged ({state.detail})")
    previous = None if force else read_marker(workspace, outputs[0]) if outputs else None
    if on_start is not None:
        on_start()
    if force or replacing:
        for name in outputs:
            clear_manifest(workspace, name)
    resumed = not (force or replacing) and any(state.rows.values())
    for name in outputs:
        recover(workspace.manifest_dir(name))
        remove_temporaries(workspace, name)
        # this run's rows are checked against this run's marker, never a previous one's
        workspace.marker_path(name).unlink(missing_ok=True)
        if resumed:
            _forget_rows_without_files(workspace, name, current)
            if forget and resolved.member_column is not None:
                _forget_members(workspace, name, current, resolved.member_column, forget)
    run = stage.function()
    single_threaded_blas()
    workspace.root.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    progress.reset()
    try:
        run(config, workspace.for_run({name: current for name in outputs}, forced=force))
    except KeyboardInterrupt:
        kept = row_count(workspace, outputs[0]) if outputs else 0
        remaining = progress.remaining()
        raise Interrupted(stage.name, kept, None if remaining is None else kept + remaining) from None
    except EngineError as error:  # the cluster failed, not the data: the finished rows resume
        error.kept_rows = row_count(workspace, outputs[0]) if outputs else 0
        raise
    seconds = time.perf_counter() - started
    rows = {name: row_count(workspace, name) for name in outputs}
    members = {**(previous.members if previous else {}), **resolved.members} if resolved.members else None
    _write_markers(stage, workspace, outputs, current, made_with, rows, members, seconds, resumed)
    workspace.sync()  # a workspace on object storage: the store gets the stage's results now
    return StageOutcome(stage.name, "resumed" if resumed else "ran", rows, seconds)


def _member_redo(name: str, state: StageStatus, resolved: Any, force: bool,
                 redo: tuple[str, ...]) -> tuple[bool, StageStatus, set[str]]:
    """``--force`` with named members (evaluate --model) redoes those and keeps every other
    one's rows: the run becomes a resume that first forgets them. Returns (force, state,
    the members to forget)."""
    if not (force and redo and state.state in ("done", "partial", "stale") and _only_members_differ(state, resolved)):
        return force, state, set()
    if set(state.members_changed) - set(redo):
        raise StageError(f"stage {name!r}: {', '.join(sorted(set(state.members_changed) - set(redo)))} changed "
                         "since scored as well; name it with --model too, or --force alone redoes all")
    return False, StageStatus(state.stage, "partial", state.rows, state.detail), set(redo)


def _write_markers(stage: StageEntry, workspace: Workspace, outputs: tuple[str, ...], current: str,
                   made_with: dict[str, Any], rows: dict[str, int], members: dict[str, str] | None,
                   seconds: float, resumed: bool) -> None:
    """Each output's completion marker (docs/architecture.md section 4), after compaction."""
    for name in outputs:
        parts, files = _complete(workspace, name, current)
        write_marker(workspace, name, CompletionMarker(
            current, rows[name], stage.name, SCHEMA_VERSION, metadata.version("speedplus-builder"),
            round(seconds, 3), resumed, datetime.now(UTC).isoformat(timespec="seconds"), made_with, parts, files,
            dict(members or {})))


def _retrained(stage: StageEntry, config: Config, workspace: Workspace, state: StageStatus,
               resolved: Any) -> list[str]:
    """What alone made the results stale, where it is files a stage of this workspace remade
    (``Resolved.retrained``): the changed members, or the changed ``extra`` keys; else none."""
    changed = list(state.members_changed) or _changed_only(stage, config, workspace, "extra")
    return changed if changed and set(changed) <= resolved.retrained else []


def _only_members_differ(state: StageStatus, resolved: Any) -> bool:
    """Whether the results are current but for members: a member-wise redo keeps the rest."""
    return bool(resolved.members) and (state.state != "stale" or bool(state.members_changed))


def _forget_members(workspace: Workspace, name: str, current: str, column: str, members: set[str]) -> None:
    """Drop the rows of ``members`` (``--force`` naming them) before the stage redoes them."""
    spec = MANIFESTS.get(name)
    if spec is None or not list_parts(workspace, name) or column not in spec.schema().names:
        return
    table = read_manifest(workspace, name)
    keep = pa.array([value not in members for value in table.column(column).to_pylist()])
    stamped = {**spec.schema().metadata, b"speedplus.fingerprint": current.encode()}
    compact(workspace.manifest_dir(name), table.filter(keep).replace_schema_metadata(stamped), spec.key)


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


def _complete(workspace: Workspace, name: str, current: str,
              ) -> tuple[tuple[PartRecord, ...] | None, dict[str, FileRecord] | None]:
    """Compact a finished manifest into key order and record its parts and files for the
    marker (``manifests.integrity``): same inputs, same bytes, whatever order the rows came
    in. (None, None) for a marker without rows (report)."""
    if name not in MANIFESTS:
        return None, None
    spec = MANIFESTS[name]
    table = read_manifest(workspace, name)
    stamped = {**spec.schema().metadata, b"speedplus.fingerprint": current.encode()}
    compact(workspace.manifest_dir(name), table.replace_schema_metadata(stamped), spec.key)
    return part_records(list_parts(workspace, name)), file_records(workspace, spec, table.to_pylist())


def redo_plan(config: Config, workspace: Workspace, stages: tuple[StageEntry, ...]) -> list[tuple[str, str]]:
    """The chained stages ``config`` would redo in ``workspace``, each with why: its own
    results are not current, or an input is made by a stage redone before it."""
    redone: dict[str, str] = {}
    plan = []
    for stage in (s for s in stages if s.chained):
        resolved = stage.resolved(config, workspace)
        upstream = [name for name in resolved.inputs if name in redone]
        state = status(stage, config, workspace)
        if upstream:
            plan.append((stage.name, f"its input {upstream[0]} is redone by {redone[upstream[0]]}"))
        elif state.state != "done":
            plan.append((stage.name, state.detail if state.state == "stale" else state.state))
        else:
            continue
        redone.update({name: stage.name for name in resolved.outputs})
    return plan


@dataclass(frozen=True)
class Finding:
    stage: str
    manifest: str
    problems: list[str]


def verify(config: Config, workspace: Workspace, stages: tuple[StageEntry, ...]) -> list[Finding]:
    """Every completed manifest ``status`` lists against its marker, and every file it
    recorded against its size and hash; one finding per manifest (no problems: intact)."""
    findings, seen = [], set()
    for stage in stages:  # under each view status shows (render's training set, every export)
        names = [name for _, view in stage.status_views(config, workspace)
                 for name in stage.resolved(view, workspace).outputs]
        for name in dict.fromkeys(names):
            marker = read_marker(workspace, name)
            if marker is None or name in seen:
                continue
            seen.add(name)
            problem = damage(list_parts(workspace, name), marker)
            findings.append(Finding(stage.name, name, ([problem] if problem else [])
                                    + damaged_files(workspace, marker)))
    return findings
