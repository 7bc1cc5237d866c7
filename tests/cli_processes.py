"""The tests' `speedplus` processes, forked from a warm interpreter (``tests.conftest.speedplus``).

The suite starts some 300 `speedplus` processes, and a fresh interpreter spends 0.4-1.0 s of
each importing the same third-party libraries (numpy, pyarrow, pandas, pydantic, typer, rich,
OpenCV) before and as the command starts. Here one interpreter per pytest worker imports them once, and each run
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
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the third-party libraries every command imports at its start, and those the stages that run
#: in the command's own process import (calibrate, fuse, label: SciPy); pandas, which pyarrow
#: imports at its first conversion of Python values (every manifest written): 0.28 s of a command,
#: with OpenCV; no renderer, no torch
WARM = ("numpy", "pyarrow", "pyarrow.parquet", "pyarrow.compute", "pyarrow.dataset", "pandas", "pyarrow.pandas_compat",
        "pydantic", "pydantic.types", "annotated_types", "importlib.metadata", "typer", "rich.console", "rich.table",
        "rich.markup", "cv2", "scipy.optimize", "scipy.stats", "scipy.spatial.transform", "scipy.linalg")


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
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        for fd, path in ((1, request["stdout"]), (2, request["stderr"])):
            os.dup2(os.open(path, os.O_WRONLY | os.O_APPEND), fd)
        # as an interpreter's own streams on a pipe: stdout buffered, stderr by line and never
        # failing on what it cannot encode
        sys.stdin = open(0, closefd=False)  # noqa: SIM115 - the process's own stream, kept open until it exits
        sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
        sys.stderr = open(2, "w", buffering=1, errors="backslashreplace", closefd=False)  # noqa: SIM115
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        sys.path[0] = os.getcwd()  # as `python -m` puts it
        sys.argv = ["speedplus", *request["args"]]
        import runpy

        runpy.run_module("pipeline.cli", run_name="__main__", alter_sys=True)
        code = 0
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
        if exit_.code is not None and not isinstance(exit_.code, int):
            print(exit_.code, file=sys.stderr)
    except KeyboardInterrupt:  # as an interpreter ends on one: by the signal itself
        import traceback

        traceback.print_exc()
        code = -signal.SIGINT
    except BaseException:  # noqa: BLE001 - what an interpreter prints of an uncaught error
        import traceback

        traceback.print_exc()
    finally:
        _finalise(code)


def _finalise(code: int) -> None:
    """What an interpreter does as it ends (``Py_FinalizeEx``): wait for its non-daemon
    threads, run its ``atexit`` functions (Ray's shutdown, multiprocessing's), flush its
    streams; then the exit status."""
    import atexit
    import threading

    with contextlib.suppress(BaseException):
        threading._shutdown()  # noqa: SLF001 - the interpreter's own step, which os._exit skips
    with contextlib.suppress(BaseException):
        atexit._run_exitfuncs()  # noqa: SLF001
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    if code < 0:
        signal.signal(-code, signal.SIG_DFL)
        os.kill(os.getpid(), -code)
    os._exit(code)


class Forker:
    """The client side: warm interpreters, started on the first run. Two, each with its own
    hash seed, taken in turn: two runs after each other hash strings differently, as two
    fresh interpreters do, so that a test comparing their bytes still sees an order that
    hangs on hashing."""

    def __init__(self) -> None:
        self.processes: list[subprocess.Popen | None] = [None, None]
        self.buffers = [b"", b""]
        self.turn = 0
        self.folder = Path(tempfile.mkdtemp(prefix="speedplus-cli-"))

    def _start(self, index: int) -> subprocess.Popen:
        process = self.processes[index]
        if process is None or process.poll() is not None:
            seed = str(int.from_bytes(os.urandom(4), "little"))
            process = subprocess.Popen([sys.executable, __file__], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                       bufsize=0, env={**os.environ, "PYTHONHASHSEED": seed})
            self.processes[index], self.buffers[index] = process, b""
        return process

    def _reply(self, index: int, timeout: float) -> dict:
        """The warm interpreter's next line; the pipe read as bytes into a buffer of our own,
        so that a line already read is never waited for."""
        process, deadline = self.processes[index], time.monotonic() + timeout
        while b"\n" not in self.buffers[index]:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([process.stdout], [], [], left)[0]:
                raise TimeoutError
            chunk = os.read(process.stdout.fileno(), 65536)
            if not chunk:
                raise RuntimeError("the tests' warm interpreter (tests/cli_processes.py) ended")
            self.buffers[index] += chunk
        line, self.buffers[index] = self.buffers[index].split(b"\n", 1)
        return json.loads(line)

    def run(self, args: list[str], env: dict[str, str], cwd: str | None,
            timeout: float) -> subprocess.CompletedProcess:
        """``subprocess.run([python, -m, pipeline.cli, *args], capture_output=True, text=True,
        env=env, cwd=cwd, timeout=timeout)``'s result."""
        cwd = os.path.abspath(cwd or os.getcwd())
        if not os.path.isdir(cwd):
            raise FileNotFoundError(f"no such directory: {cwd!r}")
        index, self.turn = self.turn, 1 - self.turn
        process = self._start(index)
        # files of this run's own: a process it left behind writes into its own, never the next run's
        handles = [tempfile.mkstemp(dir=self.folder, suffix=f".{name}") for name in ("stdout", "stderr")]
        for fd, _ in handles:
            os.close(fd)
        stdout, stderr = (Path(path) for _, path in handles)
        request = {"args": list(args), "env": env, "cwd": cwd, "stdout": str(stdout), "stderr": str(stderr)}
        try:
            message = memoryview((json.dumps(request) + "\n").encode())
            while message:  # a raw pipe may take a long request in parts
                message = message[os.write(process.stdin.fileno(), message):]
            pid = self._reply(index, 60)["pid"]
            try:
                status = self._reply(index, timeout)["status"]
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
                self._reply(index, 60)
                raise subprocess.TimeoutExpired([sys.executable, "-m", "pipeline.cli", *args], timeout) from None
            return subprocess.CompletedProcess([sys.executable, "-m", "pipeline.cli", *args], status,
                                               stdout.read_text(), stderr.read_text())
        finally:
            stdout.unlink()
            stderr.unlink()

    def close(self) -> None:
        for process in self.processes:
            if process is not None and process.poll() is None:
                process.stdin.close()
                process.wait(timeout=60)
        shutil.rmtree(self.folder, ignore_errors=True)


if __name__ == "__main__":
    _serve()
