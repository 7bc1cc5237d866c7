"""The on-disk layout of a run (docs/architecture.md section 4), as path templates and
``LAYOUT``, the one description of the folder (docs/formats.md's "Workspace layout" is
generated from it by ``python -m manifests.reference``). Paths stored in manifests are
relative to ``W`` and may never leave it.
"""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath
from typing import Any

from manifests.store import ObjectStore, Store, StoredFile
from speedplus.errors import InputError

CONFIG_FILE = "config.toml"
SESSION_FILE = "session.json"
TRUTH_FILE = "truth.json"
CALIBRATION_FILE = "calibration.json"
FUSION_FILE = "fusion.json"
MARKERS_FILE = "markers.json"
TRAJECTORIES_FILE = "trajectories.json"
#: calibrate's URDFs of a facility's robots, their identified errors written in
ROBOT_URDF_TEMPLATE = "robots/{name}.urdf"
MANIFESTS_DIR = "manifests"
PART_TEMPLATE = "part-{index:05d}.parquet"
STATE_DIR = "_state"
#: where schema versions before 1.6 kept the completion marker: inside the data folder,
#: which polars and DuckDB refuse to read as a Parquet dataset
LEGACY_MARKER_FILE = "_SUCCESS.json"
IMAGE_TEMPLATE = "images/{session}/{sample_id}.png"
RENDER_TEMPLATE = "renders/{set}/{sample_id}.png"
MASK_TEMPLATE = "renders/{set}/masks/{sample_id}.png"
GROUND_TRUTH_TEMPLATE = "renders/{set}/ground_truth/{sample_id}.exr"
TRUTH_MAPS_TEMPLATE = "truth/{sample_id}.exr"
#: train-reference's models and their cards
MODELS_DIR = "models"
MODEL_TEMPLATE = MODELS_DIR + "/{name}.onnx"
TARGET_DIR = "target"
REPORT_DIR = "report"
REPORT_PAGE = "index.html"
EXPORT_DIR = "export"
SNAPSHOT_DIR = ".snapshot"

#: every path of a workspace (``W/`` + template) and what it holds, in the order a run makes them
LAYOUT: tuple[tuple[str, str], ...] = (
    (CONFIG_FILE, "the resolved configuration"),
    (TARGET_DIR + "/", "the target folder the plan copied (target.toml, the mesh)"),
    (f"{MANIFESTS_DIR}/<name>/{PART_TEMPLATE.format(index=0).replace('00000', 'NNNNN')}",
     "one Parquet dataset per manifest: parts only, so any Parquet reader takes the folder (polars, DuckDB)"),
    (f"{MANIFESTS_DIR}/{STATE_DIR}/<name>.json", "completion marker: fingerprint, rows, parts, files, timings"),
    (f"{MANIFESTS_DIR}/{STATE_DIR}/staging/<name>/", "parts being written (linked into <name>/ when whole)"),
    (IMAGE_TEMPLATE.format(session="{calibration,dataset}", sample_id="<sample_id>"), "testbed captures"),
    (RENDER_TEMPLATE.format(set="{twins,train}", sample_id="<sample_id>"),
     "synthetic images; their masks/<sample_id>.png and ground_truth/<sample_id>.exr beside them"),
    (TRUTH_MAPS_TEMPLATE.format(sample_id="<sample_id>"), "virtual testbed: depth and part ids at the true pose"),
    (SESSION_FILE, "the capture session: backend, pattern, camera, sources"),
    (CALIBRATION_FILE, "calibrated offsets, sigmas, Table 1"),
    (ROBOT_URDF_TEMPLATE.format(name="<robot>"), "each robot as calibrated (TRON's KR 16-2 arms too): its URDF "
     "with the identified joint offsets and frames written in (for a controller, MoveIt or a planner)"),
    (FUSION_FILE, "the session's variance factor, each axis's source, the session offset, the sigmas' notes"),
    (TRUTH_FILE, "virtual testbed only: the hidden true offsets"),
    (MARKERS_FILE, "virtual testbed only: where the motion-capture markers sat on the mock-up"),
    (TRAJECTORIES_FILE, "plan.mode = trajectory: each sequence's epoch, orbit, relative orbit, inertia and spin"),
    (MODEL_TEMPLATE.format(name="<name>") + ", .json", "train-reference: a model and its card"),
    (f"{REPORT_DIR}/{REPORT_PAGE}", "the report"),
    (EXPORT_DIR + "/<format>/", "exports (speedplus, bop, shirt) unless --out names another folder"),
    (SNAPSHOT_DIR + "/", "while a command writes: its undo record (hard links), gone when it ends"),
)


class PathEscapeError(InputError, ValueError):
    """A manifest path that is absolute or climbs out of the workspace."""


def check_relative(path: str) -> PurePosixPath:
    """The path as a workspace-relative POSIX path; raises if it could leave the workspace."""
    pure = PurePosixPath(path)
    if not path or pure.is_absolute() or "\\" in path or ".." in pure.parts:
        raise PathEscapeError(f"path {path!r} must be relative to the workspace and stay inside it")
    return pure


class LocalStore:
    """Where a workspace on this machine's file system keeps its files: where the manifests
    say, under ``root``. The same interface as ``manifests.remote.RemoteCopy`` (a working
    copy of a workspace on object storage), with nothing to fetch, pull or push: a
    ``manifests.store.Store``."""

    remote: ObjectStore | None = None

    def __init__(self, root: Path) -> None:
        self.root = root

    def location(self) -> str:
        return str(self.root)

    def fetch(self, relpath: str) -> Path:
        return self.root / check_relative(relpath)

    def has(self, relpath: str) -> bool:
        return self.fetch(relpath).is_file()

    def record(self, relpath: str) -> dict[str, Any] | None:
        return None  # every file is here: hash it

    def accept(self, relpath: str, stored: StoredFile) -> None:
        raise InputError(f"{relpath}: a worker uploaded it to object storage, but {self.root} is a local workspace")

    def started(self) -> bool:
        return (self.root / CONFIG_FILE).is_file()

    def pull(self) -> None:
        """Nothing to bring: the files are here."""

    def push(self) -> None:
        """Nothing to send: the files are here."""


class Workspace:
    """A run directory ``W``; every stage reads and writes through these paths. Its files
    live in a store (``store``): this machine's file system (``LocalStore``), or object
    storage through a local working copy at ``root`` (``manifests.remote.RemoteCopy``),
    from which ``fetch`` downloads a file on demand."""

    def __init__(self, root: str | Path, output_fingerprints: dict[str, str] | None = None,
                 forced: bool = False, copy: Store | None = None) -> None:
        self.root = Path(root).resolve()
        self._output_fingerprints = dict(output_fingerprints or {})
        #: the run was asked to redo its results (--force): a stage may then replace what it
        #: would otherwise refuse to touch (export: a folder holding other files)
        self.forced = forced
        self.store: Store = copy if copy is not None else LocalStore(self.root)

    def for_run(self, output_fingerprints: dict[str, str], forced: bool = False) -> Workspace:
        """The same workspace as a stage run sees it: writers stamp each output manifest's
        parts with its fingerprint (docs/architecture.md section 1). Made by the runner."""
        return Workspace(self.root, output_fingerprints, forced, self.store if self.remote is not None else None)

    @property
    def remote(self) -> ObjectStore | None:
        """The object store this workspace lives in (workers write there directly), or None."""
        return self.store.remote

    @property
    def location(self) -> str:
        """The workspace as the user named it: its path, or its store URI."""
        return self.store.location()

    def fetch(self, relpath: str) -> Path:
        """The local path of a manifest path, to read: fetched from the store when only it
        has the file (a missing file stays missing; readers report it)."""
        return self.store.fetch(relpath)

    def has_file(self, relpath: str) -> bool:
        """Whether the file a manifest names exists (here, or in the store)."""
        return self.store.has(relpath)

    def stored_record(self, relpath: str) -> dict[str, Any] | None:
        """``{"bytes", "sha256"}`` of a file a worker wrote straight to the store, or None."""
        return self.store.record(relpath)

    def sync(self) -> None:
        """Push the working copy to its store (after a stage completes); nothing locally."""
        self.store.push()

    def output_fingerprint(self, name: str) -> str:
        """The fingerprint the running stage stamps on manifest ``name``'s parts."""
        try:
            return self._output_fingerprints[name]
        except KeyError:
            raise RuntimeError(f"manifest {name!r} is not being written by a stage run; run stages through "
                               "pipeline.runner.run_stage") from None

    def __repr__(self) -> str:
        return f"Workspace({self.location!r})"

    @property
    def config_path(self) -> Path:
        return self.root / CONFIG_FILE

    @property
    def session_path(self) -> Path:
        """Description of the capture session (pattern, camera, sources), written by acquire."""
        return self.root / SESSION_FILE

    @property
    def calibration_path(self) -> Path:
        """Calibrated camera, offsets, sigmas and Table 1, written by calibrate."""
        return self.root / CALIBRATION_FILE

    def robot_urdf_path(self, robot: str) -> Path:
        """A facility robot's calibrated URDF, written by calibrate (``robot``: its name in
        facility.toml, [a-z0-9_-]+)."""
        return self.root / check_relative(ROBOT_URDF_TEMPLATE.format(name=robot))

    @property
    def fusion_path(self) -> Path:
        """The dataset session's variance factor, written by fuse."""
        return self.root / FUSION_FILE

    @property
    def markers_path(self) -> Path:
        """Where the virtual testbed stuck the motion-capture markers on the mock-up."""
        return self.root / MARKERS_FILE

    @property
    def trajectories_path(self) -> Path:
        """The planned rendezvous sequences' orbits and spins (plan.mode = trajectory)."""
        return self.root / TRAJECTORIES_FILE

    @property
    def truth_path(self) -> Path:
        """Hidden truth of the virtual testbed; read only by tests, benchmarks and report."""
        return self.root / TRUTH_FILE

    def manifest_dir(self, name: str) -> Path:
        return self.root / MANIFESTS_DIR / name

    def marker_path(self, name: str) -> Path:
        """Completion marker of manifest ``name``, outside its data folder."""
        return self.root / MANIFESTS_DIR / STATE_DIR / f"{name}.json"

    def legacy_marker_path(self, name: str) -> Path:
        return self.manifest_dir(name) / LEGACY_MARKER_FILE

    def staging_dir(self, name: str) -> Path:
        """Where parts of ``name`` are written before they are linked into its folder (the
        same filesystem, so the link is atomic); nothing half-written is ever in the folder."""
        return self.root / MANIFESTS_DIR / STATE_DIR / "staging" / name

    def image_relpath(self, session: str, sample_id: str) -> str:
        return IMAGE_TEMPLATE.format(session=session, sample_id=sample_id)

    def model_relpath(self, name: str) -> str:
        return MODEL_TEMPLATE.format(name=name)

    def resolve(self, relpath: str) -> Path:
        """Absolute path of a manifest path, after checking it stays inside ``W``."""
        return self.root / check_relative(relpath)

    def display(self, path: Path) -> str:
        """A path as users can paste it: relative to the current directory when it lies
        below it, else absolute (in the store: its URI)."""
        if self.remote is not None and path.is_relative_to(self.root):
            return f"{self.location}/{path.relative_to(self.root).as_posix()}"
        absolute = Path(os.path.abspath(path))
        try:
            return str(absolute.relative_to(Path.cwd()))
        except (ValueError, OSError):  # outside it, or the current directory is gone
            return str(absolute)
