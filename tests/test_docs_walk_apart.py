"""The docs walk's second half (``tests.docs_blocks.walks``): the run blocks that share no
folder with the guide's workspace (a facility folder's check and plan, a target folder's run,
the sequences), in reading order, in a sandbox of their own: a module apart so that
pytest-xdist runs it beside the first half (tests/test_docs_run.py)."""

import pytest

from tests.docs_blocks import ROOT, walks
from tests.test_docs_run import _sandbox, walk


@pytest.mark.skipif(not (ROOT.parent / "shared" / "external").is_dir(), reason="the docs cite ../shared/external")
def test_the_docs_chapters_on_workspaces_of_their_own_run_as_written(tmp_path):
    ran = walk(walks()[1], _sandbox(tmp_path))
    assert len(ran) >= 8
