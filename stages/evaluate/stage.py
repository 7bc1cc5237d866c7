"""The evaluate stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

Every labelled capture is one ``lightbox`` or ``sunlamp`` image; its twin is one
``synthetic`` image. Both are scored against the label with the label camera, by every
model of ``evaluate.models`` (by default the plain and the augmented reference models), and
for a model of oracle crops also on its own crop (``self``). Writes the ``predictions``
manifest (per model, crop and image), the ``scores`` manifest (per model, crop, domain
and configuration, each mean with its interval: ``intervals.py``) and the ``comparisons``
manifest (each model minus the reference on the same images: ``comparisons.py``), and
prints Table 2 for each and each comparison.
"""

from __future__ import annotations

import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pyarrow as pa
from rich.console import Console

from core.config import Config
from core.engines import threads_per_worker
from core.progress import track
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest, write_part
from manifests import clear as clear_manifest
from manifests.integrity import sha256
from manifests.workspace import MODELS_DIR
from speedplus.errors import FileError, InputError
from stages.common.detector import DETECTOR_NAME, Detector
from stages.common.dispatch import map_config
from stages.common.json_arrays import calibrated_camera
from stages.common.model_contract import BUILTIN_TARGET
from stages.common.pose_model import PoseModel
from stages.common.workspace_target import workspace_target
from stages.evaluate.comparisons import compare, print_comparison, reference_model
from stages.evaluate.scorer import Decoding, open_scorer
from stages.evaluate.table import print_table2, summarise
from stages.evaluate.tracks import tracking_tables, tracks

REPOSITORY = Path(__file__).resolve().parents[2]


#: the reference models shipped for the built-in Tango (``evaluate.models`` empty)
SHIPPED_MODELS = ("models/reference.onnx", "models/reference_augmented.onnx")
#: and their detector (``evaluate.detector = auto``)
SHIPPED_DETECTOR = f"models/{DETECTOR_NAME}.onnx"


def model_paths(config: Config, workspace: Workspace | None) -> list[Path]:
    """``evaluate.models``: absolute, relative to the current directory, or to the repository.
    Empty: the models trained in this workspace (``W/models/*.onnx``, by train-reference),
    else, for the built-in Tango, the shipped reference models; for another target none,
    which ``preflight`` refuses naming the target and the command that trains one."""
    paths = [_located(text) for text in list(config.evaluate.models) or _default_models(config, workspace)]
    names = [path.stem for path in paths]
    if len(set(names)) != len(names):
        raise InputError(f"evaluate.models {list(config.evaluate.models)}: give each model its own file name (a "
                         "model is named by it in predictions and scores)")
    return paths


def with_added_models(config: Config, workspace: Workspace, added: list[Path]) -> tuple[list[str], list[str]]:
    """``evaluate --model FILE``: ``evaluate.models`` with the files ``added`` beside the
    models already scored (an empty list stands for those evaluate picks itself), a file
    replacing a model of the same name; and a note for each model so replaced (a model is
    named by its file name)."""
    current = config.evaluate.models or tuple(str(path) for path in model_paths(config, workspace))
    files = [str(path.expanduser().resolve()) for path in added]
    by_name = {Path(path).stem: path for path in files}
    kept = [path for path in current if Path(path).stem not in by_name]
    notes = [f"evaluate.models: {Path(path).stem} is now {by_name[Path(path).stem]} (was {path}): a model is named "
             "by its file name" for path in sorted(set(current) - set(kept) - set(files))]
    return [*kept, *files], notes


def _located(text: str) -> Path:
    path = Path(text).expanduser()
    return path.resolve() if path.is_absolute() or path.exists() else (REPOSITORY / path).resolve()


def detector_path(config: Config, workspace: Workspace | None) -> Path | None:
    """``evaluate.detector``: the detector whose box starts the self crop, located as
    ``evaluate.models``; ``auto``: this workspace's (train-reference), else the shipped one
    for the built-in Tango; ``search`` (or none to be found): None, the model's own search."""
    text = config.evaluate.detector
    if text in ("search", ""):
        return None
    if text != "auto":
        return _located(text)
    trained = None if workspace is None else workspace.resolve(workspace.model_relpath(DETECTOR_NAME))
    if trained is not None and trained.is_file():
        return trained
    shipped = REPOSITORY / SHIPPED_DETECTOR
    builtin = workspace_target(config, workspace).name == BUILTIN_TARGET
    return shipped if builtin and shipped.is_file() else None


def _default_models(config: Config, workspace: Workspace | None) -> list[str]:
    trained = [] if workspace is None else sorted(
        str(path) for path in workspace.resolve(MODELS_DIR).glob("*.onnx")
        if path.is_file() and path.stem != DETECTOR_NAME)
    if trained:
        return trained
    return list(SHIPPED_MODELS) if workspace_target(config, workspace).name == BUILTIN_TARGET else []


def _no_model(config: Config, workspace: Workspace | None) -> InputError:
    where = "W" if workspace is None else workspace.location
    target = workspace_target(config, workspace).name
    # the target as the command named it: a workspace refused before its first stage saved nothing
    folder = f" --set target.path={shlex.quote(config.target.path)}" if config.target.path else ""
    return InputError(f"evaluate.models is empty and {where}/models/ holds no model: this workspace's target is "
                      f"{target!r}, and the shipped models are of {BUILTIN_TARGET!r}; train one for it (`speedplus "
                      f"train-reference -w {where}{folder}`, with this command's --profile, --config and --set: its "
                      f"models stay in {where}/models/, where evaluate finds them), or name one (evaluate --model "
                      "FILE)")


def _digest(path: Path) -> str:
    return sha256(path)[:16] if path.exists() else "missing"


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Inputs, configuration sections, outputs and members of this stage (pipeline/registry.py):
    each model is a member, known by its file's bytes, so that a model is added (or one
    redone) without redoing the others."""
    sequences = config.plan.mode == "trajectory"  # the tracking baseline: frames in order, and the orbit
    detector = detector_path(config, workspace)
    # the detector starts every model's self crop: a new one redoes them all
    extra = {"detector": "search" if detector is None else _digest(detector)}
    paths = model_paths(config, workspace)
    ours = None if workspace is None or workspace.remote is not None else workspace.resolve(MODELS_DIR).resolve()

    def trained_here(path: Path | None) -> bool:
        return ours is not None and path is not None and path.resolve().is_relative_to(ours)

    retrained = frozenset({*(p.stem for p in paths if trained_here(p)), *(("detector",) if trained_here(detector)
                                                                            else ())})
    return Resolved(("labels", "renders", "captures") + (("plan",) if sequences else ()), ("evaluate", "plan.mode"),
                    extra,
                    ("predictions", "scores", "comparisons") + (("tracks",) if sequences else ()),
                    members={path.stem: _digest(path) for path in paths},
                    member_key="evaluate.models", member_column="model", retrained=retrained)


def preflight(config: Config, workspace: Workspace | None = None) -> None:
    """Every model of ``evaluate.models`` opens and answers an input of its contract's shape;
    else an InputError naming the file and what is wrong (the runner calls this before it
    discards or writes anything)."""
    paths = model_paths(config, workspace)
    if not paths:
        raise _no_model(config, workspace)
    for path in paths:
        PoseModel(path, threads=1).check()
    detector = detector_path(config, workspace)
    if detector is not None:
        target = workspace_target(config, workspace).name
        found = Detector(detector).contract.target
        if found != target:
            raise InputError(f"{detector}: a detector of target {found!r} (its speedplus.target), but this "
                             f"workspace's target is {target!r}: name this target's (evaluate.detector), or "
                             "search (--set evaluate.detector=search)")


def _items(workspace: Workspace) -> list[dict[str, Any]]:
    """One item per image to score: the testbed capture and the twin of every label."""
    labels = sorted(read_manifest(workspace, "labels").to_pylist(), key=lambda r: r["sample_id"])
    captures = {row["sample_id"]: row["image_path"] for row in read_manifest(workspace, "captures").to_pylist()}
    twins = {row["sample_id"]: row["image_path"] for row in read_manifest(workspace, "renders").to_pylist()}
    items = []
    for label in labels:
        common = {"sample_id": label["sample_id"], "view": label["view"], "light": label["domain"],
                  "q_true": label["q_vbs2tango_true"], "t_true": label["r_Vo2To_vbs_true"], "box": label["bbox_px"]}
        if label["sample_id"] in captures:
            items.append({**common, "domain": label["domain"], "image_path": captures[label["sample_id"]]})
        if label["sample_id"] in twins:
            items.append({**common, "domain": "synthetic", "image_path": twins[label["sample_id"]]})
    return items


def _with_images(workspace: Workspace) -> Callable[[list[dict[str, Any]]], list[dict[str, Any]]]:
    """Attach each image's bytes to its item, in the driver, just before the batch is sent."""
    def prepare(batch: list[dict[str, Any]]) -> list[dict[str, Any]]:
        out = []
        for item in batch:
            path = workspace.fetch(item["image_path"])
            try:
                data = path.read_bytes()
            except OSError as error:
                raise FileError(workspace.display(path), f"missing or unreadable image ({error.strerror})") \
                    from None
            out.append({**item, "image_bytes": data})
        return out

    return prepare


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Score every (model, crop, image) missing from ``predictions``, then rewrite the
    ``scores`` summary."""
    camera = calibrated_camera(workspace)
    target = workspace_target(config, workspace)
    paths = model_paths(config, workspace)
    if not paths:
        raise _no_model(config, workspace)
    contracts = {path: PoseModel(path, threads=1).contract for path in paths}  # a bad model fails here
    for path, contract in contracts.items():
        if contract.target != target.name:
            trained = workspace.resolve(workspace.model_relpath("reference"))
            raise InputError(f"{path}: a model of target {contract.target!r} (its speedplus.target), but this "
                             f"workspace's target is {target.name!r}: train one for it (speedplus train-reference "
                             f"-w {workspace.location} --out DIR), then score it alone (--set 'evaluate.models="
                             f"[\"{trained}\"]')")
    detector = detector_path(config, workspace)
    done = read_keys(workspace, "predictions")
    images = _items(workspace)
    batch = config.evaluate.batch_size
    shown = []
    with open_sink(workspace, "predictions", config.run.part_rows) as sink:
        for path in paths:
            contract = contracts[path]
            crops = [contract.crop] + (["self"] if contract.crop == "oracle_box" and config.evaluate.self_crop else [])
            shown += [(path.stem, crop) for crop in crops]
            items = [{**item, "model": path.stem, "crop": crop} for crop in crops for item in images
                     if f"{path.stem}:{crop}:{item['domain']}:{item['sample_id']}" not in done]
            # fixed batches (in label order): a batch's outputs do not depend on the engine or the workers
            batches = [items[i:i + batch] for i in range(0, len(items), batch)]
            threads = config.evaluate.threads or -threads_per_worker(config.run.workers)
            decoding = Decoding(config.evaluate.ransac_fraction, config.evaluate.turns, config.evaluate.ransac_seed,
                                config.evaluate.ransac_seeds)
            args = (path.read_bytes(), str(path), threads, camera.camera_matrix, camera.dist, decoding,
                    None if detector is None else detector.read_bytes())
            results = map_config(config, open_scorer, args, "score", batches, renders=False,
                                 prepare=_with_images(workspace))
            for rows in track(results, len(batches), f"evaluate {path.name} (batches of {batch}, "
                                                     f"{config.run.engine})", rows=[len(b) for b in batches]):
                for row in rows:
                    sink.add(row)
    predictions = read_manifest(workspace, "predictions")
    table = summarise(predictions.to_pylist(), target.view_names)
    clear_manifest(workspace, "scores")  # a summary of all predictions: rewritten whole
    write_part(workspace, "scores", table, workspace.output_fingerprint("scores"))
    scored = sorted(set(zip(table.column("model").to_pylist(), table.column("crop").to_pylist(), strict=True)))
    shown += [pair for pair in scored if pair not in shown]  # every model scored here, also earlier ones
    models = list(dict.fromkeys(model for model, _ in shown))
    compared = compare(predictions.to_pylist(), target.view_names, models)
    clear_manifest(workspace, "comparisons")  # like scores, a summary of all predictions
    write_part(workspace, "comparisons", compared, workspace.output_fingerprint("comparisons"))
    for model, crop in shown:  # results: standard output
        Console().print(print_table2(table, model, crop))
    for model, crop in shown:
        if model != reference_model(models):
            Console().print(print_comparison(compared, model, crop))
    if config.plan.mode == "trajectory":
        tracked = tracks(config, workspace, predictions.to_pylist())
        clear_manifest(workspace, "tracks")  # like scores, a summary of all predictions
        write_part(workspace, "tracks", tracked, workspace.output_fingerprint("tracks"))
        for shown in tracking_tables(tracked):
            Console().print(shown)
    return predictions
