"""Which RWHE solver should be the default? Each solver on the same calibration captures,
against the hidden truth (virtual testbed) and in cross-validation; and, on a Tabb
dataset, our default against OpenCV's Shah closed form.

    python -m bench solvers WORKSPACE       (a workspace after `speedplus run --until calibrate`)
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import report
from manifests import Workspace
from manifests.sidecars import read_calibration

SOLVERS = ("shah", "frobenius", "reprojection")


def main(root: str = "data/default") -> None:
    rows = []
    for solver in SOLVERS:
        with tempfile.TemporaryDirectory() as directory:
            copy = Path(directory) / "w"
            shutil.copytree(root, copy)
            started = time.perf_counter()
            result = subprocess.run([sys.executable, "-m", "pipeline.cli", "calibrate", "--workspace", str(copy),
                                     "--force", "--set", f"calibrate.solver={solver}"], capture_output=True, text=True)
            seconds = time.perf_counter() - started
            if result.returncode != 0:
                raise SystemExit(result.stderr)
            calibration = read_calibration(Workspace(copy)).to_json()
        for source in ("kuka", "vicon"):
            entry = calibration.get(source)
            if not entry:
                continue
            for kind in ("truth", "cross_validated", "in_sample"):
                metric = entry["metrics"].get(kind)
                if metric is None:
                    continue
                rows.append({"solver": solver, "source": source, "against": kind,
                             "E_T_mm": metric["E_T_m"][0] * 1000, "E_R_deg": float(np.degrees(metric["E_R_rad"][0])),
                             "E_p_px": metric["E_p_px"][0], "seconds": seconds})
            if "E_T_m" in entry.get("opencv_shah_in_sample", {}) and solver == SOLVERS[-1]:  # else it failed
                metric = entry["opencv_shah_in_sample"]
                rows.append({"solver": "OpenCV Shah", "source": source, "against": "in_sample",
                             "E_T_mm": metric["E_T_m"][0] * 1000, "E_R_deg": float(np.degrees(metric["E_R_rad"][0])),
                             "E_p_px": metric["E_p_px"][0], "seconds": float("nan")})
    report("solvers", f"RWHE solvers on {Path(root).name}", rows)


if __name__ == "__main__":
    main(*sys.argv[1:])
