"""BLAS threads under a second load: calibrate on a smoke workspace with its BLAS held to
the process's share of the cores (``run.workers = 2`` on 2 cores: 1 thread, the default)
against every core (``run.workers = 1``: the cores, as OpenBLAS takes them unlimited),
idle and beside ``LOAD`` busy processes (another job holding the cores).

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


def _calibrate(workspace: Path, workers: int) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pipeline.cli", "calibrate", "-w", str(workspace), "--force", "--set",
                    f"run.workers={workers}"], check=True, capture_output=True)
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
                for workers, threads in ((2, max(1, cores // 2)), (1, cores)):
                    times = np.array([_calibrate(workspace, workers) for _ in range(int(repeats))])
                    rows.append({"busy processes": busy, "run.workers": workers, "BLAS threads": threads,
                                 "median s": float(np.median(times)), "min s": float(times.min()),
                                 "max s": float(times.max())})
            finally:
                for spinner in spinners:
                    spinner.kill()
                    spinner.wait()
    report("threads", f"calibrate (smoke) on {cores} cores: BLAS threads, idle and under load", rows,
           {"repeats": int(repeats)})
