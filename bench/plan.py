"""Plan stage: seconds per sample for each session, redraw rate, and SO(3) uniformity of a
large dataset session (KS tests of the rotation angle and of each body axis).

    python -m bench plan [N]
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
from scipy import stats

from bench.common import report
from pipeline.config import load_config
from stages.common import geometry as g
from stages.plan.stage import plan_sample


def main(n_dataset: int | str = 1000) -> None:
    n_dataset = int(n_dataset)
    config = load_config("default")
    config = config.replace(plan=replace(config.plan, n_dataset=n_dataset))
    rows, timing = {}, []
    for session, count in (("calibration", config.plan.n_calibration), ("dataset", n_dataset)):
        started = time.perf_counter()
        rows[session] = [plan_sample(config, session, i, f"{session[:3]}{i:06d}") for i in range(count)]
        seconds = time.perf_counter() - started
        redraws = np.array([r["redraws"] for r in rows[session]])
        timing.append({"session": session, "samples": count, "ms_per_sample": 1000 * seconds / count,
                       "redraws_per_sample": float(redraws.mean()), "samples_redrawn": int((redraws > 0).sum())})
    report("plan_timing", "plan: time and reachability redraws (default profile)", timing)

    rotation = np.stack([g.quat_to_matrix(r["cam_from_target_q"]) for r in rows["dataset"]])
    angle = g.rotation_angle(rotation)
    uniformity = [{"statistic": "rotation angle vs Haar CDF (theta - sin theta)/pi",
                   "ks_p": float(stats.kstest(angle, lambda x: (x - np.sin(x)) / np.pi).pvalue)}]
    for column, axis in enumerate("xyz"):
        for row, component in enumerate("xyz"):
            p = stats.kstest(rotation[:, row, column], "uniform", args=(-1, 2)).pvalue
            uniformity.append({"statistic": f"body {axis} axis, camera {component} component vs U(-1, 1)",
                               "ks_p": float(p)})
    report("plan_uniformity", f"plan: SO(3) uniformity of {n_dataset} dataset orientations (p > 0.01 expected)",
           uniformity)


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
