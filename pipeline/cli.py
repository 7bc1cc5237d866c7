"""The ``speedplus`` command: builds a configuration and calls the runner, nothing more.

Exit codes: 0 success; 1 bad input or configuration (the message names the file, row,
field or key); 2 usage error; 3 a stage that is not built yet.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from manifests import ManifestError, Workspace
from pipeline import runner
from pipeline.config import load_config, write_config
from pipeline.errors import InputError

app = typer.Typer(
    name="speedplus",
    help="SPEED+ builder: spacecraft pose datasets from a robotic testbed and their synthetic twins.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
out = Console()
err = Console(stderr=True)

WorkspaceOption = Annotated[
    Path | None, typer.Option("--workspace", "-w", help="run directory W (default: data/<profile>)")]
ProfileOption = Annotated[
    str | None, typer.Option("--profile", "-p", help="smoke | default | paper (default: W/config.toml, else default)")]
ConfigOption = Annotated[
    Path | None, typer.Option("--config", "-c", help="TOML file overriding the profile", exists=False)]
SetOption = Annotated[
    list[str] | None, typer.Option("--set", "-s", help="override one key: section.key=value (repeatable)")]
ForceOption = Annotated[bool, typer.Option("--force", help="discard this stage's existing results and redo them")]


def _context(workspace: Path | None, profile: str | None, config: Path | None,
             overrides: list[str] | None) -> tuple[runner.Config, Workspace]:
    """Resolve the configuration: explicit options win; else the workspace's config.toml."""
    overrides = overrides or []
    if workspace is not None and profile is None and config is None:
        existing = Workspace(workspace).config_path
        if existing.exists():
            config = existing
    resolved = load_config(profile, config, overrides)
    return resolved, Workspace(workspace or Path("data") / resolved.profile)


def _run(stages: list[str], workspace: Path | None, profile: str | None, config: Path | None,
         overrides: list[str] | None, force: bool, transient: list[str] | None = None) -> None:
    """Run ``stages``; ``overrides`` are saved in W/config.toml, ``transient`` ones (which
    choose what a command does, e.g. the image set or engine of render) apply to this run only."""
    resolved, ws = _context(workspace, profile, config, overrides)
    ws.root.mkdir(parents=True, exist_ok=True)
    write_config(resolved, ws.config_path)
    if transient:
        resolved = load_config(resolved.profile, ws.config_path, transient)
    if resolved.acquire.backend == "replay" and len(stages) > 1:
        stages = [name for name in stages if name != "plan"]  # a replayed session brings its own samples
    last_done = None
    for name in stages:
        stage = runner.stage_spec(name)
        if stage.module is None:
            after = f" after {last_done!r}" if last_done else ""
            raise runner.NotBuiltError(
                f"stage {name!r} is not built yet; the pipeline stopped{after}. Results so far are in {ws.root}")
        outcome = runner.run_stage(stage, resolved, ws, force=force)
        rows = ", ".join(f"{k} {v} rows" for k, v in outcome.rows.items())
        if outcome.action == "skipped":
            out.print(f"[green]{name}[/]: up to date ({rows})")
        else:
            out.print(f"[green]{name}[/]: {outcome.action} in {outcome.seconds:.1f} s ({rows})")
        last_done = name
    if last_done == "report":
        out.print(f"report: {ws.root / 'report' / 'index.html'}")


def _stage_command(name: str) -> None:
    stage = runner.stage_spec(name)

    def command(workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
                set_: SetOption = None, force: ForceOption = False) -> None:
        _run([name], workspace, profile, config, set_, force)

    command.__doc__ = f"Run the {name} stage: {stage.summary}."
    # typer reads the parameter name for --set from the annotation's option name
    app.command(name)(command)


for _name in runner.STAGE_NAMES:
    if _name not in ("acquire", "render", "evaluate"):
        _stage_command(_name)


@app.command("acquire")
def acquire_command(
    workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
    set_: SetOption = None, force: ForceOption = False,
    backend: Annotated[str | None, typer.Option("--backend", help="virtual | replay (acquire.backend)")] = None,
    format_: Annotated[str | None, typer.Option("--format", help="replay format: session | handeye | tabb")] = None,
    source: Annotated[Path | None, typer.Option("--source", help="replay: recorded session directory")] = None,
) -> None:
    """Run the acquire stage: drive the testbed (virtual) or ingest a recorded session (replay)."""
    overrides = list(set_ or [])
    if backend is not None:
        overrides.append(f"acquire.backend={backend}")
    if format_ is not None:
        overrides.append(f"acquire.format={format_}")
    if source is not None:
        overrides.append(f"acquire.source={str(source.resolve())!r}")
    _run(["acquire"], workspace, profile, config, overrides, force)


@app.command("render")
def render_command(
    workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", "-s", help="twin (one per label) or train (the training set); or, like every command, "
        "section.key=value to override one key (repeatable)")] = None,
    force: ForceOption = False,
    count: Annotated[int | None, typer.Option("--count", help="train: number of images (render.train_count)")] = None,
    engine: Annotated[str | None, typer.Option("--engine", help="local | ray (run.engine)")] = None,
    ray_address: Annotated[str | None, typer.Option("--ray-address", help="Ray cluster address (run.ray_address)")]
    = None,
) -> None:
    """Run the render stage: Mitsuba 3 twins of the labels, or the training set."""
    overrides = [value for value in set_ or [] if "=" in value]
    transient = [f"render.set={value}" for value in set_ or [] if "=" not in value]
    if count is not None:
        overrides.append(f"render.train_count={count}")
    if engine is not None:
        transient.append(f"run.engine={engine}")
    if ray_address is not None:
        transient.append(f"run.ray_address={ray_address!r}")
    _run(["render"], workspace, profile, config, overrides, force, transient)


@app.command("evaluate")
def evaluate_command(
    workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
    set_: SetOption = None, force: ForceOption = False,
    model: Annotated[Path | None, typer.Option(
        "--model", help="ONNX model following the contract (evaluate.model; default: the reference model)")] = None,
) -> None:
    """Run the evaluate stage: score an ONNX model on the twins and the testbed images (Table 2)."""
    overrides = list(set_ or [])
    if model is not None:
        overrides.append(f"evaluate.model={str(model.resolve())!r}")
    _run(["evaluate"], workspace, profile, config, overrides, force)


@app.command("train-reference")
def train_reference_command(
    workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
    set_: SetOption = None,
    model_path: Annotated[Path, typer.Option("--out", help="where the ONNX model goes (and its card, .json)")]
    = Path("models/reference.onnx"),
    steps: Annotated[int | None, typer.Option("--steps", help="stop after this many optimiser steps (a quick "
                                                                "check of the recipe)")] = None,
) -> None:
    """Train the reference keypoint CNN on the synthetic training set (rendered first if
    needed, section [reference]) and export it to ONNX with the evaluation contract."""
    resolved, ws = _context(workspace, profile, config, set_)
    recipe = resolved.reference
    transient = ["render.set=train", f"render.train_count={recipe.images}",
                 f"render.train_resolution_scale={recipe.resolution_scale}"]
    _run(["render"], workspace, profile, config, set_, False, transient)
    trained = load_config(resolved.profile, ws.config_path, transient)
    card = runner.train_reference(trained, ws, model_path, max_steps=steps)
    held = card["held_out"]
    out.print(f"{model_path}: trained on {card['training_images']} images in {card['train_seconds']:.0f} s; "
              f"held-out synthetic: mean SPEED score {held['mean_speed_score']:.4f}, median rotation error "
              f"{held['median_rotation_error_deg']:.2f} deg")


@app.command("run")
def run_command(
    workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
    set_: SetOption = None, force: ForceOption = False,
    until: Annotated[str | None, typer.Option("--until", help="last stage to run")] = None,
) -> None:
    """Run the stages in order, skipping those already up to date."""
    names = list(runner.STAGE_NAMES)
    if until is not None:
        if until not in names:
            raise typer.BadParameter(f"unknown stage {until!r}; stages: {', '.join(names)}", param_hint="--until")
        names = names[: names.index(until) + 1]
    _run(names, workspace, profile, config, set_, force)


@app.command("status")
def status_command(workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
                   set_: SetOption = None) -> None:
    """List every stage as done / partial / stale / missing, with row counts."""
    resolved, ws = _context(workspace, profile, config, set_)
    table = Table(title=f"{ws.root} (profile {resolved.profile})")
    for column in ("stage", "state", "rows", "detail"):
        table.add_column(column)
    colours = {"done": "green", "partial": "yellow", "stale": "red", "missing": "dim", "not built": "dim"}
    for stage in runner.STAGES:
        state = runner.status(stage, resolved, ws)
        rows = ", ".join(f"{k} {v}" for k, v in state.rows.items()) or "-"
        table.add_row(stage.name, f"[{colours[state.state]}]{state.state}[/]", rows, state.detail)
    out.print(table)


@app.command("export")
def export_command(
    workspace: WorkspaceOption = None, profile: ProfileOption = None, config: ConfigOption = None,
    set_: SetOption = None,
    format_: Annotated[str, typer.Option("--format", help="speedplus | bop")] = "speedplus",
    out_dir: Annotated[Path | None, typer.Option("--out", help="export directory (default W/export)")] = None,
) -> None:
    """Export the labels as a SPEED+ (or BOP) dataset."""
    from manifests import exports, read_success
    from stages.common.sidecars import calibrated_camera

    resolved, ws = _context(workspace, profile, config, set_)
    if read_success(ws, "labels") is None:
        raise runner.StageError(f"{ws.root}: no complete labels to export; run `speedplus run --until label` first")
    if format_ not in ("speedplus", "bop"):
        raise typer.BadParameter(f"unknown format {format_!r}; expected speedplus or bop", param_hint="--format")
    camera = calibrated_camera(ws)
    camera_matrix, dist, width, height = camera.camera_matrix, camera.dist, camera.width, camera.height
    target = out_dir or ws.root / "export"
    if format_ == "speedplus":
        pitch = resolved.camera.pixel_pitch_m * resolved.camera.reference_width_px / width
        counts = exports.export_speedplus(ws, target, exports.camera_json(camera_matrix, dist, width, height, pitch))
    else:
        counts = exports.export_bop(ws, target, camera_matrix)
    out.print(f"exported {', '.join(f'{v} {k}' for k, v in counts.items())} labels ({format_}) to {target}")


def main() -> None:
    """Console-script entry point: maps errors to exit codes with one clear message."""
    try:
        app()
    except (InputError, ManifestError) as error:
        err.print(f"[bold red]error:[/] {escape(str(error))}", highlight=False)
        sys.exit(1)
    except runner.NotBuiltError as error:
        err.print(f"[bold yellow]stopped:[/] {escape(str(error))}", highlight=False)
        sys.exit(3)
    except KeyboardInterrupt:
        err.print("[yellow]interrupted[/]: finished parts are kept; rerun the same command to resume")
        sys.exit(130)


if __name__ == "__main__":
    main()
