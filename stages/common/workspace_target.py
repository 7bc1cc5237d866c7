"""Which target a stage builds: the folder the configuration names (``target.path``; the
built-in Tango when empty) until ``plan`` copies it into ``W/target/``, then that copy
(docs/architecture.md section 7). Every stage after the plan reads the copy, so a target
folder the lab edits or moves later cannot change a workspace behind its fingerprints."""

from __future__ import annotations

import hashlib
import os
import pickle
import shutil
from functools import lru_cache
from pathlib import Path

from core.config import Config
from manifests import Workspace
from manifests.target import TARGET_FILE, TargetError, target_digest, target_files
from manifests.workspace import TARGET_DIR
from stages.common.target import Target, load_target
from stages.common.targets import builtin_folder


def configured_folder(config: Config) -> Path:
    """The folder ``target.path`` names, or the built-in Tango's."""
    return Path(config.target.path) if config.target.path else builtin_folder()


def workspace_folder(config: Config, workspace: Workspace | None) -> Path:
    """``W/target`` once the plan has copied a target there (fetched from the store when the
    workspace lives on object storage), else (and without a workspace) the configured folder."""
    if workspace is None or not workspace.has_file(f"{TARGET_DIR}/{TARGET_FILE}"):
        return configured_folder(config)
    folder = workspace.fetch(f"{TARGET_DIR}/{TARGET_FILE}").parent
    for name in target_files(folder):
        workspace.fetch(f"{TARGET_DIR}/{name}")
    return folder


def planned_target(config: Config) -> Target:
    """The configured target (the plan's, before it is copied)."""
    return cached_target(configured_folder(config))


def workspace_target(config: Config, workspace: Workspace | None) -> Target:
    """The target of this workspace (``workspace_folder``)."""
    return cached_target(workspace_folder(config, workspace))


def cached_target(folder: Path) -> Target:
    """``load_target``, once per process for a given content, and kept in the user's cache
    between processes: reading a mesh costs a command or a worker most of a second (trimesh's
    import, the hull), unpickling a few milliseconds."""
    return _load(str(Path(folder).resolve()), target_digest(folder))


@lru_cache(maxsize=4)
def _load(folder: str, digest: str) -> Target:
    # keyed by the folder's content and by the code that derives a Target from it
    path = _cache_dir() / f"{hashlib.sha256((digest + _code_digest()).encode()).hexdigest()[:32]}.pickle"
    try:
        cached = pickle.loads(path.read_bytes())
        if isinstance(cached, Target) and cached.digest == digest:
            return cached
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError, ValueError):
        pass  # none yet, or written by other code: load the folder
    target = load_target(Path(folder))
    if target.digest == digest:  # not changed while it was read
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            temporary = path.with_name(f".{path.name}.{os.getpid()}")
            temporary.write_bytes(pickle.dumps(target))
            temporary.replace(path)
        except OSError:
            pass  # a read-only cache only costs the next process the load
    return target


def _cache_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "speedplus" / "targets"


@lru_cache(maxsize=1)
def _code_digest() -> str:
    import manifests.target as spec_module
    import stages.common.target as target_module

    return hashlib.sha256(b"".join(Path(m.__file__).read_bytes() for m in (spec_module, target_module))).hexdigest()


def install(config: Config, workspace: Workspace) -> None:
    """Copy the configured target's files into ``W/target`` (replacing another one there):
    written beside it and renamed into place, so that the folder is never half-written."""
    source = configured_folder(config)
    destination = workspace.root / TARGET_DIR
    if destination.is_dir() and (destination / TARGET_FILE).is_file() and _same(source, destination):
        return
    staging = workspace.root / f".{TARGET_DIR}.new"
    shutil.rmtree(staging, ignore_errors=True)
    for name in target_files(source):
        (staging / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source / name, staging / name)
    old = workspace.root / f".{TARGET_DIR}.old"
    shutil.rmtree(old, ignore_errors=True)
    if destination.exists():
        destination.rename(old)
    staging.rename(destination)
    shutil.rmtree(old, ignore_errors=True)


def _same(source: Path, destination: Path) -> bool:
    try:
        return target_digest(source) == target_digest(destination)
    except (TargetError, OSError):  # a damaged copy is simply replaced
        return False


def digest(config: Config, workspace: Workspace | None) -> str:
    """The digest a stage's fingerprint takes: of the workspace's target, or without a
    workspace (the plan, before it copies) of the configured one."""
    return target_digest(configured_folder(config) if workspace is None else workspace_folder(config, workspace))


#: SPEED+'s camera-to-target distances, full scale (m): the paper's 6.5-9.5 m, of Tango
SPEEDPLUS_RANGE_M = (6.5, 9.5)


def apparent_size_ratio(target: Target) -> float:
    """``target``'s diameter over the built-in Tango's: a distance range of SPEED+'s (made
    for Tango) times this shows ``target`` at the same apparent size (1.0 for Tango)."""
    return target.diameter_m / cached_target(builtin_folder()).diameter_m
