"""Workspaces on object storage: what the sync costs, against an S3-protocol server (moto)
on 127.0.0.1.

    python -m bench storage

1. ``speedplus run -p smoke --until label`` on a local folder and on ``s3://``: wall times.
2. Transfers of the working copy: push of N files of a capture's size, a pull of the
   metadata only (media stay in the store), a fetch of every image, a no-op push.
Loopback and moto are not a real store: latency per request is ~1 ms here, 10-50 ms on a
cloud store, so the per-file figures are lower bounds for a WAN (transfers run 8 at once).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import report
from manifests import sample_ids
from manifests.remote import Remote, RemoteCopy

BUCKET = "bench"


def _moto() -> tuple[subprocess.Popen, int]:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    for _ in range(150):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return server, port
        except OSError:
            time.sleep(0.2)
    raise RuntimeError("moto server did not start")


def _uri(port: int, prefix: str) -> str:
    return f"s3://b:b@{BUCKET}/{prefix}?endpoint_override=127.0.0.1:{port}&scheme=http&region=us-east-1"


def _timed_run(workspace: str, cache: Path) -> float:
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "-p", "smoke", "-w", workspace, "--until",
                             "label"], capture_output=True, text=True,
                            env={**os.environ, "SPEEDPLUS_WORKSPACE_CACHE": str(cache)})
    if result.returncode != 0:
        raise RuntimeError(result.stderr[-2000:])
    return time.perf_counter() - started


def main(*args: str) -> None:
    files = int(args[0]) if args else 200
    server, port = _moto()
    folder = Path(tempfile.mkdtemp())
    try:
        Remote(_uri(port, "x") + "&allow_bucket_creation=true").filesystem()[0].create_dir(BUCKET)
        local_s = _timed_run(str(folder / "local"), folder / "cache")
        remote_s = _timed_run(_uri(port, "smoke"), folder / "cache")
        rows = [{"what": "run -p smoke --until label", "local_s": round(local_s, 2), "s3_s": round(remote_s, 2),
                 "overhead_s": round(remote_s - local_s, 2)}]
        report("storage_run", "smoke chain to label: local folder vs s3:// (moto on loopback)", rows)

        rng = np.random.default_rng(0)
        source = folder / "source"
        size = 1_500_000  # about one 960 x 600 capture PNG
        for index in range(files):
            path = source / "images" / "dataset" / f"{sample_ids.make('dataset', index)}.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(rng.bytes(size))
        (source / "manifests" / "_state").mkdir(parents=True)
        (source / "manifests" / "_state" / "captures.json").write_text("{}")
        remote = Remote(_uri(port, "transfers"))
        timings = []
        started = time.perf_counter()
        RemoteCopy(remote, source).push()
        timings.append(("push", files + 1, time.perf_counter() - started))
        started = time.perf_counter()
        RemoteCopy(remote, source).push()
        timings.append(("push, nothing changed", 0, time.perf_counter() - started))
        other = RemoteCopy(remote, folder / "other")
        started = time.perf_counter()
        other.pull()
        timings.append(("pull (metadata; media on demand)", 1, time.perf_counter() - started))
        started = time.perf_counter()
        for index in range(files):
            other.fetch(f"images/dataset/img{index:06d}.png")
        timings.append(("fetch every image, one at a time", files, time.perf_counter() - started))
        rows = [{"transfer": what, "objects": count, "seconds": round(seconds, 3),
                 "MB_per_s": round(count * size / 1e6 / seconds, 1) if count > 1 else "-"}
                for what, count, seconds in timings]
        report("storage_transfers", f"working copy <-> s3:// (moto on loopback), {files} files of {size / 1e6} MB",
               rows)
    finally:
        server.terminate()
        server.wait(timeout=30)
        shutil.rmtree(folder, ignore_errors=True)
