"""Rendezvous sequences tracked (docs/sequences.md, "The default profile"): a trajectory
workspace on the default profile (two sequences of 24 frames, Tango) made, or resumed, with
`speedplus run` and the shipped reference models, then per model, crop, sequence and
domain the mean SPEED score per frame against the tracking baseline's
(``stages/evaluate/tracks.py``), and the frames its attitude filter took.

    python -m bench tracking [ROOT]     (default data/bench_tracking; about 4-5 min on 2 cores to make)
"""

from __future__ import annotations

import subprocess
import sys
from itertools import groupby
from pathlib import Path

import numpy as np

from bench.common import report
from manifests import Workspace, read_manifest


def main(root: str = "data/bench_tracking") -> None:
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", "--profile", "default", "--workspace",
                             root, "--set", "plan.mode=trajectory"], capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(result.stderr)
    rows = sorted(read_manifest(Workspace(Path(root)), "tracks").to_pylist(),
                  key=lambda r: (r["model"], r["crop"], r["sequence_id"], r["domain"], r["frame"]))
    out = []
    for (model, crop, sequence_id, domain), group in groupby(
            rows, key=lambda r: (r["model"], r["crop"], r["sequence_id"], r["domain"])):
        group = list(group)
        out.append({"model": model, "crop": crop, "sequence": sequence_id, "domain": domain, "frames": len(group),
                    "mean SPEED per frame": float(np.mean([r["frame_score_speed"] for r in group])),
                    "mean SPEED tracked": float(np.mean([r["score_speed"] for r in group])),
                    "attitude filter took": f"{sum(r['rotation_used'] for r in group)}/{len(group)}"})
    report("tracking", "rendezvous sequences: per-frame against tracked mean SPEED (default profile, trajectory)",
           out)


if __name__ == "__main__":
    main(*sys.argv[1:])
