"""One writer per workspace: a second one is refused at once, naming the holder; a lock
left by a killed process is free again."""

import os
import signal
import subprocess
import sys
import time

import pytest

from manifests import Workspace
from manifests.lock import WorkspaceBusyError, WorkspaceLock, holder
from tests.conftest import speedplus

HOLD = ("import sys, time; from manifests import Workspace; from manifests.lock import WorkspaceLock\n"
        "with WorkspaceLock(Workspace(sys.argv[1]), 'speedplus run (test holder)'):\n"
        "    print('held', flush=True); time.sleep(60)\n")


@pytest.fixture()
def held(tmp_path):
    process = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "held"
    yield process
    process.kill()
    process.wait()


def test_a_second_writer_is_refused_naming_the_holder(tmp_path, held):
    expected = rf"in use by process {held.pid} on .*speedplus run \(test holder\)"
    with pytest.raises(WorkspaceBusyError, match=expected), WorkspaceLock(Workspace(tmp_path)):
        pass
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(tmp_path))
    assert result.returncode == 1 and f"process {held.pid}" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "manifests").exists()  # refused before writing anything
    status = speedplus("status", "--workspace", str(tmp_path), "--profile", "smoke")
    assert status.returncode == 0 and f"in use by process {held.pid}" in " ".join(status.stdout.split())


def test_a_lock_left_by_a_killed_process_is_taken_over(tmp_path, held):
    os.kill(held.pid, signal.SIGKILL)
    held.wait()
    deadline = time.monotonic() + 10
    while holder(Workspace(tmp_path)) is not None and time.monotonic() < deadline:
        time.sleep(0.05)
    with WorkspaceLock(Workspace(tmp_path), "second"):
        assert f"process {os.getpid()}" in holder(Workspace(tmp_path)) and "(second," in holder(Workspace(tmp_path))
    assert speedplus("plan", "--profile", "smoke", "--workspace", str(tmp_path)).returncode == 0
