"""The export stage: the labels and their testbed images as a SPEED+ dataset (the Stanford
devkits) or BOP scenes (bop_toolkit), in ``export.out`` (default ``W/export``).

Every image copied is a row of the ``export_<format>`` manifest, so an interrupted export
resumes with the images it lacks; the annotation files are written last, from every label.
"""

from __future__ import annotations

import json
from pathlib import Path, PurePosixPath
from typing import Any

import pyarrow as pa

from manifests import Workspace, open_sink, read_keys, read_manifest
from manifests.files import write_json_atomic
from manifests.workspace import PathEscapeError, check_relative
from pipeline.config import Config
from pipeline.errors import InputError
from pipeline.progress import track
from stages.common.sidecars import calibrated_camera
from stages.export import formats

#: in the export folder: whose export it is (the devkits and bop_toolkit ignore hidden files);
#: {"version": EXPORT_MARK_VERSION, "workspace": W, "format": ...}, compared whole
EXPORT_MARK = ".speedplus-export.json"
EXPORT_MARK_VERSION = 1


def resolve(config: Config) -> tuple[tuple[str, ...], tuple[str, ...], dict[str, Any], tuple[str, ...]]:
    """(inputs, configuration sections, extra fingerprint content, outputs) of this stage
    (pipeline/registry.py): one manifest per format, so both exports can coexist."""
    return ("labels", "captures"), ("export", "camera"), {}, (f"export_{config.export.format}",)


def out_dir(config: Config, workspace: Workspace) -> Path:
    return Path(config.export.out).resolve() if config.export.out else workspace.root / "export"


def inside_export(file: str, label: dict[str, Any]) -> PurePosixPath:
    """``file`` (from the labels' filename) as a path that stays inside the export folder."""
    try:
        return check_relative(file)
    except PathEscapeError:
        raise InputError(f"labels: sample {label['sample_id']}: filename {label['filename']!r} would leave the "
                         "export folder; relabel with a plain label.filename_template") from None


def claim(out: Path, workspace: Workspace, export_format: str) -> None:
    """Make ``out`` this workspace's export folder: it must be empty, or an export of this
    workspace in this format (a resumed or repeated export), or ``--force`` was given."""
    mark = out / EXPORT_MARK
    ours = {"version": EXPORT_MARK_VERSION, "workspace": str(workspace.root), "format": export_format}
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: export.out is a file, not a folder")
    if out.is_dir() and any(out.iterdir()) and not workspace.forced:
        try:
            theirs = json.loads(mark.read_text())
        except (OSError, ValueError):
            theirs = None
        if theirs != ours:
            raise InputError(f"{out}: not empty and not a {export_format} export of {workspace.root}; choose an "
                             "empty folder, or rerun with --force to write into it anyway")
    write_json_atomic(mark, ours)


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Copy every label's image missing from the manifest, then write the annotation files."""
    out, name = out_dir(config, workspace), f"export_{config.export.format}"
    claim(out, workspace, config.export.format)
    labels = sorted(read_manifest(workspace, "labels").to_pylist(), key=lambda r: r["sample_id"])
    images = {r["sample_id"]: r["image_path"] for r in read_manifest(workspace, "captures").to_pylist()}
    camera = calibrated_camera(workspace)
    ids = formats.bop_image_ids(labels)
    done = read_keys(workspace, name)
    todo = [row for row in labels if row["sample_id"] not in done]
    with open_sink(workspace, name, config.run.part_rows) as sink:
        for row in track(todo, len(todo), "export"):
            if config.export.format == "speedplus":
                file = formats.speedplus_image(row)
            else:
                file = formats.bop_image(row, ids[row["sample_id"]])
            formats.copy_image(workspace.resolve(images[row["sample_id"]]), out / inside_export(file, row))
            sink.add({"sample_id": row["sample_id"], "domain": row["domain"], "file": file,
                      "source_image": images[row["sample_id"]]})
    if config.export.format == "speedplus":
        pitch = config.camera.pixel_pitch_m * config.camera.reference_width_px / camera.width
        counts = formats.write_speedplus(out, labels, formats.camera_json(camera.camera_matrix, camera.dist,
                                                                          camera.width, camera.height, pitch))
    else:
        counts = formats.write_bop(out, labels, camera.camera_matrix)
    print(f"export: {', '.join(f'{v} {k}' for k, v in counts.items())} labels ({config.export.format}) in {out}")
    return read_manifest(workspace, name)
