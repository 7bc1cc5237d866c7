"""One writer for a workspace on object storage (docs/architecture.md section 4): a lease
object ``W/.lock`` in the store, renewed while its holder runs.

Object stores have no ``flock``, and ``pyarrow.fs`` no conditional write, so the lease is
taken by write-then-confirm: a writer that finds no live lease writes its own (a random
token), waits ``SETTLE_S`` and reads it back; of two writers that raced, only the later one
reads its own token, and the other is refused. A holder renews the lease every ``RENEW_S``;
one not renewed for ``EXPIRE_S`` (its holder was killed, or lost the network) is free.
Times are the holders' UTC clocks, so machines sharing a workspace need synchronised clocks
(NTP), as every cluster has. Format: ``LEASE_VERSION`` JSON, checked on read.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
import threading
import time
from datetime import UTC, datetime
from typing import Any

from manifests.remote import Remote, StorageError

LEASE_FILE = ".lock"
LEASE_VERSION = 1
SETTLE_S = 1.0
RENEW_S = 20.0
EXPIRE_S = 120.0


class LeaseBusyError(StorageError):
    """Another process holds the workspace's lease (exit code 1)."""


def _now() -> float:
    return datetime.now(UTC).timestamp()


def read_lease(remote: Remote) -> dict[str, Any] | None:
    """The lease in the store, or None; an unreadable one names the object and the key."""
    data = remote.read(LEASE_FILE)
    if data is None:
        return None
    where = f"{remote.display()}/{LEASE_FILE}"
    try:
        lease = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise StorageError(f"{where}: not valid JSON ({error}); delete it if no command writes this workspace") \
            from None
    for key, kind in (("version", int), ("token", str), ("renewed", float), ("pid", int), ("host", str),
                      ("command", str), ("since", str)):
        if not isinstance(lease, dict) or not isinstance(lease.get(key), kind):
            raise StorageError(f"{where}: key {key}: expected a {kind.__name__}; delete it if no command writes "
                               "this workspace")
    if lease["version"] != LEASE_VERSION:
        raise StorageError(f"{where}: key version: expected {LEASE_VERSION}, found {lease['version']}")
    return lease


def describe(lease: dict[str, Any]) -> str:
    return f"process {lease['pid']} on {lease['host']} ({lease['command']}, since {lease['since']})"


def holder(remote: Remote) -> str | None:
    """Who holds a live lease on the workspace now, or None."""
    lease = read_lease(remote)
    return describe(lease) if lease and _now() - lease["renewed"] < EXPIRE_S else None


class Lease:
    """``with Lease(remote, command):`` holds the workspace's lease, or raises
    ``LeaseBusyError`` naming the holder at once (never waits)."""

    def __init__(self, remote: Remote, command: str) -> None:
        self.remote, self.command = remote, command
        self.token = secrets.token_hex(16)
        self.since = datetime.now(UTC).isoformat(timespec="seconds")
        self._stop = threading.Event()
        self._renewer: threading.Thread | None = None

    def _write(self) -> None:
        self.remote.put(LEASE_FILE, json.dumps({
            "version": LEASE_VERSION, "token": self.token, "renewed": _now(), "pid": os.getpid(),
            "host": socket.gethostname(), "command": self.command, "since": self.since}).encode())

    def _refuse(self, lease: dict[str, Any]) -> LeaseBusyError:
        return LeaseBusyError(f"{self.remote.display()}: in use by {describe(lease)}; wait for it to finish (a "
                              f"workspace has one writer at a time; a lease not renewed for {EXPIRE_S:.0f} s is free)")

    def __enter__(self) -> Lease:
        current = read_lease(self.remote)
        if current is not None and _now() - current["renewed"] < EXPIRE_S:
            raise self._refuse(current)
        self._write()
        time.sleep(SETTLE_S)
        confirmed = read_lease(self.remote)
        if confirmed is None or confirmed["token"] != self.token:
            if confirmed is None:
                raise LeaseBusyError(f"{self.remote.display()}: another writer took and dropped the lease at the "
                                     "same moment; try again")
            raise self._refuse(confirmed)
        self._renewer = threading.Thread(target=self._renew, daemon=True)
        self._renewer.start()
        return self

    def _renew(self) -> None:
        while not self._stop.wait(RENEW_S):
            try:
                self._write()
            except StorageError:
                continue  # the store may be back before the lease expires

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        if self._renewer is not None:
            self._renewer.join()
        try:
            current = read_lease(self.remote)
            if current is not None and current["token"] == self.token:
                self.remote.delete(LEASE_FILE)
        except StorageError:
            pass  # it expires by itself
