"""Where ``train-reference --out DIR`` puts the trained models (``DIR/<target>_<name>.onnx``
and its card), so that a model of one target never takes another target's file, and what
the command prints of each (its ``models`` row)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from core.config import Config
from manifests import Workspace, read_manifest, read_marker
from manifests.files import copy_atomic
from manifests.integrity import sha256
from speedplus.errors import InputError
from stages.common.workspace_target import workspace_target


def trained_names(workspace: Workspace) -> list[str]:
    """The models of the ``models`` manifest, by name."""
    return sorted(read_manifest(workspace, "models").column("model").to_pylist())


def published(workspace: Workspace, destinations: dict[str, Path]) -> list[tuple[str, Path, dict[str, Any]]]:
    """After train-reference: each trained model's name, where it now is (copied to its
    ``destinations`` entry, or the workspace's own file) and its ``models`` row."""
    out = []
    for name in trained_names(workspace):
        if name in destinations:
            out.append((name, destinations[name], publish_model(workspace, name, destinations[name])))
        else:
            out.append((name, workspace.resolve(workspace.model_relpath(name)), model_row(workspace, name)))
    return out


def publish_destinations(config: Config, workspace: Workspace, names: list[str], out_dir: Path,
                         force: bool) -> dict[str, Path]:
    """Where ``train-reference --out DIR`` copies each model: ``DIR/<target>_<name>.onnx``
    (and its card), so that a model of one target never takes another target's file. Refused
    before anything is trained when a file is there that this workspace's current model did
    not make, unless ``force``."""
    target = workspace_target(config, workspace).name
    destinations = {name: out_dir / f"{target}_{name}.onnx" for name in names}
    if force:
        return destinations
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: --out is a file, not a folder")
    ours = _current_model_digests(workspace)
    for name, destination in destinations.items():
        for file in (destination, destination.with_suffix(".json")):
            if file.exists() and (name not in ours or ours[name] != sha256_of(destination)):
                raise InputError(f"{file}: exists, and train-reference never replaces a file it did not make; "
                                 f"choose another --out, move the file, or rerun with --force to retrain and "
                                 f"replace it (the models stay in {workspace.location}/models either way)")
    return destinations


def _current_model_digests(workspace: Workspace) -> dict[str, str]:
    """model -> sha256 of this workspace's completed ``models`` manifest (none while incomplete)."""
    if read_marker(workspace, "models") is None:
        return {}
    return {row["model"]: row["sha256"] for row in read_manifest(workspace, "models").to_pylist()}


def sha256_of(path: Path) -> str | None:
    return sha256(path) if path.is_file() else None


def model_row(workspace: Workspace, name: str) -> dict[str, Any]:
    """Model ``name``'s row of the ``models`` manifest."""
    rows = {row["model"]: row for row in read_manifest(workspace, "models").to_pylist()}
    if name not in rows:
        raise InputError(f"{workspace.display(workspace.manifest_dir('models'))}: no model {name!r}; run "
                         "train-reference first")
    return rows[name]


def publish_model(workspace: Workspace, name: str, destination: Path) -> dict[str, Any]:
    """Copy model ``name`` (``W/models/<name>.onnx`` and its card) to ``destination``,
    atomically; returns its ``models`` row."""
    row = model_row(workspace, name)
    source = workspace.fetch(row["path"])
    workspace.fetch(row["path"].removesuffix(".onnx") + ".json")
    destination.parent.mkdir(parents=True, exist_ok=True)
    copy_atomic(source, destination)
    copy_atomic(source.with_suffix(".json"), destination.with_suffix(".json"))
    return row
