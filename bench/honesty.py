"""Are the labels' sigmas honest? Over several virtual facilities (``virtual.seed``: other
true arms, fixtures, bases and noise), each acquired, calibrated, fused and labelled from
scratch, the share of true errors inside 1.96 sigma per camera axis, pooled and per
facility, and the share of labels under the SPEED+ thresholds.

One facility's 48 labels share one calibration, so their errors are strongly correlated
and the share inside 1.96 sigma of one facility is nearly a single draw; pooling several
independent calibrations is the fair test of the issue's 90-99% goal.

    python -m bench honesty [SEEDS] [ROOT]     (default: 4 seeds from 12, data/honesty; ~5 min each)
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from bench.accuracy import dataset_metrics
from bench.common import report
from manifests import Workspace

AXES = "xyz"


def main(seeds: str = "12,13,14,15", root: str = "data/honesty") -> None:
    rows, inside, counts = [], [], []
    for seed in (int(s) for s in seeds.split(",")):
        workspace = Path(root) / f"seed{seed}"
        result = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "--profile", "default", "--workspace",
                                 str(workspace), "--until", "label", "--set", f"virtual.seed={seed}"],
                                capture_output=True, text=True)
        if result.returncode != 0:
            raise SystemExit(result.stderr)
        metrics = dataset_metrics(Workspace(workspace))
        shares = [metrics[f"true error inside 1.96 sigma, camera {a} (fraction)"] for a in AXES]
        inside.append(shares)
        counts.append(metrics["dataset labels"])
        rows.append({"seed": seed, "labels": metrics["dataset labels"],
                     **{f"inside 1.96 sigma {a}": v for a, v in zip(AXES, shares, strict=True)},
                     "under both thresholds": metrics["both (fraction)"],
                     "rotation error max (deg)": metrics["rotation error, max (deg)"]})
    pooled = np.average(np.array(inside), axis=0, weights=counts)
    rows.append({"seed": "pooled", "labels": int(sum(counts)),
                 **{f"inside 1.96 sigma {a}": float(v) for a, v in zip(AXES, pooled, strict=True)},
                 "under both thresholds": float(np.average([r["under both thresholds"] for r in rows],
                                                           weights=counts)),
                 "rotation error max (deg)": float(max(r["rotation error max (deg)"] for r in rows))})
    report("honesty", "labels' sigmas over independent virtual facilities", rows)


if __name__ == "__main__":
    main(*sys.argv[1:])
