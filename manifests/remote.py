"""Workspaces on object storage (docs/architecture.md section 4): ``s3://bucket/prefix`` or
``gs://bucket/prefix``, through ``pyarrow.fs``.

Stages work in a local *working copy* (``$SPEEDPLUS_WORKSPACE_CACHE``, else
``~/.cache/speedplus/workspaces/``) with the atomic local writes of any workspace; the store
is the record, and the working copy a cache of it:

- **pull**, when a command starts: configuration, sidecars, manifests, markers, models and
  the report come down where the store changed; images, renders and truth maps
  (``ON_DEMAND``) only when a stage reads one (``fetch``).
- **push**, when a stage completes and when a command ends (an error and Ctrl-C included):
  markers that changed are deleted first, files and parts uploaded, markers last, so a reader
  of the store sees a marker only once everything it records is there; what the working copy
  deleted after syncing it (an old part, a cleared manifest) is deleted from the store.
- **workers write directly** (``Remote.put``): a Ray worker uploads its images itself and
  returns their size and SHA-256; the driver checks every object's size before it records the
  row (``RemoteCopy.accept``) and the completion marker keeps size and hash.
- **one writer**: a lease object ``W/.lock`` (``lease.py``) beside the working copy's flock.

The sync state is ``W/.remote.json`` in the working copy (``INDEX_VERSION``): what was last
transferred, with the store's modification time then, and which objects the store holds that
the copy does not. A local file changed since its last transfer while the store's object did
not is unpushed work (a killed command) and is kept; otherwise the store wins.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from manifests.files import write_bytes_atomic, write_json_atomic
from manifests.store import StoredFile
from manifests.workspace import CONFIG_FILE, STATE_DIR, PathEscapeError, check_relative
from speedplus.errors import InputError

SCHEMES = ("s3", "gs", "gcs")
CACHE_ENV = "SPEEDPLUS_WORKSPACE_CACHE"
INDEX_FILE = ".remote.json"
INDEX_VERSION = 1
#: folders of large media, fetched only when read (their JSON files come with every pull)
ON_DEMAND = ("images/", "renders/", "truth/")
#: uploads and downloads in flight at once
TRANSFERS = 8


class StorageError(InputError):
    """The object store cannot be reached or refuses an operation (exit code 1)."""


def is_remote(location: str | os.PathLike) -> bool:
    """Whether a ``--workspace`` names an object store (``scheme://...``, not ``file://``)."""
    text = str(location)
    return "://" in text and not text.startswith("file://")


def _on_demand(relpath: str) -> bool:
    return relpath.startswith(ON_DEMAND) and not relpath.endswith(".json")


def _is_marker(relpath: str) -> bool:
    return relpath.startswith(f"manifests/{STATE_DIR}/") and relpath.count("/") == 2 and relpath.endswith(".json")


def _syncs(relpath: str) -> bool:
    """Whether a working-copy path belongs in the store: not the lock, the index, staging
    parts, temporaries or compaction folders (every such name starts with a dot)."""
    return not any(part.startswith(".") for part in relpath.split("/")) and not relpath.startswith(
        f"manifests/{STATE_DIR}/staging/")


_FILESYSTEMS: dict[str, tuple[Any, str]] = {}


@dataclass(frozen=True)
class Remote:
    """The store location of a workspace; pickles as its URI (workers connect themselves,
    with their node's credentials)."""

    uri: str

    def __post_init__(self) -> None:
        scheme = urlsplit(self.uri).scheme
        if scheme not in SCHEMES:
            raise StorageError(f"--workspace {self.display()}: unsupported storage {scheme!r}; use a local path, "
                               f"s3://bucket/prefix or gs://bucket/prefix")
        if not urlsplit(self.uri).path.strip("/"):
            raise StorageError(f"--workspace {self.display()}: name a prefix inside the bucket "
                               "(s3://bucket/prefix), not the bucket itself")

    def display(self) -> str:
        """The URI without credentials or query (for messages and the working copy's name)."""
        parts = urlsplit(self.uri)
        return urlunsplit((parts.scheme, parts.hostname or "", parts.path.rstrip("/"), "", ""))

    def filesystem(self) -> tuple[Any, str]:
        """(``pyarrow.fs.FileSystem``, base path), connected once per process."""
        if self.uri not in _FILESYSTEMS:
            from pyarrow import fs

            try:
                filesystem, base = fs.FileSystem.from_uri(self.uri)
            except (OSError, ValueError) as error:
                raise StorageError(f"--workspace {self.display()}: {' '.join(str(error).split())[:300]}") from None
            _FILESYSTEMS[self.uri] = (filesystem, base.rstrip("/"))
        return _FILESYSTEMS[self.uri]

    def key(self, relpath: str) -> str:
        return f"{self.filesystem()[1]}/{check_relative(relpath)}"

    def _fail(self, action: str, relpath: str, error: Exception) -> StorageError:
        return StorageError(f"{self.display()}/{relpath}: cannot {action} ({' '.join(str(error).split())[:300]})")

    def listing(self) -> dict[str, tuple[int, int]]:
        """Every object under the prefix: relative path -> (size [bytes], modified [ns]).
        A key that would leave the workspace is refused, naming it."""
        from pyarrow import fs

        filesystem, base = self.filesystem()
        try:
            infos = filesystem.get_file_info(fs.FileSelector(base, recursive=True, allow_not_found=True))
        except OSError as error:
            raise self._fail("list", "", error) from None
        out = {}
        for info in infos:
            if info.type == fs.FileType.File:
                relpath = info.path[len(base) + 1:]
                try:
                    check_relative(relpath)
                except PathEscapeError:
                    raise StorageError(f"{self.display()}: object {relpath!r} has a key that leaves the workspace; "
                                       "remove it from the store") from None
                out[relpath] = (info.size, info.mtime_ns or 0)
        return out

    def info(self, relpath: str) -> tuple[int, int] | None:
        """(size [bytes], modified [ns]) of one object, or None when it does not exist."""
        from pyarrow import fs

        filesystem, _ = self.filesystem()
        try:
            info = filesystem.get_file_info(self.key(relpath))
        except OSError as error:
            raise self._fail("read", relpath, error) from None
        return (info.size, info.mtime_ns or 0) if info.type == fs.FileType.File else None

    def read(self, relpath: str) -> bytes | None:
        """An object's bytes, or None when it does not exist."""
        if self.info(relpath) is None:
            return None
        filesystem, _ = self.filesystem()
        try:
            with filesystem.open_input_stream(self.key(relpath)) as stream:
                return stream.read()
        except OSError as error:
            raise self._fail("read", relpath, error) from None

    def put(self, relpath: str, data: bytes) -> StoredFile:
        """Upload ``data`` as one object (a reader sees all of it or nothing)."""
        filesystem, _ = self.filesystem()
        try:
            with filesystem.open_output_stream(self.key(relpath)) as stream:
                stream.write(data)
        except OSError as error:
            raise self._fail("write", relpath, error) from None
        return StoredFile(len(data), hashlib.sha256(data).hexdigest())

    def delete(self, relpath: str) -> None:
        filesystem, _ = self.filesystem()
        try:
            filesystem.delete_file(self.key(relpath))
        except FileNotFoundError:
            pass
        except OSError as error:
            raise self._fail("delete", relpath, error) from None


def working_copy_for(remote: Remote) -> Path:
    """Where this machine keeps its working copy of ``remote``: a folder per store location."""
    base = Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "speedplus" / "workspaces")
    readable = re.sub(r"[^A-Za-z0-9._-]+", "_", remote.display().split("://", 1)[1]).strip("_")[-60:]
    return base / f"{readable}-{hashlib.sha256(remote.display().encode()).hexdigest()[:10]}"


class RemoteCopy:
    """A working copy at ``root`` of the workspace stored at ``remote``; see the module docstring."""

    def __init__(self, remote: Remote, root: Path) -> None:
        self.remote, self.root = remote, root
        self.index_path = root / INDEX_FILE
        self.synced: dict[str, list[int]] = {}  # relpath -> [size, local mtime_ns, store mtime_ns]
        self.stored: dict[str, dict[str, Any]] = {}  # relpath -> {"bytes", "sha256" or None}: in the store only
        self._load_index()

    # -------------------------------------------------------------------------- the index
    def _load_index(self) -> None:
        if not self.index_path.exists():
            return
        where = str(self.index_path)
        try:
            payload = json.loads(self.index_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise StorageError(f"{where}: not valid JSON ({error}); delete the working copy {self.root}") from None
        if not isinstance(payload, dict) or payload.get("version") != INDEX_VERSION:
            raise StorageError(f"{where}: key version: expected {INDEX_VERSION}; delete the working copy {self.root}")
        for key in ("synced", "stored"):
            if not isinstance(payload.get(key), dict):
                raise StorageError(f"{where}: key {key}: expected an object; delete the working copy {self.root}")
        if payload.get("uri") != self.remote.display():
            raise StorageError(f"{where}: key uri: this working copy belongs to {payload.get('uri')!r}, "
                               f"not {self.remote.display()!r}")
        self.synced, self.stored = payload["synced"], payload["stored"]

    def _save_index(self) -> None:
        write_json_atomic(self.index_path, {"version": INDEX_VERSION, "uri": self.remote.display(),
                                            "synced": dict(sorted(self.synced.items())),
                                            "stored": dict(sorted(self.stored.items()))})

    def _local_state(self, relpath: str) -> list[int] | None:
        try:
            stat = (self.root / relpath).stat()
        except FileNotFoundError:
            return None
        return [stat.st_size, stat.st_mtime_ns]

    # -------------------------------------------------------------------------- transfers
    def _download(self, relpath: str, mtime_ns: int) -> None:
        data = self.remote.read(relpath)
        if data is None:
            raise StorageError(f"{self.remote.display()}/{relpath}: vanished while it was being fetched")
        path = self.root / check_relative(relpath)
        write_bytes_atomic(path, data)
        self.synced[relpath] = [*self._local_state(relpath), mtime_ns]
        self.stored.pop(relpath, None)

    def pull(self) -> None:
        """Bring the working copy up to the store (media stay in the store until read)."""
        self.root.mkdir(parents=True, exist_ok=True)
        listing = self.remote.listing()
        downloads = []
        for relpath, (size, mtime) in listing.items():
            if not _syncs(relpath):
                continue
            entry, local = self.synced.get(relpath), self._local_state(relpath)
            media = _on_demand(relpath)
            if entry is not None and entry[2] == mtime and (local is not None or not media):
                continue  # in sync, or changed here only (unpushed work of an interrupted command)
            if media:
                (self.root / relpath).unlink(missing_ok=True)  # an older copy, if any
                self.synced.pop(relpath, None)
                self.stored[relpath] = {"bytes": size, "sha256": None}
            else:
                downloads.append((relpath, mtime))
        for relpath in [r for r in self.synced if r not in listing]:  # deleted in the store by its writer
            (self.root / relpath).unlink(missing_ok=True)
            self.synced.pop(relpath)
        for relpath in [r for r in self.stored if r not in listing]:
            self.stored.pop(relpath)
        self._transfer(self._download, downloads)
        self._save_index()

    def fetch(self, relpath: str) -> Path:
        """The local path of a workspace file, downloaded first when only the store has it."""
        path = self.root / check_relative(relpath)
        if not path.is_file() and relpath in self.stored:
            info = self.remote.info(relpath)
            if info is not None:
                self._download(relpath, info[1])
                self._save_index()
        return path

    def has(self, relpath: str) -> bool:
        return (self.root / check_relative(relpath)).is_file() or relpath in self.stored

    def location(self) -> str:
        return self.remote.display()

    def saved_config(self) -> bytes | None:
        """The store's ``config.toml`` (not what this machine last saw), or None."""
        return self.remote.read(CONFIG_FILE)

    def started(self) -> bool:
        return self.saved_config() is not None

    def record(self, relpath: str) -> dict[str, Any] | None:
        """Size and SHA-256 of a file only the store holds (None when unknown or held here)."""
        entry = self.stored.get(relpath)
        if not entry or not entry.get("sha256") or (self.root / check_relative(relpath)).is_file():
            return None  # written here since: the local file is the one to hash
        return entry

    def accept(self, relpath: str, stored: StoredFile) -> None:
        """Record a file a worker uploaded, after checking the store holds that many bytes."""
        info = self.remote.info(relpath)
        size = None if info is None else info[0]
        if size != stored.size:
            found = "no such object" if size is None else f"{size} bytes"
            raise StorageError(f"{self.remote.display()}/{relpath}: the worker wrote {stored.size} bytes, the store "
                               f"holds {found}; rerun the stage to redo it")
        (self.root / check_relative(relpath)).unlink(missing_ok=True)  # an older local copy
        self.synced.pop(relpath, None)
        self.stored[relpath] = {"bytes": stored.size, "sha256": stored.sha256}

    def _upload(self, relpath: str, _: int = 0) -> None:
        path = self.root / relpath
        state = self._local_state(relpath)
        self.remote.put(relpath, path.read_bytes())
        self.synced[relpath] = [*state, 0]  # the store's time is read back after the batch

    def push(self) -> None:
        """Bring the store up to the working copy: changed markers deleted, files uploaded,
        markers last; what was synced and is gone here is deleted there."""
        local = {}
        for path in self.root.rglob("*"):
            relpath = path.relative_to(self.root).as_posix()
            if path.is_file() and _syncs(relpath):
                local[relpath] = self._local_state(relpath)
        changed = [r for r, state in sorted(local.items())
                   if self.synced.get(r, [None, None])[:2] != state]
        # a medium deleted here is a dropped cache copy; anything else was deleted by this writer
        gone = [r for r in self.synced if r not in local and not _on_demand(r)]
        for relpath in [r for r in [*gone, *changed] if _is_marker(r)]:
            self.remote.delete(relpath)
            self.synced.pop(relpath, None)
        self._transfer(self._upload, [(r, 0) for r in changed if not _is_marker(r)])
        self._transfer(self._upload, [(r, 0) for r in changed if _is_marker(r)])
        for relpath in gone:
            if not _is_marker(relpath):
                self.remote.delete(relpath)
                self.synced.pop(relpath, None)
        if changed:
            listing = self.remote.listing()
            for relpath in changed:
                if relpath in listing:
                    self.synced[relpath][2] = listing[relpath][1]
        self._save_index()

    def _transfer(self, action: Any, work: Iterable[tuple[str, int]]) -> None:
        work = list(work)
        if not work:
            return
        with ThreadPoolExecutor(TRANSFERS) as pool:
            for future in [pool.submit(action, relpath, mtime) for relpath, mtime in work]:
                future.result()

