"""Shared, expensive fixtures: run once per test session."""

import os
import shutil
import subprocess
import sys

import pytest

from manifests import Workspace


@pytest.fixture(scope="session")
def default_acquisition(tmp_path_factory):
    """A workspace after `speedplus run --profile default --until acquire` (several minutes:
    112 Mitsuba captures), shared by every test that needs realistic captures."""
    root = tmp_path_factory.mktemp("default") / "w"
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "--profile", "default", "--workspace",
                             str(root), "--until", "acquire"], capture_output=True, text=True,
                            env={**os.environ, "COLUMNS": "200"}, timeout=1800)
    assert result.returncode == 0, result.stderr
    return Workspace(root)


@pytest.fixture(scope="session")
def default_labelled(default_acquisition, tmp_path_factory):
    """``default_acquisition`` calibrated, fused and labelled with the default configuration
    (read only: copy it to change it)."""
    root = tmp_path_factory.mktemp("default_labelled") / "w"
    shutil.copytree(default_acquisition.root, root)
    result = speedplus("run", "--workspace", str(root), "--until", "label")
    assert result.returncode == 0, result.stderr
    return Workspace(root)


@pytest.fixture(scope="session")
def smoke_finished(smoke_labelled, tmp_path_factory):
    """A copy of ``smoke_labelled`` after the rest of the chain (render, evaluate, report)
    with the local engine, and the run's standard output (read only: copy it to change it)."""
    root = tmp_path_factory.mktemp("e2e") / "w"
    shutil.copytree(smoke_labelled.root, root)
    result = speedplus("run", "--workspace", str(root))
    assert result.returncode == 0, result.stderr
    return Workspace(root), result.stdout


def speedplus(*args, env=None, timeout=1800):
    """Run the CLI in a fresh process (as users do)."""
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True,
                          env={**os.environ, "COLUMNS": "200", **(env or {})}, timeout=timeout)


@pytest.fixture(scope="session")
def smoke_labelled(tmp_path_factory):
    """A smoke workspace after `speedplus run --until label` (about half a minute)."""
    root = tmp_path_factory.mktemp("smoke") / "w"
    result = speedplus("run", "--profile", "smoke", "--workspace", str(root), "--until", "label")
    assert result.returncode == 0, result.stderr
    assert "Table 1" in result.stdout and "KUKA-only" in result.stdout
    return Workspace(root)


def reseal(workspace, name):
    """Record a manifest's current parts in its completion marker, as if the stage had
    written them: for tests of what readers make of bad content (not of damage)."""
    import json

    from manifests import list_parts
    from manifests.integrity import part_records

    path = workspace.success_path(name)
    marker = json.loads(path.read_text())
    marker["parts"] = part_records(list_parts(workspace, name))
    path.write_text(json.dumps(marker))
