"""A command's undo record (docs/architecture.md section 4): the workspace's record as it
was before a command changed it, so that a refused or failed command leaves
``W/config.toml``, every manifest, every completion marker, every JSON file and every file
a marker names (images, masks, models) byte for byte as it found them.

```
W/.snapshot/manifests/...     the manifests folder (parts hard-linked, markers copied)
W/.snapshot/files/<relpath>   config.toml, the JSON files, report/, and each file a marker names
W/.snapshot/present.json      the files the record globs cover that existed
W/.snapshot/tree.json         every file and folder of the workspace that existed: what the
                              command made besides (images of a failed stage) goes on restore
```

Parts and media are hard links: every writer replaces files by rename (``manifests.files``),
never in place, so a link keeps the old bytes at no cost. Small text files are copied. The
folder's name starts with a dot: a workspace on object storage never syncs it.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from manifests.io import DIAGNOSTICS_FILE, mark_diagnostics
from manifests.lock import LOCK_FILE
from manifests.workspace import (
    CONFIG_FILE,
    MANIFESTS_DIR,
    SNAPSHOT_DIR,
    STATE_DIR,
    TARGET_DIR,
    PathEscapeError,
    Workspace,
    check_relative,
)

#: files a command may write beside the manifests (the typed JSON files, the report, the
#: target folder plan copies in, calibrate's URDFs)
RECORD_GLOBS = (CONFIG_FILE, "*.json", "report/**/*", f"{TARGET_DIR}/**/*", "robots/*.urdf")


def _recorded_files(workspace: Workspace) -> set[str]:
    """Workspace-relative paths of the files the completion markers name (a path that would
    leave the workspace is no file of it: never linked, never written back)."""
    state = workspace.root / MANIFESTS_DIR / STATE_DIR
    names: set[str] = set()
    for marker in state.glob("*.json"):
        try:
            recorded = json.loads(marker.read_text()).get("files", {})
        except (OSError, ValueError, AttributeError):
            continue  # a damaged marker: `status` and `verify` report it
        for relpath in recorded if isinstance(recorded, dict) else ():
            try:
                names.add(check_relative(relpath).as_posix())
            except (PathEscapeError, TypeError):
                continue
    return names


def _move_back(saved: Path, target_root: Path) -> None:
    """Every file under ``saved`` to the same relative path under ``target_root``."""
    if not saved.is_dir():
        return
    for path in sorted(saved.rglob("*")):
        if path.is_file():
            target = target_root / path.relative_to(saved)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(path, target)


def _keep(source: Path, destination: Path) -> None:
    destination.parent.mkdir(parents=True, exist_ok=True)
    if source.suffix in (".json", ".toml", ".html"):
        shutil.copy2(source, destination)
    else:
        try:
            os.link(source, destination)
        except OSError:  # another filesystem, or links refused: a copy keeps the bytes too
            shutil.copy2(source, destination)


def _tree(root: Path) -> dict[str, list[str]]:
    """The workspace's files and folders (relative paths), the snapshot and the lock aside."""
    files, folders = [], []
    for path in root.rglob("*"):
        relpath = path.relative_to(root)
        if relpath.parts[0] in (SNAPSHOT_DIR, LOCK_FILE):
            continue
        (folders if path.is_dir() else files).append(relpath.as_posix())
    return {"files": sorted(files), "folders": sorted(folders)}


def _remove_new(root: Path, before: dict[str, list[str]], kept: set[str]) -> None:
    """Remove what was made since ``before`` (``_tree``): files, then the folders left empty;
    the manifests of ``kept`` stay."""
    files, folders = set(before["files"]), set(before["folders"])
    now = _tree(root)
    keep = tuple(f"{MANIFESTS_DIR}/{name}/" for name in kept)
    for relpath in now["files"]:
        if relpath not in files and not relpath.startswith(keep):
            (root / relpath).unlink(missing_ok=True)
    for relpath in sorted(now["folders"], key=lambda r: -r.count("/")):  # deepest first
        path = root / relpath
        if relpath not in folders and not f"{relpath}/".startswith(keep) and not any(path.iterdir()):
            path.rmdir()


class Snapshot:
    """The record of ``workspace`` taken by ``take``; ``restore`` puts it back, ``drop``
    forgets it. Only one command holds the workspace (``manifests.lock``), so one snapshot."""

    def __init__(self, workspace: Workspace) -> None:
        self.workspace = workspace
        self.folder = workspace.root / SNAPSHOT_DIR

    def take(self) -> Snapshot:
        """Record the manifests, the markers, the top-level files and every file a marker names."""
        root = self.workspace.root
        shutil.rmtree(self.folder, ignore_errors=True)  # a previous command's, killed before it ended
        self.folder.mkdir(parents=True)
        manifests = root / MANIFESTS_DIR
        if manifests.is_dir():
            for path in manifests.rglob("*"):
                if path.is_file() and "staging" not in path.relative_to(manifests).parts:
                    _keep(path, self.folder / MANIFESTS_DIR / path.relative_to(manifests))
        present = {p.relative_to(root).as_posix() for pattern in RECORD_GLOBS for p in root.glob(pattern)
                   if p.is_file()}
        for relpath in sorted(present | _recorded_files(self.workspace)):
            path = root / relpath
            if path.is_file() and not relpath.startswith(SNAPSHOT_DIR):
                _keep(path, self.folder / "files" / relpath)
        (self.folder / "present.json").write_text(json.dumps(sorted(present)))
        (self.folder / "tree.json").write_text(json.dumps(_tree(root)))
        return self

    def restore(self, keep_new: tuple[str, ...] = ()) -> set[str]:
        """The workspace as ``take`` found it: its record put back, and every file and folder
        made since removed (a failed stage's images, a new folder of the report).
        ``keep_new``: manifests to leave as they are now where the snapshot had none of
        them, or only an earlier refusal's (a refusal's diagnostics: no results are replaced
        by them). Returns the manifests so kept."""
        root = self.workspace.root
        saved = self.folder / MANIFESTS_DIR
        # the last refusal's diagnostics give way to this one's; results are never replaced
        kept = {name for name in keep_new if not (saved / name).is_dir() or (saved / name / DIAGNOSTICS_FILE).is_file()}
        before = set(json.loads((self.folder / "present.json").read_text()))
        for pattern in RECORD_GLOBS:
            for path in root.glob(pattern):
                relpath = path.relative_to(root).as_posix()
                if path.is_file() and relpath not in before:
                    path.unlink()
        target = root / TARGET_DIR
        if target.is_dir() and not any(p.is_file() for p in target.rglob("*")) and not any(
                name.startswith(f"{TARGET_DIR}/") for name in before):
            shutil.rmtree(target)  # a folder the command made (a target copied in) goes with its files
        manifests = root / MANIFESTS_DIR
        if manifests.is_dir():
            for path in sorted(manifests.iterdir()):
                if path.name != STATE_DIR and path.name not in kept:
                    if path.is_dir():
                        shutil.rmtree(path)
                    else:
                        path.unlink()
            for path in (manifests / STATE_DIR).glob("*.json"):
                path.unlink()
        _move_back(saved, manifests)
        _move_back(self.folder / "files", root)
        _remove_new(root, json.loads((self.folder / "tree.json").read_text()), kept)
        for name in kept:
            mark_diagnostics(self.workspace, name)
        self.drop()
        return kept

    def drop(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
