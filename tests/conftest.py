"""Shared, expensive fixtures: run once per test session."""

import os
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
