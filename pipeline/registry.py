"""Every stage, by name (docs/architecture.md section 2): what it does, the package that
runs it, and how it chains. What a stage reads, writes and depends on is the stage's own:
its package's ``resolve(config, workspace) -> Resolved`` (``core/stage_io.py``), which
the runner (fingerprints, resume, status) and the CLI read; nothing here repeats it, so
nothing here can disagree with it. Stages are named as strings and imported only when
used; nothing else imports a stage.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from core.config import Config
from core.stage_io import Resolved
from manifests import Workspace
from speedplus.errors import InputError


@dataclass(frozen=True)
class StageEntry:
    name: str
    summary: str
    #: the stage's package: ``<package>.stage`` has its ``run(config, workspace)`` and
    #: ``resolve(config, workspace)``, ``<package>.config`` its configuration sections
    #: (``SECTIONS``, which ``pipeline.config`` gathers)
    package: str
    #: the package checks what it reads from outside the workspace, or what it will need of
    #: the stages before it (``preflight(config, workspace)``: evaluate, every model against
    #: its contract; calibrate, the plan's count of calibration samples; acquire, the disk
    #: space its images need) before anything is discarded: a chain runs every stage's
    #: before its first stage starts
    preflight: bool = False
    chained: bool = True  # a step of `speedplus run`
    #: results made with another configuration are replaced without --force (they only
    #: record copies made elsewhere, an export to another folder, or a view of other
    #: results, the report)
    replace_stale: bool = False
    #: which target folder's digest is in the fingerprint: the configured folder's (the plan,
    #: which copies it into the workspace) or the workspace's copy (every later stage)
    target_folder: Literal["configured", "workspace"] = "workspace"
    #: its work is spread over the engine's workers: its command takes --engine, --workers
    #: and --ray-address (the others run in the command's own process)
    engines: bool = False
    #: the package may leave itself out of a chain of stages (``skipped_in_chain(config)``:
    #: the plan, when a replayed session brings its own samples)
    may_skip: bool = False
    #: the package reports several results side by side (``status_views(config, workspace)``
    #: -> [(label, config)]: export, one per format written)
    views: bool = False
    #: the package says something of its finished results in ``status`` (``status_note(config,
    #: workspace)`` -> str: the plan, the share of the poses drawn that the facility presents)
    notes: bool = False
    #: the package says what it would make of a facility folder (``facility_rows(config)`` ->
    #: [(what, value)], which ``speedplus facility`` prints: the plan, how well its
    #: calibration poses there determine the robots)
    facility_rows: bool = False

    def resolved(self, config: Config, workspace: Workspace) -> Resolved:
        resolved = _load(f"{self.package}.stage:resolve")(config, workspace)
        if not isinstance(resolved, Resolved):
            raise TypeError(f"{self.package}.resolve returned {type(resolved).__name__}, not a Resolved")
        return resolved

    def check(self, config: Config, workspace: Workspace) -> None:
        """The stage's own checks of its inputs from outside the workspace (a model file),
        before the runner changes anything."""
        if self.preflight:
            _load(f"{self.package}.stage:preflight")(config, workspace)

    def status_views(self, config: Config, workspace: Workspace) -> list[tuple[str, Config]]:
        """What ``status`` shows of this stage: (label, the configuration it is judged under)."""
        if not self.views:
            return [(self.name, config)]
        return list(_load(f"{self.package}.stage:status_views")(config, workspace))

    def note(self, config: Config, workspace: Workspace) -> str:
        """What ``status`` says of the stage's finished results (empty: nothing)."""
        return str(_load(f"{self.package}.stage:status_note")(config, workspace)) if self.notes else ""

    def facility_report(self, config: Config, **options: Any) -> list[tuple[str, str]]:
        """What ``speedplus facility`` prints for this stage on ``config``'s facility folder
        (``options``: the command's own, the package's to read)."""
        return list(_load(f"{self.package}.stage:facility_rows")(config, **options)) if self.facility_rows else []

    def skipped_in_chain(self, config: Config) -> bool:
        """Whether ``speedplus run`` (or any command of several stages) leaves it out."""
        return self.may_skip and bool(_load(f"{self.package}.stage:skipped_in_chain")(config))

    def function(self) -> Callable[..., Any]:
        return _load(f"{self.package}.stage:run")

    def options(self) -> Callable[..., Any] | None:
        """The stage's own command-line options (``<package>.cli:options``, typer-annotated
        parameters -> ``core.command.Request``), or None: the common options alone."""
        try:
            return _load(f"{self.package}.cli:options")
        except ModuleNotFoundError as error:
            if error.name != f"{self.package}.cli":
                raise
            return None


def _load(entry_point: str) -> Callable[..., Any]:
    """The function ``package.module:name`` names, imported now."""
    module, name = entry_point.split(":")
    return getattr(importlib.import_module(module), name)


STAGES: tuple[StageEntry, ...] = (
    StageEntry("plan", "relative poses, view, light and robot/rail commands", "stages.plan", target_folder="configured",
               engines=True, may_skip=True, notes=True, facility_rows=True),
    StageEntry("acquire", "drive the testbed (virtual) or ingest a recorded session (replay): telemetry, motion "
               "capture and images", "stages.acquire", engines=True, preflight=True),
    StageEntry("calibrate", "RWHE calibration per source and Table 1 (W/calibration.json)", "stages.calibrate",
               preflight=True),
    StageEntry("fuse", "per-source poses, rejection, Bayesian fusion (W/fusion.json)", "stages.fuse"),
    StageEntry("label", "SPEED+ labels, keypoints, boxes", "stages.label"),
    StageEntry("render", "Mitsuba 3 synthetic twins of the labels (or, with --set train, the training set)",
               "stages.render", engines=True, views=True),
    StageEntry("evaluate", "ONNX model scores on twins and testbed images (Table 2)", "stages.evaluate",
               preflight=True, engines=True),
    StageEntry("report", "static HTML report (W/report/index.html)", "stages.report", replace_stale=True),
    StageEntry("export", "the labels and images as a SPEED+, BOP or SHIRT dataset", "stages.export", chained=False,
               replace_stale=True, engines=True, views=True),
    StageEntry("train-reference", "train the reference keypoint CNNs (plain and augmented) on the synthetic "
               "training set and export ONNX (W/models/reference.onnx, reference_augmented.onnx)",
               "stages.reference", chained=False, engines=True, views=True),
)
STAGE_NAMES = tuple(stage.name for stage in STAGES)
CHAIN = tuple(stage.name for stage in STAGES if stage.chained)


def stage(name: str) -> StageEntry:
    for entry in STAGES:
        if entry.name == name:
            return entry
    raise InputError(f"unknown stage {name!r}; stages: {', '.join(STAGE_NAMES)}")
