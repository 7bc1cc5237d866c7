"""BLAS threads under a second load: calibrate on a smoke workspace with its BLAS held to
one thread (``core.engines.single_threaded_blas``, as shipped) against a thread per
core (OpenBLAS's own choice, as before issue 42), idle and beside ``LOAD`` busy processes
(another job holding the cores).

    python -m bench threads [REPEATS] [LOAD]

Each cell: the median of REPEATS runs (default 3) of ``speedplus calibrate --force`` and
their range, in seconds of wall time.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import report

SPIN = "while True: pass"
#: the CLI with BLAS left to its own thread count (the pipeline's limit switched off)
UNLIMITED = ("import sys, core.engines as engines; engines.single_threaded_blas = lambda: None; "
             "from pipeline.cli import main; sys.argv[0] = 'speedplus'; main()")


def _calibrate(workspace: Path, one_thread: bool) -> float:
    command = ["-m", "pipeline.cli"] if one_thread else ["-c", UNLIMITED]
    started = time.perf_counter()
    subprocess.run([sys.executable, *command, "calibrate", "-w", str(workspace), "--force"], check=True,
                   capture_output=True)
    return time.perf_counter() - started


def main(repeats: str = "3", load: str = "2") -> None:
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory(prefix="bench-threads-") as folder:
        workspace = Path(folder) / "w"
        subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "--profile", "smoke", "-w", str(workspace),
                        "--until", "acquire"], check=True, capture_output=True)
        rows = []
        for busy in (0, int(load)):
            spinners = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(busy)]
            try:
                for one_thread in (True, False):
                    times = np.array([_calibrate(workspace, one_thread) for _ in range(int(repeats))])
                    rows.append({"busy processes": busy, "BLAS threads": 1 if one_thread else cores,
                                 "median s": float(np.median(times)), "min s": float(times.min()),
                                 "max s": float(times.max())})
            finally:
                for spinner in spinners:
                    spinner.kill()
                    spinner.wait()
    report("threads", f"calibrate (smoke) on {cores} cores: BLAS threads, idle and under load", rows,
           {"repeats": int(repeats)})
