"""The ``speedplus`` command: builds a configuration and calls the runner, nothing more.
One command per stage of ``pipeline.registry``, plus ``run`` (the chain) and ``status``.

Exit codes: 0 success; 1 bad input or configuration (the message names the file, row,
field or key); 2 usage error; 130 interrupted.
"""

from __future__ import annotations

import contextlib
import inspect
import os
import shutil
import sys
import tempfile
import traceback
import typing
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from typer.core import TyperGroup

from core.command import FacilityOption, Request, TargetOption, folders, overrides
from core.command import key_help as section_key_help
from core.config import Config, Override, documented, with_overrides, write_config
from core.engines import EngineError
from manifests import Workspace
from manifests.lock import WorkspaceLock, holder
from manifests.remote import Remote, RemoteCopy, is_remote, working_copy_for
from manifests.schema import MANIFESTS
from manifests.snapshot import Snapshot
from manifests.workspace import CONFIG_FILE
from pipeline import registry, runner
from pipeline.config import SECTION_TYPES, layered, load_config
from speedplus.errors import InputError, RefusalError


class _PipelineOrder(TyperGroup):
    """Lists the commands in the pipeline's order, then the ones about a workspace, a target or a facility."""

    def list_commands(self, ctx: typer.Context) -> list[str]:
        order = [*registry.STAGE_NAMES, "run", "status", "verify", "target", "facility", "keys"]
        return sorted(super().list_commands(ctx), key=lambda name: order.index(name) if name in order else len(order))


app = typer.Typer(
    cls=_PipelineOrder,
    name="speedplus",
    help="SPEED+ builder: spacecraft pose datasets from a robotic testbed and their synthetic twins.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode=None,  # help texts name configuration sections in brackets: [reference] is not markup
)
out = Console()
err = Console(stderr=True)


def _print_version(asked: bool) -> None:
    if asked:
        from importlib.metadata import PackageNotFoundError, version

        from manifests.schema import SCHEMA_VERSION

        try:
            number = version("speedplus-builder")
        except PackageNotFoundError:  # run from a checkout that was not installed
            number = "unknown (not installed)"
        out.print(f"speedplus {number} (manifest schema {SCHEMA_VERSION})", highlight=False)
        raise typer.Exit()


@app.callback()
def _options(version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                                   help="print the version and exit")] = False) -> None:
    """SPEED+ builder: spacecraft pose datasets from a robotic testbed and their synthetic twins."""


def key_help(dotted: str) -> str:
    """The documentation of configuration key ``section.key`` (its field's help and unit)."""
    section, key = dotted.split(".")
    return section_key_help(SECTION_TYPES[section], key)


WorkspaceOption = Annotated[
    str | None, typer.Option("--workspace", "-w", help="run directory W, or a workspace on object storage: "
                             "s3://bucket/prefix, gs://bucket/prefix (default: data/<profile>)")]
ProfileOption = Annotated[
    str | None, typer.Option("--profile", "-p", help="smoke | default | paper (default: W/config.toml, else default)")]
ConfigOption = Annotated[
    Path | None, typer.Option("--config", "-c", help="TOML file overriding the profile", exists=False)]
SetOption = Annotated[
    list[str] | None, typer.Option("--set", "-s", metavar="SECTION.KEY=VALUE",
                                   help="override one key (repeatable)")]
ForceOption = Annotated[bool, typer.Option("--force", help="discard this stage's existing results and redo them")]
EngineOption = Annotated[str | None, typer.Option("--engine", help=key_help("run.engine") + "; this run only")]
RayAddressOption = Annotated[str | None, typer.Option("--ray-address",
                                                      help=key_help("run.ray_address") + "; this run only")]
WorkersOption = Annotated[int | None, typer.Option("--workers", help=key_help("run.workers") + "; this run only")]
def _engine(engine: str | None, ray_address: str | None, workers: int | None) -> list[Override]:
    """The engine flags, which every stage command takes, as overrides of this run only."""
    chosen = [("run.engine", engine, "--engine"), ("run.ray_address", ray_address, "--ray-address"),
              ("run.workers", workers, "--workers")]
    return [Override.of(key, value, flag) for key, value, flag in chosen if value is not None]


def _workspace(location: str, root: Path | None = None) -> Workspace:
    """The workspace a ``--workspace`` names: a local folder, or a working copy (this
    machine's, or ``root``) of one on object storage."""
    if not is_remote(location):
        if Path(location).exists() and not Path(location).is_dir():
            raise InputError(f"{location}: --workspace names a file, not a folder; give a folder (a new one is made)")
        return Workspace(location)
    remote = Remote(location)
    root = root or working_copy_for(remote)
    return Workspace(root, copy=RemoteCopy(remote, root))


def _context(workspace: str | None, profile: str | None, config: Path | None,
             overrides: list[Override]) -> tuple[Config, Workspace, str | None]:
    """The command's configuration, layered on the workspace's saved one
    (``core.config.layered``: saved or profile, then --config, then --set), its
    workspace, and the profile an explicit --profile switched from (None: no switch)."""
    if workspace is None:
        named = profile or (load_config(None, config).profile if config is not None else "default")
        workspace = str(Path("data") / named)
    ws = _workspace(workspace)
    with tempfile.TemporaryDirectory(prefix="speedplus-config-") as folder:
        saved = ws.config_path  # named as it is in messages
        if ws.remote is not None:  # the store's, not what this machine last saw
            saved = Path(folder) / CONFIG_FILE
            data = ws.store.saved_config()
            if data is not None:
                saved.write_bytes(data)
        resolved, switched_from = layered(saved, profile, config, overrides)
    return resolved, ws, switched_from


def _exists(ws: Workspace) -> bool:
    """Whether a workspace has been started (its saved configuration exists)."""
    return ws.store.started()


@contextlib.contextmanager
def _writing(ws: Workspace) -> Iterator[Workspace]:
    """Hold the workspace's lock; on object storage, pull first and push at the end, however
    the command ends (rows finished before an error or Ctrl-C reach the store)."""
    with WorkspaceLock(ws):
        ws.store.pull()
        try:
            yield ws
        except BaseException:
            try:
                ws.store.push()
            except InputError as error:
                err.print(f"[yellow]warning:[/] {escape(str(error))}", highlight=False)
            raise
        ws.store.push()


@contextlib.contextmanager
def _reading(ws: Workspace) -> Iterator[Workspace]:
    """A workspace to read without the lock: on object storage, a fresh temporary copy."""
    if ws.remote is None:
        yield ws
        return
    with tempfile.TemporaryDirectory(prefix="speedplus-read-") as folder:
        copy = _workspace(ws.remote.uri, Path(folder))
        copy.store.pull()
        yield copy


def _run(stages: list[str], workspace: str | None, profile: str | None, config: Path | None,
         saved: list[Override], force: bool, transient: list[Override] = (),
         redo: tuple[str, ...] = (), command: str = "run") -> Workspace:
    """Run ``stages``; ``saved`` overrides go into W/config.toml, ``transient`` ones (which
    choose what a command does: render's image set) apply to this run only, and so do those
    of the ``run`` section (how to execute, never what: engine, workers), wherever they come
    from. A run section in a --config file is the way to keep one.

    Each stage is its own transaction (``_transaction``): the stages a chain completed are
    kept when a later one fails, and the failing one puts back every manifest, marker, JSON
    file and recorded file it changed (``manifests.snapshot``). W/config.toml is written
    when the first stage starts changing anything. Ctrl-C keeps the rows done."""
    transient = [*transient, *(o for o in saved if o.section == "run")]
    saved = [o for o in saved if o.section != "run"]
    resolved, ws, switched_from = _context(workspace, profile, config, saved)
    existed = ws.root.exists()
    try:
        _transaction(stages, resolved, transient, ws, force, switched_from, redo, command)
    finally:
        if ws.remote is None and not existed and not _exists(ws):
            shutil.rmtree(ws.root, ignore_errors=True)  # refused before anything was made: no empty folder left
    if stages and stages[-1] == "report":
        out.print(f"report: {ws.location}/report/index.html")
    return ws


def _transaction(stages: list[str], resolved: Config, transient: list[Override], ws: Workspace, force: bool,
                 switched_from: str | None, redo: tuple[str, ...], command: str) -> None:
    """The stages under the workspace's lock, each stage its own transaction
    (``manifests.snapshot``, docs/architecture.md section 4): a stage that completes is
    kept, whatever comes after it, as make and Snakemake keep every finished target; a
    stage that fails or is refused puts back what it changed (its own half-done work, with
    a refusal's diagnostics), and the error says what the chain kept and how to resume.
    Ctrl-C keeps the rows done (``runner.Interrupted``). ``W/config.toml`` is saved when
    the first stage starts changing anything: what is kept resumes under the configuration
    it was made with."""
    with _writing(ws):
        started: list[str] = []
        done: list[str] = []
        try:
            for name in _chain(stages, resolved, ws, switched_from):
                _one_stage(name, resolved, with_overrides(resolved, transient), ws, force, started, redo,
                           follow=len(stages) > 1, kept=done, command=command)
                done.append(name)
            write_config(resolved, ws.config_path)
        except Exception as error:
            if done and not isinstance(error, typer.Exit):
                error.add_note(_kept_note(done, ws, force))
            raise


def _kept_note(done: list[str], ws: Workspace, force: bool) -> str:
    """What a chain that failed after some stages kept, and how to go on (without --force,
    which would redo what was kept)."""
    again = "run it again without --force" if force else "run the same command"
    return (f"kept: {', '.join(done)} (completed; `speedplus status -w {ws.location}` shows them); after the fix, "
            f"{again} to resume from the stage that failed")


def _chain(stages: list[str], resolved: Config, ws: Workspace, switched_from: str | None) -> list[str]:
    """The stages the command runs, after what must hold before any of them starts."""
    if resolved.run.engine == "ray" and resolved.run.ray_address:
        from core.engines.cluster import reachable

        reachable(resolved.run.ray_address)  # before --force discards anything
    if len(stages) > 1:
        stages = [name for name in stages if not registry.stage(name).skipped_in_chain(resolved)]
    for name in stages:  # what can be refused is refused before the first stage changes anything
        registry.stage(name).check(resolved, ws)
    if switched_from is not None:
        plan = runner.redo_plan(resolved, ws, registry.STAGES)
        listed = "; ".join(f"{name} ({why})" for name, why in plan) or "none"
        out.print(escape(f"profile {switched_from} -> {resolved.profile}: stages to redo: {listed}"), highlight=False)
    return stages


def _one_stage(name: str, saved: Config, resolved: Config, ws: Workspace, force: bool, started: list[str],
               redo: tuple[str, ...], follow: bool, kept: list[str], command: str) -> None:
    """One stage of the command, its own transaction: a failure or refusal puts back what it
    changed (``W/config.toml`` too when it was the first to start); Ctrl-C keeps its rows.
    ``kept``: the stages of the chain done before it."""
    snapshot = Snapshot(ws).take()
    began = False

    def starting() -> None:
        nonlocal began
        began = True
        # saved before the first stage changes anything: rows a killed command leaves resume
        # under the configuration they were made with (a failure puts the old file back)
        if not started:
            if not ws.config_path.exists():  # a new workspace says what it was made with
                out.print(escape(f"{ws.location}: a new workspace, profile {saved.profile} (--profile chooses "
                                 "another; `speedplus status` shows it)"), highlight=False)
            write_config(saved, ws.config_path)
        started.append(name)

    try:
        outcome = runner.run_stage(registry.stage(name), resolved, ws, force=force, on_start=starting, redo=redo,
                                   follow=follow, command=command)
    except KeyboardInterrupt as interrupt:
        if began:  # rows made under this configuration are kept: save it, so that they resume
            write_config(saved, ws.config_path)
            snapshot.drop()
        else:
            snapshot.restore()
        _interrupted(interrupt, force, kept)
    except EngineError as error:
        if not _engine_failed(error, name, began, saved, snapshot, ws, force) and began:
            started.remove(name)
        raise
    except BaseException as error:
        keep = error.keep if isinstance(error, RefusalError) else ()
        for manifest in sorted(set(keep) - snapshot.restore(keep)):
            error.add_note(f"the {manifest} manifest still holds the results made before it (a refusal never replaces "
                           "results): this refusal's reasons are only those above")
        if began:
            started.remove(name)
        raise
    snapshot.drop()
    # a marker-only output (the report's folder) has no rows to count
    rows = ", ".join(f"{k} {v} rows" for k, v in outcome.rows.items() if k in MANIFESTS)
    rows = f" ({rows})" if rows else ""
    if outcome.action == "skipped":
        out.print(f"[green]{name}[/]: up to date{rows}")
    else:
        out.print(f"[green]{name}[/]: {outcome.action} in {outcome.seconds:.1f} s{rows}")


def _engine_failed(error: EngineError, name: str, began: bool, saved: Config, snapshot: Snapshot,
                   ws: Workspace, force: bool) -> bool:
    """A stage its engine could not finish (a Ray node lost, the cluster gone) keeps the rows
    it finished, as Ctrl-C does: each was written whole with its files by the driver and is
    what any engine makes, so they resume; a stage's own error puts its work back instead,
    since its rows may be what the error made (docs/architecture.md section 4)."""
    kept = getattr(error, "kept_rows", 0)
    if not began or not kept:
        snapshot.restore()
        return False
    write_config(saved, ws.config_path)
    snapshot.drop()
    again = "run it again without --force" if force else "run the same command"
    error.add_note(f"kept: {kept} finished rows of {name} (the engine failed, not the data); {again} to resume them")
    return True


def _interrupted(interrupt: KeyboardInterrupt, force: bool, kept: list[str]) -> None:
    """One line and exit 130 (click would otherwise swallow the interrupt without a word);
    ``kept``: the stages of the chain done before the one interrupted."""
    said = str(interrupt) if isinstance(interrupt, runner.Interrupted) else (
        f"interrupted before it changed anything; kept: {', '.join(kept)}; run the same command to resume" if kept
        else "interrupted: nothing was changed; run the same command to start again")
    if force:  # --force again would redo what was kept
        said = said.replace("run the same command to resume", "run it again without --force to resume")
    err.print(f"[yellow]{escape(said)}[/]", highlight=False)
    raise typer.Exit(130)


_COMMON = (
    inspect.Parameter("workspace", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=WorkspaceOption),
    inspect.Parameter("profile", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=ProfileOption),
    inspect.Parameter("config", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=ConfigOption),
    inspect.Parameter("set_", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=SetOption),
    inspect.Parameter("force", inspect.Parameter.KEYWORD_ONLY, default=False, annotation=ForceOption),
)
_ENGINE = (
    inspect.Parameter("engine", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=EngineOption),
    inspect.Parameter("ray_address", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=RayAddressOption),
    inspect.Parameter("workers", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=WorkersOption),
)


def _parameters(options: Callable[..., Request]) -> list[inspect.Parameter]:
    """A stage's own options as keyword parameters, their annotations resolved (typer reads them)."""
    hints = typing.get_type_hints(options, include_extras=True)
    return [parameter.replace(kind=inspect.Parameter.KEYWORD_ONLY, annotation=hints[name])
            for name, parameter in inspect.signature(options).parameters.items()]


def _stage_command(entry: registry.StageEntry) -> None:
    """The stage's command: the common options (an own option of the same name, render's
    ``--set``, takes its place), the stage's own (``<package>.cli:options``), and the
    engine's where its work is spread over workers."""
    options = entry.options()
    own = _parameters(options) if options is not None else []
    by_name = {parameter.name: parameter for parameter in own}
    parameters = [by_name.pop(common.name, common) for common in _COMMON]
    parameters += [*by_name.values(), *(_ENGINE if entry.engines else ())]
    common_names = {parameter.name for parameter in (*_COMMON, *_ENGINE)} - {parameter.name for parameter in own}

    def command(**given: Any) -> None:
        common = {name: given.pop(name, None) for name in common_names}
        request = options(**given) if options is not None else Request()
        _execute(entry, request, common)

    command.__signature__ = inspect.Signature(parameters)  # type: ignore[attr-defined]
    command.__annotations__ = {parameter.name: parameter.annotation for parameter in parameters}
    command.__doc__ = (options.__doc__ if options is not None and options.__doc__
                       else f"Run the {entry.name} stage: {entry.summary}.")
    app.command(entry.name)(command)


def _execute(entry: registry.StageEntry, request: Request, common: dict[str, Any]) -> None:
    """Run what a stage command asks: the common options, then the stage's request (and what
    it asks once the configuration is resolved), then what it reports."""
    workspace, profile, config, force = (common.get(name) for name in ("workspace", "profile", "config", "force"))
    given = list(overrides(common.get("set_")))
    if request.then is not None:
        resolved, ws, _ = _context(workspace, profile, config, [*given, *request.saved])
        request = request.merged(request.then(resolved, ws, bool(force)))
    saved = [*given, *request.saved]
    for note in request.notes:
        out.print(escape(note), highlight=False)
    transient = [*request.transient, *_engine(common.get("engine"), common.get("ray_address"), common.get("workers"))]
    ws = _run(list(request.stages or (entry.name,)), workspace, profile, config, saved, bool(force), transient,
              request.redo, entry.name)
    for line in request.report(ws) if request.report is not None else ():
        out.print(escape(line), highlight=False)


for _entry in registry.STAGES:
    _stage_command(_entry)


@app.command("run")
def run_command(
    workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
    set_: SetOption = None, force: ForceOption = False,
    until: Annotated[str | None, typer.Option("--until", help="last stage to run: " + ", ".join(registry.CHAIN))]
    = None, target: TargetOption = None, facility: FacilityOption = None,
    engine: EngineOption = None, ray_address: RayAddressOption = None, workers: WorkersOption = None,
    check: Annotated[bool, typer.Option(
        "--check", "--dry-run", help="check every stage's inputs (models, folders, counts) and say what would run, "
        "changing nothing")] = False,
) -> None:
    """Run the stages of the chain in order, skipping those already up to date. Every
    stage's checks run before the first stage starts; a stage that completes is kept if a
    later one fails."""
    names = list(registry.CHAIN)
    if until is not None:
        if until not in names:
            raise typer.BadParameter(f"unknown stage {until!r}; stages: {', '.join(names)}", param_hint="--until")
        names = names[: names.index(until) + 1]
    saved = [*overrides(set_), *folders(target, facility)]
    if check:
        _check(names, workspace, profile, config, saved, force)
        return
    _run(names, workspace, profile, config, saved, force, _engine(engine, ray_address, workers))


def _check(stages: list[str], workspace: str | None, profile: str | None, config: Path | None,
           saved: list[Override], force: bool) -> None:
    """``run --check``: the chain's checks, and what each stage would do, as Snakemake's
    dry run says (nothing is written, not even W/config.toml)."""
    resolved, ws, switched_from = _context(workspace, profile, config, [o for o in saved if o.section != "run"])
    table = Table(title=escape(f"{ws.location}: what `speedplus run` would do (profile {resolved.profile})"))
    for column in ("stage", "now", "would"):
        table.add_column(column)
    redone = False
    for name in _chain(stages, resolved, ws, switched_from):
        state = runner.status(registry.stage(name), resolved, ws)
        if state.state == "done" and not force and not redone:
            would = "skip: up to date"
        elif state.state == "stale" and not force and not redone and not state.replaced(registry.stage(name)):
            would = f"refuse: {state.detail} (--force redoes it)"
        else:
            would = "resume" if state.state == "partial" and not force else "run"
            redone = True
        table.add_row(name, f"{state.state}: {state.detail}" if state.detail else state.state, escape(would))
    out.print(table)
    out.print("checks passed: models, folders and counts of every stage above")


@app.command("status")
def status_command(workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
                   set_: SetOption = None) -> None:
    """List every stage as done / partial / stale / missing, with row counts."""
    resolved, located, _ = _context(workspace, profile, config, list(overrides(set_)))
    _must_exist(located)
    with _reading(located) as ws:
        _print_status(resolved, ws)


def _must_exist(ws: Workspace) -> None:
    """A folder, or a store prefix holding anything (a workspace its first command is still
    starting counts: its lock or lease is there)."""
    if not (ws.root.is_dir() if ws.remote is None else bool(ws.remote.listing())):
        raise InputError(f"{ws.location}: no such workspace; start one with `speedplus run "
                         f"--workspace {ws.location}`")


def _print_status(resolved: Config, ws: Workspace) -> None:
    table = Table(title=escape(f"{ws.location} (profile {resolved.profile})"))
    for column in ("stage", "state", "rows", "detail"):
        table.add_column(column)
    colours = {"done": "green", "partial": "yellow", "stale": "red", "missing": "dim", "damaged": "bold red"}
    chain: list[tuple[str, str]] = []
    for entry in registry.STAGES:
        for label, config in entry.status_views(resolved, ws):
            state = runner.status(entry, config, ws)
            rows = ", ".join(f"{k} {v}" for k, v in state.rows.items() if k in MANIFESTS) or "-"
            detail = state.detail or (entry.note(config, ws) if state.state == "done" else "")
            table.add_row(label, f"[{colours[state.state]}]{state.state}[/]", escape(rows), escape(detail))
            if entry.chained and label == entry.name and not entry.skipped_in_chain(config):  # render train: not run's
                chain.append((entry.name, state.state))
    out.print(table)
    done = [name for name, state in chain if state == "done"]
    after = next((name for name, state in chain if state != "done"), None)
    if done and after is not None:
        out.print(escape(f"kept: {', '.join(done)}; `speedplus run -w {ws.location}` goes on from {after} "
                         "(with the --set and --config of the command that made them)"), highlight=False)
    busy = holder(ws)
    if busy:
        out.print(escape(f"in use by {busy}: states may change while it runs"))


@app.command("verify")
def verify_command(workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
                   set_: SetOption = None) -> None:
    """Check a whole workspace: every completed manifest against its completion marker, and
    every image, mask and model against the size and hash recorded when it was written.
    Exit 1 when anything is damaged, naming the stage to redo."""
    resolved, located, _ = _context(workspace, profile, config, list(overrides(set_)))
    _must_exist(located)
    with _reading(located) as ws:
        findings = runner.verify(resolved, ws, registry.STAGES)
    table = Table(title=escape(f"{ws.location}: integrity"))
    for column in ("stage", "manifest", "state", "detail"):
        table.add_column(column)
    for finding in findings:
        detail = "; ".join(finding.problems[:3]) + (f" (and {len(finding.problems) - 3} more)"
                                                    if len(finding.problems) > 3 else "")
        table.add_row(finding.stage, finding.manifest, "[green]intact[/]" if not finding.problems
                      else "[bold red]damaged[/]", escape(detail))
    out.print(table)
    damaged = sorted({f.stage for f in findings if f.problems}, key=registry.STAGE_NAMES.index)
    if damaged:
        raise InputError(f"{ws.location}: damaged results; redo {', '.join(damaged)} with --force "
                         f"(`speedplus {damaged[0]} -w {ws.location} --force`, then `speedplus run -w {ws.location}`)")
    out.print(f"{len(findings)} completed manifests intact" if findings else "nothing completed yet")


@app.command("keys")
def keys_command(sections: Annotated[list[str] | None, typer.Argument(
        help=f"configuration sections ({', '.join(SECTION_TYPES)}); none: every one")] = None) -> None:
    """Print the configuration keys of SECTIONS: default, unit and meaning, as
    ``--set SECTION.KEY=VALUE`` and a TOML file take them. Exit 1 naming an unknown section."""
    unknown = [name for name in sections or [] if name not in SECTION_TYPES]
    if unknown:
        raise InputError(f"keys: no configuration section {unknown[0]!r}; the sections: {', '.join(SECTION_TYPES)}")
    for name in sections or list(SECTION_TYPES):
        table = Table(title=escape(f"[{name}]"), title_justify="left")
        for column, options in (("key", {"no_wrap": True}), ("default", {"overflow": "fold", "max_width": 24}),
                                ("unit", {}), ("meaning", {"ratio": 1})):
            table.add_column(column, **options)
        for key, default, unit, meaning in documented(SECTION_TYPES[name]):
            table.add_row(escape(f"{name}.{key}"), escape(repr(default)), escape(unit), escape(meaning))
        out.print(table)


@app.command("target")
def target_command(folder: Annotated[Path, typer.Argument(help="a target folder: target.toml beside its mesh")]
                   ) -> None:
    """Check a target folder and print what the pipeline takes from it: its parts, its size
    at full scale and as the mock-up, its keypoints (declared, or chosen on the mesh), its
    views, where the motion-capture markers go, and the symmetries that make its keypoints
    ambiguous. Exit 1 naming the file and key when it cannot be used."""
    from stages.common.target_report import describe  # the shared layer: meshes load only there

    title, rows = describe(folder, load_config("default"))
    table = Table(title=escape(title))
    for column in ("what", "value"):
        table.add_column(column)
    for what, value in rows:
        table.add_row(what, escape(value))
    out.print(table)


@app.command("facility")
def facility_command(
    folder: Annotated[Path, typer.Argument(help="a facility folder: facility.toml beside its URDFs")],
    target: Annotated[Path | None, typer.Option(
        help="the target folder whose mock-up the distances are for (default: the built-in Tango)")] = None,
    samples: Annotated[int, typer.Option(min=8, help="relative poses drawn to measure what it presents")] = 96,
    distance: Annotated[tuple[float, float] | None, typer.Option(
        help="camera-to-mock-up distances MIN MAX, m (default: SPEED+'s at the target's apparent size)")] = None,
    profile: Annotated[str, typer.Option(
        "--profile", "-p", help="the profile whose calibration poses (plan.n_calibration) are planned here and "
        "measured: how well they determine the robots")] = "smoke",
    calibration_poses: Annotated[int | None, typer.Option(
        min=0, help="calibration poses to plan and measure instead of the profile's plan.n_calibration (0: none)")]
    = None,
) -> None:
    """Check a facility folder and print what the pipeline will use: the room, each robot's
    chain, joint limits, reach, rail and inverse kinematics, static mounts, camera, lights
    and motion capture, the share of SO(3) and of the distance range the facility can
    present to its camera (with its 95% interval), and how well the profile's calibration
    poses determine the robots. Exit 1 naming the file and key, or the URDF element, when it
    cannot be used."""
    from stages.common.facility_report import describe  # the shared layer: URDFs load only there

    if distance is not None and not 0 < distance[0] <= distance[1]:
        raise InputError(f"facility: --distance {distance[0]:g} {distance[1]:g}: expected 0 < MIN <= MAX (m)")
    title, rows = describe(folder, target, samples, distance)
    config = load_config(profile, overrides=list(folders(target, folder)))
    rows += registry.stage("plan").facility_report(config, calibration_poses=calibration_poses)
    table = Table(title=escape(title))
    for column in ("what", "value"):
        table.add_column(column)
    for what, value in rows:
        table.add_row(escape(what), escape(value))
    out.print(table)


@app.command("view")
def view_command(
    folder: Annotated[Path, typer.Argument(help="a facility folder (facility.toml) or a workspace (config.toml)")],
    out_file: Annotated[Path | None, typer.Option(
        "--out", help="the recording to write (default: DIR/view.rrd, in the folder or the workspace)")] = None,
    open_viewer: Annotated[bool | None, typer.Option(
        "--open/--no-open", help="open it in the Rerun viewer (default: where a display exists)")] = None,
) -> None:
    """Write a 3D recording of a facility folder or a workspace, and open it in the Rerun
    viewer where a display exists (``rerun FILE`` opens it anywhere): the room, its
    obstacles, the robots' links and rails, the motion-capture cameras and the lights; for a
    workspace also, on the ``capture`` timeline, the arms at each planned pose, the camera's
    frustum with its image, motion capture's lines of sight to the markers, and the
    labelled target against the true one, green where it meets the SPEED+ thresholds."""
    from stages.common.view import record_facility, record_workspace  # the shared layer: rerun loads only there

    out_path = (out_file or folder / "view.rrd").resolve()
    if (folder / CONFIG_FILE).is_file():
        workspace = Workspace(folder)
        written, words = record_workspace(load_config(None, folder / CONFIG_FILE), workspace, out_path)
    else:
        written, words = record_facility(folder, out_path)
    out.print(f"view: {escape(words)} in {escape(str(written))}")
    display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform == "darwin"
    if open_viewer if open_viewer is not None else display:
        import subprocess

        subprocess.Popen([sys.executable, "-m", "rerun", str(written)], start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    else:
        out.print(f"open it with `rerun {escape(str(written))}` (pip install rerun-sdk=={_rerun_version()})")


def _rerun_version() -> str:
    from importlib.metadata import version

    return version("rerun-sdk")


def _crash_log(error: BaseException) -> Path:
    """Where an unexpected error's traceback goes (the message names it): the user's cache,
    else the system's temporary folder."""
    text = (f"speedplus {' '.join(sys.argv[1:])}\n\n"
            + "".join(traceback.format_exception(type(error), error, error.__traceback__)))
    name = f"crash-{datetime.now(UTC):%Y%m%dT%H%M%S}-{os.getpid()}.log"
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "speedplus" / "crashes"
    for folder in (cache, Path(tempfile.gettempdir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            (folder / name).write_text(text)
            return folder / name
        except OSError:
            continue
    raise error


def main() -> None:
    """Console-script entry point: maps errors to exit codes with one clear message; an
    unexpected error is one line too, with its traceback in a crash log."""
    try:
        app()
    except InputError as error:  # ManifestError among them
        said = "\n".join([str(error), *getattr(error, "__notes__", ())])
        err.print(f"[bold red]error:[/] {escape(said)}", highlight=False)
        sys.exit(1)
    except KeyboardInterrupt:
        err.print("[yellow]interrupted[/]")
        sys.exit(130)
    except Exception as error:  # noqa: BLE001 - the last line of defence: never a traceback
        log = _crash_log(error)
        err.print(f"[bold red]error:[/] unexpected {escape(type(error).__name__)}: {escape(str(error))[:300]} "
                  f"(a bug of speedplus; the traceback is in {escape(str(log))})"
                  + "".join(f"\n{escape(note)}" for note in getattr(error, "__notes__", ())), highlight=False)
        sys.exit(1)


if __name__ == "__main__":
    main()
