"""A workspace on object storage through the CLI (issue 15), against an S3-protocol server
on 127.0.0.1: interrupted on one machine, resumed on another, finished on the first, read
by a consumer straight from the store; the bytes are those of a local run."""

import glob
import io
import os
import signal
import subprocess
import sys
import time

import pyarrow.dataset as pads
import pyarrow.parquet as pq
from pyarrow import fs

from manifests.lease import Lease
from manifests.remote import Remote
from tests.conftest import speedplus

VOLATILE = ("seconds",)


def _machine(tmp_path, name: str) -> dict[str, str]:
    """The environment of another machine: its own working copies."""
    return {"SPEEDPLUS_WORKSPACE_CACHE": str(tmp_path / name)}


def _same_as_local(stored: dict[str, bytes], local, name: str, file_columns: tuple[str, ...]) -> None:
    parts = sorted(k for k in stored if k.startswith(f"manifests/{name}/part-"))
    got = pq.read_table(io.BytesIO(stored[parts[0]])) if len(parts) == 1 else None
    assert got is not None, parts
    want = pq.read_table(local.manifest_dir(name))
    volatile = [c for c in VOLATILE if c in got.column_names]
    assert got.drop_columns(volatile).equals(want.drop_columns(volatile)), name
    if not volatile:
        assert stored[parts[0]] == (local.manifest_dir(name) / "part-00000.parquet").read_bytes(), name
    for column in file_columns:
        for relpath in got.column(column).to_pylist():
            if relpath:
                assert stored[relpath] == local.resolve(relpath).read_bytes(), relpath


def test_a_run_on_object_storage_interrupted_resumed_elsewhere_and_finished_has_the_local_bytes(
        object_store, smoke_labelled, smoke_finished, tmp_path):
    uri = object_store.uri("smoke")
    a, b = _machine(tmp_path, "a"), _machine(tmp_path, "b")
    # machine a: Ctrl-C in the middle of acquire; the rows finished so far reach the store
    process = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "run", "--profile", "smoke", "--workspace", uri,
                                "--until", "acquire"], env={**os.environ, **a}, start_new_session=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               # a shell's background job ignores SIGINT, and Python keeps that
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while len(glob.glob(str(tmp_path / "a" / "*" / "images" / "*" / "*.png"))) < 6:
        assert process.poll() is None and time.monotonic() < deadline, process.stderr.read()
        time.sleep(0.1)
    os.killpg(process.pid, signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130 and "Traceback" not in stderr, stderr
    stored = object_store.keys("smoke")
    assert any(k.startswith("manifests/captures/part-") for k in stored), sorted(stored)
    assert "manifests/_state/captures.json" not in stored and "manifests/_state/plan.json" in stored
    assert ".lock" not in stored  # the lease is given back

    # machine b resumes from the store and goes on to label
    result = speedplus("run", "--workspace", uri, "--until", "label", env=b)
    assert result.returncode == 0, result.stderr
    assert "acquire: resumed" in result.stdout
    stored = object_store.keys("smoke")
    for name, files in (("captures", ("image_path",)), ("truth", ("maps_path",)), ("calibration_samples", ()),
                        ("poses", ()), ("labels", ())):
        _same_as_local(stored, smoke_labelled, name, files)
    assert stored["calibration.json"] == smoke_labelled.calibration_path.read_bytes()

    # machine a finishes the chain from its stale working copy, reading images from the store
    result = speedplus("run", "--workspace", uri, env=a)
    assert result.returncode == 0, result.stderr
    assert "acquire: up to date" in result.stdout and "render: ran" in result.stdout
    stored = object_store.keys("smoke")
    finished = smoke_finished[0]
    _same_as_local(stored, finished, "renders", ("image_path", "mask_path", "ground_truth_path"))
    _same_as_local(stored, finished, "predictions", ())
    assert "report/index.html" in stored

    # a consumer reads the manifests where they are, with its own library
    filesystem, base = fs.FileSystem.from_uri(uri)
    labels = pads.dataset(f"{base}/manifests/labels", filesystem=filesystem, format="parquet").to_table()
    assert labels.equals(pq.read_table(smoke_labelled.manifest_dir("labels")))

    # a third machine checks every file against the markers; then a changed object is damage
    result = speedplus("verify", "--workspace", uri, env=_machine(tmp_path, "c"))
    assert result.returncode == 0, result.stderr
    assert "completed manifests intact" in result.stdout
    object_store.client().put_object(Bucket=object_store.BUCKET, Key="smoke/renders/twins/img000001.png", Body=b"x")
    result = speedplus("verify", "--workspace", uri, env=_machine(tmp_path, "d"))
    assert result.returncode == 1 and "renders/twins/img000001.png changed since it was written" in result.stdout


def test_a_second_writer_of_a_workspace_on_object_storage_is_refused(object_store, tmp_path):
    uri = object_store.uri("busy")
    with Lease(Remote(uri), "speedplus run (elsewhere)"):
        result = speedplus("plan", "--profile", "smoke", "--workspace", uri, env=_machine(tmp_path, "a"))
        status = speedplus("status", "--workspace", uri, "--profile", "smoke", env=_machine(tmp_path, "b"))
        assert object_store.keys("busy").keys() == {".lock"}  # the refused command wrote nothing
    assert result.returncode == 1 and "Traceback" not in result.stderr
    message = " ".join(result.stderr.split())
    assert "s3://speedplus-tests/busy: in use by process" in message and "speedplus run (elsewhere)" in message
    assert "test:test" not in message  # credentials never reach a message
    assert status.returncode == 0 and "in use by process" in status.stdout


def test_an_unreachable_store_is_one_message(tmp_path):
    uri = "s3://test:test@bucket/w?endpoint_override=127.0.0.1:9&scheme=http&region=us-east-1"
    result = speedplus("plan", "--profile", "smoke", "--workspace", uri, env={**_machine(tmp_path, "a"),
                                                                            "AWS_EC2_METADATA_DISABLED": "true"},
                       timeout=300)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert "error: s3://bucket/w" in result.stderr and "test:test" not in result.stderr
