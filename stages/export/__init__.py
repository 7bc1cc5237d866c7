"""The export stage: the labelled testbed images, their synthetic twins and the training set
as a SPEED+ dataset (the Stanford devkits; ``stages.export.speedplus``) or a BOP dataset
(bop_toolkit; ``stages.export.bop``), in ``export.out`` (default ``W/export``).

Every image written is a row of the ``export_<format>`` manifest (key ``<set>/<sample_id>``),
so an interrupted export resumes with the images it lacks; the annotation files are
written last, from every item.
"""

from __future__ import annotations

import json
from pathlib import Path, PurePosixPath
from typing import Any

import pyarrow as pa

from manifests import Workspace, open_sink, read_keys, read_manifest
from manifests.files import copy_atomic, write_json_atomic
from manifests.schema import DOMAINS
from manifests.workspace import PathEscapeError, check_relative
from pipeline.config import Config
from pipeline.errors import InputError
from pipeline.progress import track
from stages.common.cameras import train_camera
from stages.common.lens import LensCamera
from stages.common.sidecars import calibrated_camera
from stages.common.workspace_target import workspace_target
from stages.export import bop, speedplus

#: in the export folder: whose export it is (the devkits and bop_toolkit ignore hidden files);
#: {"version": EXPORT_MARK_VERSION, "workspace": W, "format": ...}, compared whole
EXPORT_MARK = ".speedplus-export.json"
EXPORT_MARK_VERSION = 1


def resolve(config: Config, workspace: Workspace | None = None) -> tuple[tuple[str, ...], tuple[str, ...],
                                                                     dict[str, Any], tuple[str, ...]]:
    """(inputs, configuration sections, extra fingerprint content, outputs) of this stage
    (pipeline/registry.py): one manifest per format, so both exports can coexist."""
    inputs = {"testbed": ("labels", "captures"), "twins": ("labels", "renders"), "train": ("train",)}
    needed = tuple(dict.fromkeys(name for chosen in config.export.sets for name in inputs[chosen]))
    # of the render section, only what sizes the training camera matters here
    extra = {"train_resolution_scale": config.render.train_resolution_scale} if "train" in config.export.sets else {}
    return needed, ("export", "camera"), extra, (f"export_{config.export.format}",)


def out_dir(config: Config, workspace: Workspace) -> Path:
    return Path(config.export.out).resolve() if config.export.out else workspace.root / "export"


def inside_export(file: str, item: dict[str, Any]) -> PurePosixPath:
    """``file`` (from the labels' filename) as a path that stays inside the export folder."""
    try:
        return check_relative(file)
    except PathEscapeError:
        raise InputError(f"labels: sample {item['sample_id']}: filename {item['filename']!r} would leave the "
                         "export folder; relabel with a plain label.filename_template") from None


def claim(out: Path, workspace: Workspace, export_format: str) -> None:
    """Make ``out`` this workspace's export folder: it must be empty, or an export of this
    workspace in this format (a resumed or repeated export), or ``--force`` was given."""
    mark = out / EXPORT_MARK
    ours = {"version": EXPORT_MARK_VERSION, "workspace": workspace.location, "format": export_format}
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: export.out is a file, not a folder")
    if out.is_dir() and any(out.iterdir()) and not workspace.forced:
        try:
            theirs = json.loads(mark.read_text())
        except (OSError, ValueError):
            theirs = None
        if theirs != ours:
            raise InputError(f"{out}: not empty and not a {export_format} export of {workspace.location}; choose an "
                             "empty folder, or rerun with --force to write into it anyway")
    write_json_atomic(mark, ours)


def items(config: Config, workspace: Workspace) -> list[dict[str, Any]]:
    """Every image to export, in export_id order: export_id, sample_id, set, domain,
    filename, source (W-relative), the pose (q_vbs2tango_true, r_Vo2To_vbs_true, full
    scale) and, for BOP, scene_id and im_id."""
    out: list[dict[str, Any]] = []
    labels = sorted(read_manifest(workspace, "labels").to_pylist(), key=lambda r: r["sample_id"]) \
        if {"testbed", "twins"} & set(config.export.sets) else []
    sources: dict[str, dict[str, str]] = {}
    if "testbed" in config.export.sets:
        sources["testbed"] = {r["sample_id"]: r["image_path"] for r in read_manifest(workspace, "captures").to_pylist()}
    if "twins" in config.export.sets:
        sources["twins"] = {r["sample_id"]: r["image_path"] for r in read_manifest(workspace, "renders").to_pylist()}
    for export_set in ("testbed", "twins"):
        if export_set not in sources:
            continue
        index = dict.fromkeys(DOMAINS, 0)
        for label in labels:
            source = sources[export_set].get(label["sample_id"])
            if source is None and export_set == "testbed":
                raise InputError(f"labels: sample {label['sample_id']} has no row in the captures manifest")
            if source is None:  # a twin that could not be rendered (render's rejected.json says why)
                continue
            scene_id, im_id = bop.place(export_set, label["domain"], index[label["domain"]])
            index[label["domain"]] += 1
            out.append({"set": export_set, "sample_id": label["sample_id"], "domain": label["domain"],
                        "filename": label["filename"], "source": source, "scene_id": scene_id, "im_id": im_id,
                        "q_vbs2tango_true": label["q_vbs2tango_true"], "r_Vo2To_vbs_true": label["r_Vo2To_vbs_true"]})
    if "train" in config.export.sets:
        train = sorted(read_manifest(workspace, "train").to_pylist(), key=lambda r: r["sample_id"])
        for index, row in enumerate(train):
            scene_id, im_id = bop.place("train", "synthetic", index)
            out.append({"set": "train", "sample_id": row["sample_id"], "domain": "synthetic",
                        "filename": f"{row['sample_id']}.png", "source": row["image_path"], "scene_id": scene_id,
                        "im_id": im_id, "q_vbs2tango_true": row["q_vbs2tango_true"],
                        "r_Vo2To_vbs_true": row["r_Vo2To_vbs_true"]})
    for item in out:
        item["export_id"] = f"{item['set']}/{item['sample_id']}"
    return sorted(out, key=lambda item: item["export_id"])


def cameras(config: Config, workspace: Workspace) -> dict[str, LensCamera]:
    """The camera of each exported set: the calibrated one for the testbed and the twins
    (render draws them with it), the training camera for the training set."""
    out = {}
    if {"testbed", "twins"} & set(config.export.sets):
        out["testbed"] = out["twins"] = calibrated_camera(workspace)
    if "train" in config.export.sets:
        out["train"] = train_camera(config)
    return out


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Write every item missing from the manifest, then the annotation files."""
    out, name = out_dir(config, workspace), f"export_{config.export.format}"
    claim(out, workspace, config.export.format)
    chosen, by_set = items(config, workspace), cameras(config, workspace)
    if config.export.format == "speedplus" and "train" in by_set:
        speedplus.check_one_camera(by_set["testbed"] if "testbed" in by_set else by_set["train"], by_set["train"])
    done = read_keys(workspace, name)
    todo = [item for item in chosen if item["export_id"] not in done]
    target = workspace_target(config, workspace)
    surfaces = bop.TargetSurfaces(target.parts) if config.export.format == "bop" and todo else None
    with open_sink(workspace, name, config.run.part_rows) as sink:
        for item in track(todo, len(todo), "export"):
            source = workspace.fetch(item["source"])
            if config.export.format == "speedplus":
                file = speedplus.image_file(item["set"], item["domain"], item["filename"])
                copy_atomic(source, out / inside_export(file, item))
            else:
                file = bop.write_image(out, item, source, by_set[item["set"]], surfaces)
            sink.add({"export_id": item["export_id"], "sample_id": item["sample_id"], "set": item["set"],
                      "domain": item["domain"], "file": file, "source_image": item["source"]})
    if config.export.format == "speedplus":
        labels_camera = by_set.get("testbed") or by_set["train"]
        pitch = config.camera.pixel_pitch_m * config.camera.reference_width_px / labels_camera.width
        counts = speedplus.write_annotations(out, chosen, speedplus.camera_json(labels_camera, pitch),
                                             config.export.validation_fraction)
        speedplus.write_keypoints(out, target.name, target.keypoints_m)
    else:
        counts = bop.write_annotations(out, chosen, by_set, target)
    print(f"export: {', '.join(f'{v} in {k}' for k, v in counts.items())} ({config.export.format}) in {out}")
    return read_manifest(workspace, name)
