"""Shared, expensive fixtures: built once per test run, whatever the number of pytest-xdist
workers (``once``), and read only: copy one to change it."""

import atexit
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from filelock import FileLock

from manifests import Workspace
from tests.cli_processes import Forker

#: the modules whose end-to-end runs take a minute or more of the suite (their durations:
#: ``pytest --durations=30``): marked ``slow`` (``-m "not slow"`` leaves them out of a quick
#: local run)
SLOW_MODULES = frozenset({
    "tests/test_docs_run.py", "tests/test_docs_walk_apart.py", "tests/bench/test_cited_benches.py",
    "tests/pipeline/test_workspace_changes.py",
    "tests/stages/test_plan_facility.py", "tests/test_any_target.py", "tests/stages/acquire/test_acquire_default.py",
    "tests/stages/test_accuracy_default.py", "tests/stages/render/test_twins_default.py",
    "tests/pipeline/test_object_storage.py", "tests/core/test_cluster.py",
    "tests/stages/acquire/test_facility_rehearsal.py", "tests/stages/calibrate/test_real_kuka.py",
})
#: the modules the workers take first, one each: the docs walk's two halves, a minute and a
#: half each in one process apiece, which pytest-xdist's own order (the most tests first)
#: handed out last, the other worker long out of work by the time they ended
FIRST_MODULES = ("tests/test_docs_walk_apart.py", "tests/test_docs_run.py")


def pytest_configure(config) -> None:
    """The workers take the modules in collection order (``pytest_collection_modifyitems``)."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items) -> None:
    """Mark the slow modules' tests; collect ``FIRST_MODULES`` first, then the others as
    pytest-xdist orders them (the most tests first: the heavy end-to-end modules, of few
    tests, between light ones; tried longest first, the two heaviest ran together, each
    spawning workers, and the suite took longer). ``make test`` runs ``--dist loadfile``: a
    module's tests on one worker, so each module-scoped fixture is built once. (``--dist
    loadgroup`` cannot group here: xdist 3.8 renames a grouped test's ``_nodeid``, which
    pytest 9 no longer reads.)"""
    counts: dict[str, int] = {}
    first: dict[str, int] = {}  # a module's first place in the collection: its tests stay together, in order
    for index, item in enumerate(items):
        module = item.nodeid.split("::")[0]
        counts[module] = counts.get(module, 0) + 1
        first.setdefault(module, index)
        if module in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
    rank = {module: index for index, module in enumerate(FIRST_MODULES)}

    def place(item) -> tuple[int, int, int]:
        module = item.nodeid.split("::")[0]
        return rank.get(module, len(rank)), -counts[module], first[module]

    items.sort(key=place)


def once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """The folder ``name``, made by ``build(folder)`` once for the whole run: under pytest-xdist
    the first worker to ask builds it, under a lock, and the others wait and read the same
    folder (each would otherwise build its own, minutes of captures each). A build that
    failed fails the others at once with its error, rather than each building it again."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = shared / "once" / name
    done, failed = folder.with_name(f"{name}.done"), folder.with_name(f"{name}.failed")
    folder.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(folder.with_name(f"{name}.lock"))):
        if failed.exists():
            pytest.fail(f"the shared fixture {name} failed in another worker:\n{failed.read_text()}")
        if not done.exists():
            try:
                build(folder)
            except BaseException as error:
                failed.write_text(f"{type(error).__name__}: {error}")
                raise
            done.touch()
    return folder


@pytest.fixture(scope="session")
def default_acquisition(tmp_path_factory):
    """A workspace after `speedplus run --profile default --until acquire` (several minutes:
    112 Mitsuba captures), shared by every test that needs realistic captures."""
    def build(folder: Path) -> None:
        result = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "--profile", "default",
                                 "--workspace", str(folder / "w"), "--until", "acquire"], capture_output=True,
                                text=True, env={**os.environ, "COLUMNS": "200"}, timeout=1800)
        assert result.returncode == 0, result.stderr

    return Workspace(once(tmp_path_factory, "default", build) / "w")


@pytest.fixture(scope="session")
def default_labelled(default_acquisition, tmp_path_factory):
    """``default_acquisition`` calibrated, fused and labelled with the default configuration
    (read only: copy it to change it)."""
    def build(folder: Path) -> None:
        shutil.copytree(default_acquisition.root, folder / "w")
        result = speedplus("run", "--workspace", str(folder / "w"), "--until", "label")
        assert result.returncode == 0, result.stderr

    return Workspace(once(tmp_path_factory, "default_labelled", build) / "w")


@pytest.fixture(scope="session")
def smoke_finished(smoke_labelled, tmp_path_factory):
    """A copy of ``smoke_labelled`` after the rest of the chain (render, evaluate, report)
    with the local engine, and the run's standard output (read only: copy it to change it)."""
    def build(folder: Path) -> None:
        shutil.copytree(smoke_labelled.root, folder / "w")
        result = speedplus("run", "--workspace", str(folder / "w"))
        assert result.returncode == 0, result.stderr
        (folder / "stdout.txt").write_text(result.stdout)

    folder = once(tmp_path_factory, "e2e", build)
    return Workspace(folder / "w"), (folder / "stdout.txt").read_text()


_FORKER: list[Forker] = []
#: variables an interpreter or the libraries it has loaded read as it starts: a run that sets
#: one gets a fresh interpreter (tests/cli_processes.py)
_READ_AT_START = re.compile(r"PYTHON|LC_|LANG$|.*_NUM_THREADS$|TYPER_|OMP_|MKL_|OPENBLAS")


def speedplus(*args, env=None, timeout=1800, cwd=None):
    """Run the CLI in a process of its own (as users do), forked from a warm interpreter
    (tests/cli_processes.py). An ``env`` that sets a ``SPEEDPLUS_FAULT_*`` gets the fault
    injection of tests/faults/sitecustomize.py, in a fresh interpreter (which reads it at its
    start), as does one that sets what an interpreter reads as it starts (``_READ_AT_START``)."""
    asked = dict(env or {})
    env = {**os.environ, "COLUMNS": "200", **asked}
    faults = any(name.startswith("SPEEDPLUS_FAULT_") and value for name, value in env.items())
    if faults:
        folder = str(Path(__file__).resolve().parent / "faults")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (folder, env.get("PYTHONPATH", "")) if p)
    if faults or any(map(_READ_AT_START.match, asked)) or os.environ.get("SPEEDPLUS_TESTS_FRESH_PROCESSES") == "1":
        return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True,
                              env=env, timeout=timeout, cwd=cwd)
    if not _FORKER:
        _FORKER.append(Forker())
        atexit.register(_FORKER[0].close)
    return _FORKER[0].run([str(a) for a in args], env, None if cwd is None else str(cwd), timeout)


@pytest.fixture(scope="session")
def smoke_labelled(tmp_path_factory):
    """A smoke workspace after `speedplus run --until label` (about half a minute)."""
    def build(folder: Path) -> None:
        result = speedplus("run", "--profile", "smoke", "--workspace", str(folder / "w"), "--until", "label")
        assert result.returncode == 0, result.stderr
        assert "Table 1" in result.stdout and "KUKA-only" in result.stdout

    return Workspace(once(tmp_path_factory, "smoke", build) / "w")


def reseal(workspace, name):
    """Record a manifest's current parts in its completion marker, as if the stage had
    written them: for tests of what readers make of bad content (not of damage)."""
    from dataclasses import replace

    from manifests import list_parts, read_marker, write_marker
    from manifests.integrity import part_records

    parts = part_records(list_parts(workspace, name))
    write_marker(workspace, name, replace(read_marker(workspace, name), parts=parts))


class ObjectStore:
    """An S3-protocol server (moto) on 127.0.0.1 for this test session; ``uri(prefix)`` names a
    workspace in its bucket, endpoint and credentials included, so every process (CLI, Ray
    workers) reaches it without environment variables."""

    BUCKET = "speedplus-tests"

    def __init__(self, port: int) -> None:
        self.port = port

    def uri(self, prefix: str) -> str:
        return (f"s3://test:test@{self.BUCKET}/{prefix}?endpoint_override=127.0.0.1:{self.port}&scheme=http"
                "&region=us-east-1")

    def client(self):
        import boto3

        return boto3.client("s3", endpoint_url=f"http://127.0.0.1:{self.port}", aws_access_key_id="test",
                            aws_secret_access_key="test", region_name="us-east-1")

    def keys(self, prefix: str) -> dict[str, bytes]:
        """Every object under ``prefix`` (key relative to it -> bytes)."""
        client, out = self.client(), {}
        for page in client.get_paginator("list_objects_v2").paginate(Bucket=self.BUCKET, Prefix=prefix + "/"):
            for entry in page.get("Contents", []):
                key = entry["Key"]
                if key.endswith("/"):  # a folder marker pyarrow leaves
                    continue
                out[key[len(prefix) + 1:]] = client.get_object(Bucket=self.BUCKET, Key=key)["Body"].read()
        return out


@pytest.fixture(scope="session")
def object_store():
    """moto's S3 server on a free loopback port, with one bucket; stopped at the end."""
    import socket
    import time

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 30
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            assert server.poll() is None and time.monotonic() < deadline, "moto server did not start"
            time.sleep(0.2)
    store = ObjectStore(port)
    store.client().create_bucket(Bucket=ObjectStore.BUCKET)
    yield store
    server.terminate()
    server.wait(timeout=30)


# ------------------------------------------ a smoke workspace with twins, exported (export, loaders)
ALL_SETS = "export.sets=[\"testbed\", \"twins\", \"train\"]"


@pytest.fixture(scope="session")
def rendered(smoke_labelled, tmp_path_factory):
    def build(folder: Path) -> None:
        shutil.copytree(smoke_labelled.root, folder / "w")
        for args in (("render",), ("render", "--set", "train", "--count", "6")):
            result = speedplus(*args, "--workspace", str(folder / "w"))
            assert result.returncode == 0, result.stderr

    return Workspace(once(tmp_path_factory, "export", build) / "w")


@pytest.fixture(scope="session")
def exported(rendered, tmp_path_factory):
    """{format: export folder} of every set."""
    def build(folder: Path) -> None:
        for export_format in ("bop", "speedplus"):
            result = speedplus("export", "--workspace", str(rendered.root), "--format", export_format, "--out",
                               str(folder / export_format), "--set", ALL_SETS)
            assert result.returncode == 0, result.stderr

    folder = once(tmp_path_factory, "exported", build)
    return {export_format: folder / export_format for export_format in ("bop", "speedplus")}


def missing_named(message: str, root: Path) -> list[str]:
    """What an error message sends the user to that does not exist after the command (issue
    58): a manifest it names (``the X manifest``, ``manifest X``, ``X manifest``), a path
    under the workspace ``root``, a ``speedplus`` command, and the workspace such a command
    is given with ``-w``/``--workspace``. Empty when all exist."""
    import re

    from pipeline.cli import app

    said = " ".join(message.split())
    missing = []
    for name in {a or b for a, b in re.findall(r"the (\w+) manifest|manifest (\w+)", said)}:
        if not any((root / "manifests" / name).glob("*.parquet")):
            missing.append(f"manifest {name}")
    for found in re.findall(re.escape(str(root)) + r"(/[\w./-]*)?", said):
        path = root / found.strip("/").rstrip(".") if found else root
        if not path.exists():
            missing.append(str(path))
    commands = {c.name for c in app.registered_commands} | {g.name for g in app.registered_groups}
    for command, rest in re.findall(r"`speedplus ([\w-]+)([^`]*)`", said):
        if command not in commands:
            missing.append(f"command speedplus {command}")
        workspace = re.search(r"(?:-w|--workspace) (\S+)", rest)
        if workspace and not Path(workspace.group(1)).exists():
            missing.append(f"workspace {workspace.group(1)}")
    return missing
