"""Where a workspace keeps its files, as an interface: ``Store`` (this machine's folder,
``manifests.workspace.LocalStore``, or a working copy of object storage,
``manifests.remote.RemoteCopy``) and ``ObjectStore`` (the object-storage location itself,
``manifests.remote.Remote``). ``Workspace`` is written against these protocols, so it
imports neither implementation and ``manifests.remote`` may import the workspace's paths
(docs/architecture.md section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol


@dataclass(frozen=True)
class StoredFile:
    """A file a worker wrote to the store itself: its size [bytes] and SHA-256 (hex)."""

    size: int
    sha256: str


class ObjectStore(Protocol):
    """An object-storage location of a workspace (``s3://bucket/prefix``, ``gs://...``);
    relpaths are workspace-relative POSIX paths."""

    uri: str

    def display(self) -> str:
        """The location as the user named it (credentials left out)."""
        ...

    def listing(self) -> dict[str, tuple[int, int]]:
        """relpath -> (size [bytes], modification time [ns]) of every object under the prefix."""
        ...

    def info(self, relpath: str) -> tuple[int, int] | None:
        """(size, modification time [ns]) of one object, or None."""
        ...

    def read(self, relpath: str) -> bytes | None:
        """An object's bytes, or None."""
        ...

    def put(self, relpath: str, data: bytes) -> StoredFile:
        """Write an object."""
        ...

    def delete(self, relpath: str) -> None:
        """Remove an object (absent: nothing)."""
        ...


class Store(Protocol):
    """Where a workspace's files are: ``fetch`` gives the local path of a relpath (brought
    here first if only the store has it); ``pull`` and ``push`` bring the working copy and
    the store level (nothing to do for a local folder)."""

    root: Path

    @property
    def remote(self) -> ObjectStore | None:
        """The object storage behind the working copy, or None for a local folder."""
        ...

    def location(self) -> str:
        """The workspace as the user named it: its path or its URI."""
        ...

    def fetch(self, relpath: str) -> Path:
        """The local path of a workspace file."""
        ...

    def has(self, relpath: str) -> bool:
        """Whether the workspace holds the file (here or in the store)."""
        ...

    def record(self, relpath: str) -> dict[str, Any] | None:
        """Size and SHA-256 of a file only the store holds; None: hash the local file."""
        ...

    def accept(self, relpath: str, stored: StoredFile) -> None:
        """Record a file a worker uploaded to the store."""
        ...

    def started(self) -> bool:
        """Whether the workspace has a saved configuration."""
        ...

    def pull(self) -> None:
        """Bring the working copy up to the store."""
        ...

    def push(self) -> None:
        """Bring the store up to the working copy."""
        ...
