"""Every stage, declared once (docs/architecture.md section 2): its name, what it does, the
function that runs it, the manifests it reads and writes, and the configuration sections
that determine its results. The runner (fingerprints, resume, status) and the CLI (one
command per stage) derive everything from these entries; nothing else imports a stage.

A stage whose inputs or outputs depend on the configuration (acquire's backend, render's
image set, export's format) names a ``resolve`` function in its own package; it returns
``(inputs, sections, extra, outputs)``, where ``extra`` is more fingerprint content (a
replayed folder's digest, an ONNX model's digest).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from manifests import Workspace
from pipeline.config import Config
from speedplus.errors import InputError


@dataclass(frozen=True)
class Resolved:
    """A stage's inputs, configuration sections, extra fingerprint content and outputs for one configuration."""

    inputs: tuple[str, ...]
    sections: tuple[str, ...]
    extra: dict[str, Any]
    outputs: tuple[str, ...]
    #: results kept per member (evaluate: per model): name -> digest. Members are added
    #: without redoing the others; their digests are not in the fingerprint but in the markers
    members: dict[str, str] = field(default_factory=dict)
    #: the configuration key that lists the members (left out of the fingerprint) and the
    #: output column that names a row's member
    member_key: str | None = None
    member_column: str | None = None


@dataclass(frozen=True)
class StageEntry:
    name: str
    summary: str
    run: str  # "module:function" taking (config, workspace); imported only when the stage runs
    inputs: tuple[str, ...]  # manifests whose completion markers it needs
    outputs: tuple[str, ...]  # manifests it writes (the runner writes their completion markers)
    sections: tuple[str, ...]  # configuration sections in its fingerprint
    #: "module:function": (config, workspace) -> Resolved (or its first four fields)
    resolve: str | None = None
    #: "module:function" taking (config, workspace): checks what the stage reads from outside the
    #: workspace (evaluate: every model against its contract) before anything is discarded
    preflight: str | None = None
    chained: bool = True  # a step of `speedplus run`
    #: results made with another configuration are replaced without --force (they only
    #: record copies made elsewhere: an export to another folder or in another format)
    replace_stale: bool = False
    #: which target's digest is in the fingerprint: the configured folder's (the plan, which
    #: copies it into the workspace) or the workspace's copy (every later stage)
    target: Literal["configured", "workspace"] = "workspace"

    def resolved(self, config: Config, workspace: Workspace) -> Resolved:
        if self.resolve is None:
            return Resolved(self.inputs, self.sections, {}, self.outputs)
        resolved = _load(self.resolve)(config, workspace)
        if isinstance(resolved, dict):  # a stage cannot import this module: it names the fields
            return Resolved(**resolved)
        return Resolved(*resolved)

    def check(self, config: Config, workspace: Workspace) -> None:
        """The stage's own checks of its inputs from outside the workspace (a model file),
        before the runner changes anything."""
        if self.preflight is not None:
            _load(self.preflight)(config, workspace)

    def function(self) -> Callable[..., Any]:
        return _load(self.run)


def evaluated_models(config: Config, workspace: Workspace) -> list[Any]:
    """The model files evaluate scores under ``config`` in ``workspace`` (paths; none when
    it has none to pick): what ``evaluate --model`` adds to."""
    return list(_load("stages.evaluate:model_paths")(config, workspace))


def _load(target: str) -> Callable[..., Any]:
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


STAGES: tuple[StageEntry, ...] = (
    StageEntry("plan", "relative poses, view, light and robot/rail commands", "stages.plan:run",
               (), ("plan",), ("plan", "camera", "testbed"), resolve="stages.plan:resolve", target="configured"),
    StageEntry("acquire", "drive the testbed (virtual) or ingest a recorded session (replay): telemetry, motion "
               "capture and images", "stages.acquire:run",
               ("plan",), ("captures", "truth"), ("acquire", "virtual", "camera", "testbed"),
               resolve="stages.acquire:resolve"),
    StageEntry("calibrate", "RWHE calibration per source and Table 1 (W/calibration.json)", "stages.calibrate:run",
               ("captures",), ("calibration_samples",), ("calibrate", "testbed")),
    StageEntry("fuse", "per-source poses, rejection, Bayesian fusion (W/fusion.json)", "stages.fuse:run",
               ("captures", "calibration_samples"), ("poses",), ("fuse", "testbed")),
    StageEntry("label", "SPEED+ labels, keypoints, boxes", "stages.label:run",
               ("poses",), ("labels",), ("label", "testbed")),
    StageEntry("render", "Mitsuba 3 synthetic twins of the labels (or, with --set train, the training set)",
               "stages.render:run", ("labels",), ("renders",), ("render", "testbed"),
               resolve="stages.render:resolve"),
    StageEntry("evaluate", "ONNX model scores on twins and testbed images (Table 2)", "stages.evaluate:run",
               ("renders", "labels"), ("predictions", "scores"), ("evaluate",), resolve="stages.evaluate:resolve",
               preflight="stages.evaluate:check_models"),
    StageEntry("report", "static HTML report (W/report/index.html)", "stages.report:run",
               ("labels", "renders", "predictions", "scores"), ("report",), ()),
    StageEntry("export", "the labels and images as a SPEED+ or BOP dataset", "stages.export:run",
               ("labels", "captures"), ("export_speedplus",), ("export", "camera"),
               resolve="stages.export:resolve", chained=False, replace_stale=True),
    StageEntry("train-reference", "train the reference keypoint CNNs (plain and augmented) on the synthetic "
               "training set and export ONNX (W/models/reference.onnx, reference_augmented.onnx)",
               "stages.reference:run",
               ("train",), ("models",), ("reference",), chained=False),
)
STAGE_NAMES = tuple(stage.name for stage in STAGES)
CHAIN = tuple(stage.name for stage in STAGES if stage.chained)


def stage(name: str) -> StageEntry:
    for entry in STAGES:
        if entry.name == name:
            return entry
    raise InputError(f"unknown stage {name!r}; stages: {', '.join(STAGE_NAMES)}")
