"""The acquire stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

Backends (``acquire.backend``): ``virtual`` (the embedded digital twin; captures the
plan) and ``replay`` (a recorded session on disk: ``acquire.format`` ``session``,
``handeye`` or its preset ``tabb``, or a ROS 2 bag, ``rosbag``). Interrupted runs resume
with the samples missing from the manifests.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path
from typing import Any

import pyarrow as pa

from core.config import Config
from core.engines import Produced, store
from core.progress import track
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest
from manifests.facility import facility_digest
from manifests.sidecars import write_markers, write_session, write_truth
from speedplus.errors import InputError
from stages.acquire.backend import Testbed
from stages.common.dispatch import map_config
from stages.common.workspace_target import install


def open_testbed(config: Config, root: str, plan: list[dict[str, Any]] | None = None) -> Testbed:
    """The configured backend for the workspace at ``root`` (a picklable factory). The
    virtual testbed's workers get the ``plan`` rows with it: they never read the workspace."""
    workspace = Workspace(root)
    if config.acquire.backend == "virtual":
        from stages.acquire.virtual import VirtualTestbed

        return VirtualTestbed(config, workspace, plan)
    if config.acquire.format in ("handeye", "tabb"):
        from stages.acquire.handeye import HandEyeReplay, read_dataset_toml
        from stages.acquire.tabb import tabb_dataset

        source = Path(config.acquire.source)
        if config.acquire.format == "tabb":
            return HandEyeReplay(tabb_dataset(source), workspace, "tabb")
        return HandEyeReplay(read_dataset_toml(source), workspace)
    if config.acquire.format == "rosbag":
        from stages.acquire.rosbag import BagReplay

        return BagReplay(Path(config.acquire.source), workspace)
    from stages.acquire.replay import SessionReplay

    return SessionReplay(Path(config.acquire.source), workspace)


def source_digest(source: Path) -> str:
    """Identity of a recorded session: names and sizes of its files, contents of its text files."""
    digest = hashlib.sha256()
    if not source.is_dir():
        return "missing"
    for path in sorted(p for p in source.rglob("*") if p.is_file()):
        digest.update(str(path.relative_to(source)).encode())
        digest.update(str(path.stat().st_size).encode())
        if path.suffix.lower() in (".txt", ".csv", ".toml", ".json"):
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


#: a capture's PNG against its raw RGB bytes, measured on this pipeline's images (default
#: profile 960 x 600: 214 kB against 1.73 MB, 1/8; smoke 320 x 200: 29 kB against 192 kB,
#: 1/6.6): the estimate takes 1/6
PNG_SHARE = 1 / 6


def planned_bytes(config: Config, count: int) -> int:
    """What ``count`` captures of the configured camera are expected to take on disk."""
    return int(count * config.camera.width_px * config.camera.height_px * 3 * PNG_SHARE)


def preflight(config: Config, workspace: Workspace | None = None) -> None:
    """Before the chain's first stage: a virtual session's images fit on the workspace's
    disk (``planned_bytes`` of every planned capture; a workspace on object storage is not
    measured)."""
    if config.acquire.backend != "virtual" or workspace is None or workspace.remote is not None:
        return
    frames = (config.trajectory.frames * len(config.trajectory.presets) if config.plan.mode == "trajectory"
              else config.plan.n_dataset)
    try:
        count = config.plan.n_calibration + frames - len(read_keys(workspace, "captures"))
    except InputError:  # damaged: acquire says so itself, and --force captures them all anew
        count = config.plan.n_calibration + frames
    folder = next((p for p in (workspace.root, *workspace.root.parents) if p.exists()), None)
    if folder is None:
        return
    needed, free = planned_bytes(config, count), shutil.disk_usage(folder).free
    if needed > free:
        raise InputError(f"{workspace.root}: {count} captures of {config.camera.width_px} x "
                         f"{config.camera.height_px} px need about {needed / 1e9:.2f} GB (PNG, 1/6 of their raw "
                         f"bytes), and {folder} has {free / 1e9:.2f} GB free; free some, or put the workspace "
                         "elsewhere (--workspace)")


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """The virtual testbed follows the plan and draws a truth (``captures``, ``truth``) in
    TRON's room or the facility folder's (whose digest it is fingerprinted by); a replayed
    session writes ``captures`` and is fingerprinted by its folder's content."""
    if config.acquire.backend == "virtual":
        extra = {"facility": facility_digest(Path(config.facility.path))} if config.facility.path else {}
        return Resolved(("plan",), ("acquire", "virtual", "camera", "testbed", "facility.path"), extra,
                        ("captures", "truth"))
    source = Path(config.acquire.source).resolve()
    return Resolved((), ("acquire",), {"source": str(source), "source_digest": source_digest(source)}, ("captures",))


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Capture every sample missing from the manifests; returns the ``captures`` table. A
    replayed session has no plan: the configured target is copied into ``W/target`` here."""
    if config.acquire.backend != "virtual":
        install(config, workspace)
    testbed = open_testbed(config, str(workspace.root))
    samples = testbed.samples()
    write_session(workspace, testbed.session())
    with_truth = config.acquire.backend == "virtual"
    if with_truth:
        write_truth(workspace, testbed.truth_record())
        write_markers(workspace, testbed.markers_record())
    have_captures = read_keys(workspace, "captures")
    have_truth = read_keys(workspace, "truth") if with_truth else set()
    todo = [s for s in samples
            if s["sample_id"] not in have_captures or (with_truth and s["sample_id"] not in have_truth)]
    part_rows = config.run.part_rows
    if with_truth:
        records = map_config(config, open_testbed, (config, str(workspace.root), samples), "capture", todo,
                             renders=True, remote=workspace.remote)
    else:  # a replay reads its session's files where they are: no cluster needed
        records = (testbed.capture(sample) for sample in todo)
    with open_sink(workspace, "captures", part_rows) as captures:
        truth = open_sink(workspace, "truth", part_rows) if with_truth else None
        try:
            for record in track(records, len(todo), f"acquire ({config.acquire.backend})"):
                store(workspace, Produced(record, record.files))  # the image before its row
                if record.captures["sample_id"] not in have_captures:
                    captures.add(record.captures)
                if truth is not None and record.truth["sample_id"] not in have_truth:
                    truth.add(record.truth)
        finally:
            if truth is not None:
                truth.flush()
    return read_manifest(workspace, "captures")
