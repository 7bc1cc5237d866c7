"""One writer per workspace (docs/architecture.md section 4): an advisory lock on
``W/.lock`` held for the life of a writing command.

``flock`` belongs to the open file, so the kernel releases it when the holder exits or is
killed: a lock left by a dead process is simply free, and the next writer takes it over.
The file says who holds it (PID, host, command, since when), for the message a second
writer gets. Readers (``status``, ``verify``) never take it. A workspace on object storage
also takes its store's lease (``manifests.lease``): one writer across machines.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
from datetime import UTC, datetime
from types import TracebackType

from manifests.lease import Lease
from manifests.lease import holder as lease_holder
from manifests.workspace import Workspace
from speedplus.errors import InputError

LOCK_FILE = ".lock"


class WorkspaceBusyError(InputError):
    """Another process writes this workspace (exit code 1)."""


class WorkspaceLock:
    """``with WorkspaceLock(workspace):`` holds the workspace's write lock, or raises
    ``WorkspaceBusyError`` naming the holder at once (never waits)."""

    def __init__(self, workspace: Workspace, command: str | None = None) -> None:
        self.path = workspace.root / LOCK_FILE
        self.command = command or " ".join(os.path.basename(a) if i == 0 else a for i, a in enumerate(sys.argv))
        self.handle: int | None = None
        self.lease = Lease(workspace.remote, self.command) if workspace.remote is not None else None

    def __enter__(self) -> WorkspaceLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(handle)
            os.close(handle)
            raise WorkspaceBusyError(f"{self.path.parent}: in use by {holder}; wait for it to finish (a workspace has "
                                "one writer at a time)") from None
        # the holder's description, for whoever is refused next
        os.ftruncate(handle, 0)
        os.pwrite(handle, json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "command": self.command,
                                      "since": datetime.now(UTC).isoformat(timespec="seconds")}).encode(), 0)
        self.handle = handle
        if self.lease is not None:
            try:
                self.lease.__enter__()
            except BaseException:
                self.lease = None
                self.__exit__(None, None, None)
                raise
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if self.lease is not None:
            self.lease.__exit__(kind, error, traceback)
        if self.handle is not None:
            os.ftruncate(self.handle, 0)
            fcntl.flock(self.handle, fcntl.LOCK_UN)
            os.close(self.handle)
            self.handle = None


def _holder(handle: int) -> str:
    try:
        info = json.loads(os.pread(handle, 4096, 0) or b"{}")
        return f"process {info['pid']} on {info['host']} ({info['command']}, since {info['since']})"
    except (ValueError, KeyError, TypeError):
        return "another process"


def holder(workspace: Workspace) -> str | None:
    """Who writes the workspace now, or None (for ``status``; takes nothing)."""
    if workspace.remote is not None:
        return lease_holder(workspace.remote)
    path = workspace.root / LOCK_FILE
    try:
        handle = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
        fcntl.flock(handle, fcntl.LOCK_UN)
        return None
    except BlockingIOError:
        return _holder(handle)
    finally:
        os.close(handle)
