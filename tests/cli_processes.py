"""The tests' `speedplus` processes, forked from a warm interpreter (``tests.conftest.speedplus``).

The suite starts some 300 `speedplus` processes, and a fresh interpreter spends 0.4-0.5 s of
each importing the same third-party libraries (numpy, pyarrow, pydantic, typer, rich) before
the command starts. Here one interpreter per pytest worker imports them once, and each run
is a process forked from it: a process of its own, with the run's arguments, environment,
working directory, standard streams and exit status, that imports the project's own modules
afresh (so that their import-time state follows the run's environment) and runs the console
script's ``main`` as ``python -m pipeline.cli`` does. The warm interpreter never imports a
renderer (nothing is forked after Mitsuba has run) and never runs a command itself.

What a fresh interpreter does that these runs do not, the tests that need it still get a
fresh one: a run with a fault to inject (tests/faults/sitecustomize.py is read at start-up),
the docs walk, Ctrl-C in its own process group, a second process beside the first, and
``make dataset`` in CI. ``SPEEDPLUS_TESTS_FRESH_PROCESSES=1`` gives every run a fresh one.

Protocol, one JSON line each way: the request (args, env, cwd, stdout and stderr file
paths), then ``{"pid": N}`` once forked and ``{"status": S}`` once it ended (``S`` as
``subprocess`` gives it: the exit code, or minus the signal that ended it).
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

#: the third-party libraries every command imports at its start, and those the stages that run
#: in the command's own process import (calibrate, fuse, label: SciPy); no renderer, no torch
WARM = ("numpy", "pyarrow", "pyarrow.parquet", "pyarrow.compute", "pyarrow.dataset", "pydantic", "pydantic.types",
        "annotated_types", "importlib.metadata", "typer", "rich.console", "rich.table", "rich.markup", "cv2",
        "scipy.optimize", "scipy.stats", "scipy.spatial.transform", "scipy.linalg")


def _serve() -> None:
    """The warm interpreter: forks one run per request, in turn."""
    import importlib

    for name in WARM:
        importlib.import_module(name)
    for line in sys.stdin:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            _run(request)  # never returns
        print(json.dumps({"pid": pid}), flush=True)
        _, status = os.waitpid(pid, 0)
        print(json.dumps({"status": os.waitstatus_to_exitcode(status)}), flush=True)


def _run(request: dict) -> None:
    """The forked process: ``python -m pipeline.cli ARGS`` in the request's environment."""
    code = 1
    try:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        for fd, path in ((1, request["stdout"]), (2, request["stderr"])):
            os.dup2(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), fd)
        sys.stdin = open(0, closefd=False)  # noqa: SIM115 - the process's own stream, kept open until it exits
        sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
        sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115
        sys.path[0] = os.getcwd()  # as `python -m` puts it
        sys.argv = ["speedplus", *request["args"]]
        import runpy

        runpy.run_module("pipeline.cli", run_name="__main__", alter_sys=True)
        code = 0
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
        if exit_.code is not None and not isinstance(exit_.code, int):
            print(exit_.code, file=sys.stderr)
    except BaseException:  # noqa: BLE001 - what an interpreter prints of an uncaught error
        import traceback

        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        os._exit(code)


class Forker:
    """The client side: one warm interpreter, started on the first run."""

    def __init__(self) -> None:
        self.process: subprocess.Popen | None = None
        self.folder = Path(tempfile.mkdtemp(prefix="speedplus-cli-"))

    def _start(self) -> subprocess.Popen:
        if self.process is None or self.process.poll() is not None:
            self.process = subprocess.Popen([sys.executable, __file__], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                            text=True, bufsize=1)
        return self.process

    def _reply(self, process: subprocess.Popen, timeout: float | None) -> dict:
        if timeout is not None and not select.select([process.stdout], [], [], max(timeout, 0.0))[0]:
            raise TimeoutError
        line = process.stdout.readline()
        if not line:
            raise RuntimeError("the tests' warm interpreter (tests/cli_processes.py) ended")
        return json.loads(line)

    def run(self, args: list[str], env: dict[str, str], cwd: str | None,
            timeout: float) -> subprocess.CompletedProcess:
        """``subprocess.run([python, -m, pipeline.cli, *args], capture_output=True, text=True)``'s result."""
        process = self._start()
        stdout, stderr = self.folder / "stdout", self.folder / "stderr"
        request = {"args": list(args), "env": env, "cwd": str(cwd or os.getcwd()), "stdout": str(stdout),
                   "stderr": str(stderr)}
        process.stdin.write(json.dumps(request) + "\n")
        process.stdin.flush()
        pid = self._reply(process, 60)["pid"]
        try:
            status = self._reply(process, timeout)["status"]
        except TimeoutError:
            os.kill(pid, signal.SIGKILL)
            self._reply(process, 60)
            raise subprocess.TimeoutExpired(["speedplus", *args], timeout) from None
        return subprocess.CompletedProcess([sys.executable, "-m", "pipeline.cli", *args], status,
                                           stdout.read_text(errors="replace"), stderr.read_text(errors="replace"))

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.stdin.close()
            self.process.wait(timeout=60)


if __name__ == "__main__":
    _serve()
