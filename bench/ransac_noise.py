"""How much of Table 2 is RANSAC's draw: a finished workspace's ``evaluate`` redone on
copies of it with other ``evaluate.ransac_seed`` values, every model and crop; per model,
crop and domain (testbed or twins), the mean SPEED score of each seed and their spread. A
difference between two runs, models or versions on the same images that is no larger than
this spread is the draw's, not the models'.

    python -m bench ransac_noise WORKSPACE [SEEDS] [--against OTHER]

SEEDS: comma-separated (default 1,2), besides the workspace's own. ``--against`` adds the
same figures of another workspace holding predictions of the same images (e.g. one
evaluated by an earlier commit) and its difference to the workspace's own. The copies are
made in a temporary folder and removed; WORKSPACE is only read. Results:
bench/results/ransac_noise.json.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from bench.common import report
from pipeline.config import load_config


def _means(root: Path) -> dict[tuple[str, str, str], float]:
    """Mean SPEED score per (model, crop, testbed|twins) over a workspace's predictions."""
    rows = pq.read_table(root / "manifests" / "predictions",
                         columns=["model", "crop", "domain", "score_speed"]).to_pylist()
    groups: dict[tuple[str, str, str], list[float]] = {}
    for row in rows:
        domain = "twins" if row["domain"] == "synthetic" else "testbed"
        groups.setdefault((row["model"], row["crop"], domain), []).append(row["score_speed"])
    return {key: float(np.mean(values)) for key, values in sorted(groups.items())}


def _with_seed(workspace: Path, seed: int, scratch: Path) -> dict[tuple[str, str, str], float]:
    """``_means`` of a copy of the workspace evaluated afresh with RANSAC seed ``seed``."""
    copy = scratch / f"seed{seed}"
    shutil.copytree(workspace, copy, ignore=shutil.ignore_patterns("report", "export"))
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", "evaluate", "--workspace", str(copy), "--force",
                           "--set", f"evaluate.ransac_seed={seed}"], capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"evaluate with seed {seed} failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
    means = _means(copy)
    shutil.rmtree(copy)
    return means


def main(*args: str) -> None:
    if not args:
        sys.exit(__doc__)
    workspace, rest = Path(args[0]).resolve(), list(args[1:])
    options = {}
    if "--against" in rest:
        at = rest.index("--against")
        if at + 1 >= len(rest):
            sys.exit("--against needs a workspace")
        options["--against"] = rest.pop(at + 1)
        rest.pop(at)
    if not (workspace / "manifests" / "predictions").exists():
        sys.exit(f"{workspace}: not an evaluated workspace (no manifests/predictions)")
    if rest and not all(s.isdigit() for s in rest[0].split(",")):
        sys.exit(f"SEEDS: expected comma-separated non-negative integers, got {rest[0]!r}")
    seeds = [int(s) for s in rest[0].split(",")] if rest else [1, 2]
    own_seed = load_config(None, workspace / "config.toml").evaluate.ransac_seed
    own = _means(workspace)
    with tempfile.TemporaryDirectory(dir=workspace.parent) as scratch:
        by_seed = {own_seed: own, **{seed: _with_seed(workspace, seed, Path(scratch)) for seed in seeds}}
    against = _means(Path(options["--against"]).resolve()) if "--against" in options else {}
    rows: list[dict[str, Any]] = []
    for key in own:
        values = [means[key] for means in by_seed.values() if key in means]
        row: dict[str, Any] = {"model / crop / domain": " / ".join(key)}
        row |= {f"seed {seed}": means.get(key, float("nan")) for seed, means in by_seed.items()}
        row["spread over seeds"] = max(values) - min(values)
        if against:
            row["--against"] = against.get(key, float("nan"))
            row["own - against"] = own[key] - against.get(key, float("nan"))
        rows.append(row)
    report("ransac_noise", f"mean SPEED score by RANSAC seed: {workspace}", rows,
           {"seeds": list(by_seed), "against": options.get("--against", "")})
