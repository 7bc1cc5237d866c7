"""A smoke workspace with labels, twins and a small training set, exported in both formats."""

import shutil

import pytest

from manifests import Workspace
from tests.conftest import speedplus

ALL_SETS = "export.sets=[\"testbed\", \"twins\", \"train\"]"


@pytest.fixture(scope="package")
def rendered(smoke_labelled, tmp_path_factory):
    root = tmp_path_factory.mktemp("export") / "w"
    shutil.copytree(smoke_labelled.root, root)
    for args in (("render",), ("render", "--set", "train", "--count", "6")):
        result = speedplus(*args, "--workspace", str(root))
        assert result.returncode == 0, result.stderr
    return Workspace(root)


@pytest.fixture(scope="package")
def exported(rendered, tmp_path_factory):
    """{format: export folder} of every set."""
    out = {}
    for export_format in ("bop", "speedplus"):
        folder = tmp_path_factory.mktemp(export_format) / "out"
        result = speedplus("export", "--workspace", str(rendered.root), "--format", export_format, "--out",
                           str(folder), "--set", ALL_SETS)
        assert result.returncode == 0, result.stderr
        out[export_format] = folder
    return out
