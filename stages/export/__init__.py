"""The export stage: the labels and their testbed images as a SPEED+ dataset (the Stanford
devkits) or BOP scenes (bop_toolkit), in ``export.out`` (default ``W/export``).

Every image copied is a row of the ``export_<format>`` manifest, so an interrupted export
resumes with the images it lacks; the annotation files are written last, from every label.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath
from typing import Any

import pyarrow as pa

from manifests import Workspace, open_sink, read_keys, read_manifest
from manifests.workspace import PathEscapeError, check_relative
from pipeline.config import Config
from pipeline.errors import InputError
from pipeline.progress import track
from stages.common.sidecars import calibrated_camera
from stages.export import formats


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


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Copy every label's image missing from the manifest, then write the annotation files."""
    out, name = out_dir(config, workspace), f"export_{config.export.format}"
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
