"""The Ray engine on a two-node cluster without a shared filesystem (issue 15).

The head node and the driver see the workspace; the second node runs in its own mount
namespace with an empty tmpfs over the workspace, so a worker that read or wrote the
workspace itself would fail or lose files there. acquire, render and evaluate must make
the bytes of a local run, and must survive a killed worker and a node lost mid-chain.
"""

import glob
import hashlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from core.engines.local_cluster import ENV, LocalCluster, free_port
from manifests import Workspace, list_parts
from manifests.remote import Remote, RemoteCopy
from tests.conftest import speedplus

VOLATILE = ("seconds",)

pytestmark = pytest.mark.skipif(os.geteuid() != 0 or shutil.which("unshare") is None,
                                reason="a node in its own mount namespace needs root and unshare")


@pytest.fixture(scope="module")
def places(tmp_path_factory):
    """Where the cluster's workspaces live (hidden from the second node), and a local
    reference: the smoke workspace rendered and evaluated by the local engine."""
    base = tmp_path_factory.mktemp("cluster")
    return base / "hidden", base / "local"


@pytest.fixture(scope="module")
def local_reference(smoke_finished):
    return smoke_finished[0]


@pytest.fixture(scope="module")
def cluster(places):
    """The head and a second node; while ``cluster.slow`` exists, each twin a node renders
    takes a second longer (tests/faults/sitecustomize.py)."""
    hidden, _ = places
    slow = hidden.parent / "second-node-slow"
    faults = str(Path(__file__).resolve().parents[1] / "faults")
    env = {"PYTHONPATH": os.pathsep.join(p for p in (faults, os.environ.get("PYTHONPATH", "")) if p),
           "SPEEDPLUS_FAULT_SLOW_RENDER_WHILE": str(slow)}
    with LocalCluster(head_cpus=1, env=env) as running:
        running.hidden, running.slow = hidden, slow
        running.second = running.add_node(1, hidden, env=env)
        yield running


def _copy(smoke_labelled: Workspace, hidden: Path, name: str) -> Workspace:
    root = hidden / name
    shutil.copytree(smoke_labelled.root, root, ignore=shutil.ignore_patterns("renders", "predictions", "scores",
                                                                                "comparisons"))
    return Workspace(root)


def _on(cluster: LocalCluster, *args: str, env: dict[str, str] | None = None):
    return speedplus(*args, "--engine", "ray", "--ray-address", cluster.address, env=env or ENV, timeout=600)


def _same(a: Workspace, b: Workspace, name: str, file_columns: tuple[str, ...]) -> None:
    got, want = (pq.read_table(ws.manifest_dir(name)) for ws in (a, b))
    volatile = [c for c in VOLATILE if c in got.column_names]
    assert got.drop_columns(volatile).equals(want.drop_columns(volatile)), name
    if not volatile:  # another engine, another finishing order: the same manifest bytes
        assert [p.read_bytes() for p in list_parts(a, name)] == [p.read_bytes() for p in list_parts(b, name)], name
    for column in file_columns:
        for relpath in got.column(column).to_pylist():
            if relpath:
                assert a.resolve(relpath).read_bytes() == b.resolve(relpath).read_bytes(), relpath


def _busy_workers() -> list[int]:
    result = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True)
    return [int(line.split()[0]) for line in result.stdout.splitlines() if line.split()[1:2] == ["ray::Worker.call"]]


def _interrupted(cluster: LocalCluster, interrupt, *args: str) -> subprocess.CompletedProcess:
    """A command on the cluster; once two workers are busy, ``interrupt()``; then wait."""
    # two workers, one a node each (the smoke profile runs one)
    command = [sys.executable, "-m", "pipeline.cli", *args, "--engine", "ray", "--ray-address", cluster.address,
               "--workers", "2"]
    process = subprocess.Popen(command, env={**os.environ, "COLUMNS": "200", **ENV}, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while len(_busy_workers()) < 2:
        assert time.monotonic() < deadline and process.poll() is None, "the workers never got busy"
        time.sleep(0.2)
    time.sleep(2.0)  # mid-stage: some captures done, some in flight
    interrupt()
    stdout, stderr = process.communicate(timeout=600)
    return subprocess.CompletedProcess(command, process.returncode, stdout, stderr)


def test_speedplus_run_on_two_nodes_without_a_shared_filesystem_survives_a_killed_worker_with_the_local_bytes(
        cluster, local_reference, smoke_labelled):
    root = cluster.hidden / "run"  # the second node sees an empty tmpfs there
    result = _interrupted(cluster, lambda: os.kill(_busy_workers()[0], signal.SIGKILL),  # during acquire
                          "run", "--profile", "smoke", "--workspace", str(root))
    assert result.returncode == 0, result.stderr
    assert "a worker died" in result.stderr
    reports = [line for line in result.stderr.splitlines() if line.startswith("ray worker on")]
    assert len({line.split(" (node ")[1].split(",")[0] for line in reports}) == 2, result.stderr  # both nodes
    assert sum("mitsuba_variant llvm_ad_rgb" in line for line in reports) >= 4, result.stderr  # acquire, render
    ws = Workspace(root)
    for name, files in (("captures", ("image_path",)), ("truth", ("maps_path",)), ("calibration_samples", ()),
                        ("poses", ()), ("labels", ())):
        _same(ws, smoke_labelled, name, files)
    _same(ws, local_reference, "renders", ("image_path", "mask_path", "ground_truth_path"))
    _same(ws, local_reference, "predictions", ())
    run = tomllib.loads((ws.root / "config.toml").read_text())["run"]
    assert (run["engine"], run["ray_address"]) == ("local", "")  # the flags were for this run only


def test_a_node_lost_mid_chain_keeps_what_finished_and_resumes_to_the_local_bytes(
        cluster, smoke_labelled, local_reference):
    """Issue 58: the second node dies while `speedplus run` renders, after plan to label. The
    retries finish the chain on the head, or the command fails keeping the stages before
    render and the twins finished; then the same command resumes. Either way, the bytes of
    a local run."""
    ws = _copy(smoke_labelled, cluster.hidden, "killed")
    cluster.slow.touch()  # a twin takes each node a second: the second is lost mid-render
    try:
        result = _interrupted(cluster, lambda: cluster.kill_node(cluster.second), "run", "--workspace",
                              str(ws.root))
    finally:
        cluster.slow.unlink()
    assert result.returncode != 0 or "a worker died" in result.stderr, result.stderr  # lost mid-render
    if result.returncode != 0:  # at most one resume
        said = " ".join(result.stderr.split())
        assert "kept: plan, acquire, calibrate, fuse, label (completed;" in said and "Traceback" not in said, said
        result = _on(cluster, "run", "--workspace", str(ws.root))
    assert result.returncode == 0, result.stderr
    _same(ws, local_reference, "renders", ("image_path", "mask_path", "ground_truth_path"))
    _same(ws, local_reference, "predictions", ())
    assert (ws.root / "report" / "index.html").is_file()


def test_more_workers_than_free_cpus_never_hang_and_write_to_object_storage_directly(
        cluster, smoke_labelled, local_reference, object_store, tmp_path):
    """render with 6 workers asked on 2 CPUs, the workspace in an S3 store: the workers upload
    their images themselves (the driver's working copy never holds them), the driver checks
    them, and evaluate on the cluster reads them back: the bytes of a local run."""
    if cluster.cpus < 2:
        cluster.second = cluster.add_node(1, cluster.hidden)
    uri = object_store.uri("cluster")
    seed = _copy(smoke_labelled, cluster.hidden, "seed")
    RemoteCopy(Remote(uri), seed.root).push()  # the labelled workspace, put in the store
    driver = {**ENV, "SPEEDPLUS_WORKSPACE_CACHE": str(tmp_path / "driver")}
    result = speedplus("render", "--workspace", uri, "--workers", "6", "--engine", "ray", "--ray-address",
                       cluster.address, env=driver, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "ray: 2 worker(s)" in result.stderr
    assert not glob.glob(str(tmp_path / "driver" / "*" / "renders" / "twins" / "*.png"))  # never sent to the driver
    result = _on(cluster, "evaluate", "--workspace", uri, env=driver)
    assert result.returncode == 0, result.stderr
    stored = object_store.keys("cluster")
    for name, files in (("renders", ("image_path", "mask_path", "ground_truth_path")), ("predictions", ())):
        got, want = pq.read_table(io.BytesIO(stored[f"manifests/{name}/part-00000.parquet"])), \
            pq.read_table(local_reference.manifest_dir(name))
        assert got.drop_columns([c for c in VOLATILE if c in got.column_names]).equals(
            want.drop_columns([c for c in VOLATILE if c in want.column_names])), name
        for column in files:
            for relpath in got.column(column).to_pylist():
                assert stored[relpath] == local_reference.resolve(relpath).read_bytes(), relpath
    marker = json.loads(stored["manifests/_state/renders.json"])
    assert all(marker["files"][r]["sha256"] == hashlib.sha256(stored[r]).hexdigest() for r in marker["files"])


def test_an_unreachable_cluster_is_an_error_before_anything_is_discarded(local_reference, tmp_path):
    shutil.copytree(local_reference.root, tmp_path / "nowhere")
    ws = Workspace(tmp_path / "nowhere")
    result = speedplus("render", "--workspace", str(ws.root), "--force", "--engine", "ray", "--ray-address",
                       f"127.0.0.1:{free_port()}", env=ENV, timeout=300)
    assert result.returncode == 1
    assert "error: cannot join the Ray cluster" in result.stderr and "Traceback" not in result.stderr
    assert pq.read_table(ws.manifest_dir("renders")).num_rows == 8  # --force discarded nothing


def test_a_node_that_would_render_with_another_variant_is_refused(cluster, smoke_labelled):
    ws = _copy(smoke_labelled, cluster.hidden, "scalar")
    bad = cluster.add_node(1, env={"DRJIT_LIBLLVM_PATH": "/nonexistent/libLLVM.so"})  # no LLVM on that node
    try:  # 40 images keep the good workers busy well past the bad one's report
        result = _on(cluster, "render", "--workspace", str(ws.root), "--set", "train", "--count", "40",
                     "--workers", "0")
    finally:
        cluster.kill_node(bad)
    assert result.returncode == 1, result.stderr
    message = " ".join(result.stderr.split())
    assert "refusing the Ray worker" in message and "llvm_ad_rgb variant is unavailable" in message
    assert "libllvm19" in message and "Traceback" not in message
