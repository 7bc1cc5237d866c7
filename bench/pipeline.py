"""The whole pipeline's time, stage by stage, against an earlier commit: ``speedplus run``
of one profile with the commit's code (a temporary worktree) and with this tree, each on a
fresh workspace, one after the other on the same machine; then what the speed-ups moved in
what users read (Table 1's figures, Table 2's mean SPEED scores).

    python -m bench pipeline REF [--profile default] [--root data/bench_pipeline] [--until STAGE]

The two workspaces are kept under ROOT (``before``, ``after``) for the benchmarks that judge
a finished workspace (``bench acquire ROOT/after``). Results: bench/results/pipeline.json.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from bench.common import report
from bench.identity import REPO, worktree_env

#: what a run leaves under ROOT (and a rerun replaces)
_OWN = ("before", "after", "tree")
_STAGE_TIME = re.compile(r"^(\w+): ran in ([0-9.]+) s", re.MULTILINE)


def timed_run(code: Path, profile: str, workspace: Path, until: str | None = None) -> dict[str, float]:
    """Seconds of each stage (as the CLI prints them) and in all of ``speedplus run``
    (``--until`` ``until``, where given)."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
                           "from pipeline.cli import main; sys.argv = ['speedplus'] + sys.argv[2:]; main()",
                           str(code), "run", "--profile", profile, "--workspace", str(workspace),
                           *(("--until", until) if until else ())],
                          cwd=code, env=worktree_env(code), capture_output=True, text=True)
    total = time.perf_counter() - started
    if done.returncode != 0:
        sys.exit(f"speedplus run with {code} failed ({done.returncode}):\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
    return {**{stage: float(seconds) for stage, seconds in _STAGE_TIME.findall(done.stdout)}, "total": total}


def _table1(root: Path) -> dict[str, float]:
    """Table 1's means (mm, deg, px) per source and kind (none before calibrate)."""
    if not (root / "calibration.json").is_file():
        return {}
    calibration = json.loads((root / "calibration.json").read_text())
    out = {}
    for source in ("kuka", "vicon", "fused"):
        for kind, metrics in ((calibration.get(source) or {}).get("metrics") or {}).items():
            for key, factor in (("E_T_m", 1e3), ("E_R_rad", 57.29577951308232), ("E_p_px", 1.0)):
                if metrics and metrics.get(key):
                    out[f"Table 1 {source} {kind} {key.split('_')[1]}"] = metrics[key][0] * factor
    return out


def _table2(root: Path) -> dict[str, float]:
    """Table 2's mean SPEED score of each model, crop and domain over all views and lights."""
    if not (root / "manifests" / "scores").is_dir():
        return {}
    rows = pq.read_table(root / "manifests" / "scores").to_pylist()
    return {f"Table 2 {r['model']} {r['crop']} {r['domain']}": r["mean_score_speed"] for r in rows
            if r["view"] == "all" and r["light"] == "all"}


def _crop_seconds(root: Path) -> dict[str, float]:
    """Evaluate's mean seconds per prediction of each crop (the ``seconds`` column: a
    batch's time over its items, in its worker; a batch that holds both crops, where the
    images of a model are not a multiple of ``evaluate.batch_size``, counts alike for both)."""
    if not (root / "manifests" / "predictions").is_dir():
        return {}
    rows = pq.read_table(root / "manifests" / "predictions", columns=["crop", "seconds"]).to_pylist()
    crops = sorted({row["crop"] for row in rows})
    return {f"evaluate {crop} crop [s per prediction]": sum(r["seconds"] for r in rows if r["crop"] == crop)
            / sum(1 for r in rows if r["crop"] == crop) for crop in crops}


def main(*args: str) -> None:
    if not args:
        sys.exit(__doc__)
    ref, options = args[0], dict(zip(args[1::2], args[2::2], strict=True))
    profile = options.get("--profile", "default")
    root = Path(options.get("--root", REPO / "data" / "bench_pipeline")).resolve()
    # only this benchmark's own earlier results are replaced, never a folder of something else
    strangers = sorted(p.name for p in root.iterdir() if p.name not in _OWN) if root.is_dir() else []
    if root.exists() and (not root.is_dir() or strangers):
        sys.exit(f"{root}: holds {', '.join(strangers) or 'a file'}, not only this benchmark's "
                 f"{', '.join(_OWN)}; give an empty or new --root")
    for name in _OWN:
        shutil.rmtree(root / name, ignore_errors=True)
    root.mkdir(parents=True, exist_ok=True)
    tree = root / "tree"
    added = subprocess.run(["git", "worktree", "add", "--detach", str(tree), ref], cwd=REPO, capture_output=True,
                           text=True)
    if added.returncode != 0:
        sys.exit(f"cannot check out {ref!r}: {added.stderr.strip()}")
    try:
        before = timed_run(tree, profile, root / "before", options.get("--until"))
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=REPO, check=False)
    after = timed_run(REPO, profile, root / "after", options.get("--until"))
    rows: list[dict[str, Any]] = [
        {"what": f"{stage} [s]", "before": before.get(stage, 0.0), "after": after.get(stage, 0.0),
         "ratio": after.get(stage, 0.0) / before[stage] if before.get(stage) else float("nan")}
        for stage in before]
    for figures in (_crop_seconds, _table1, _table2):
        old, new = figures(root / "before"), figures(root / "after")
        rows += [{"what": name, "before": old[name], "after": new.get(name, float("nan")),
                  "ratio": new.get(name, float("nan")) / old[name] if old[name] else float("nan")} for name in old]
    report("pipeline", f"speedplus run --profile {profile}: {ref} against this tree", rows,
           {"before_ref": ref, "profile": profile})
