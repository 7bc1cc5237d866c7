"""Nothing a user sees changes across a refactoring: run the default profile with an
earlier commit and with this tree, and compare what users read, byte for byte or digest
for digest (issue 11: Table 1, Table 2, the labels and the twin images).

    python -m bench identity REF [--before W] [--after W]

``REF`` is the earlier commit (checked out in a temporary worktree, run with its own code);
``--before`` / ``--after`` reuse workspaces already made by ``speedplus run --profile
default``. Each run takes about ten minutes on a 2-core machine. Results:
bench/results/identity.json (the digests of both, and whether they are equal).
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from bench.common import report

REPO = Path(__file__).resolve().parents[1]


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _rows(root: Path, name: str, key: str, drop: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """A manifest's rows in key order, read with pyarrow alone (no code of either version)."""
    table = pq.read_table(root / "manifests" / name)
    rows = [{k: v for k, v in row.items() if k not in drop} for row in table.to_pylist()]
    return sorted(rows, key=lambda row: row[key])


def _files(root: Path, rows: list[dict[str, Any]], *columns: str) -> str:
    """Digest of the bytes of every file the rows point to, in row order."""
    digest = hashlib.sha256()
    for row in rows:
        for column in columns:
            digest.update((root / row[column]).read_bytes())
    return digest.hexdigest()[:16]


def _table1(root: Path) -> list[list[Any]]:
    """Table 1's cells as calibrate prints them (mean and std per metric and column)."""
    calibration = json.loads((root / "calibration.json").read_text())
    out = []
    for column in ("kuka", "vicon", "fused"):
        entry = calibration.get(column)
        for kind in ("in_sample", "cross_validated", "truth"):
            metrics = (entry or {}).get("metrics", {}).get(kind) or {}
            out.append([column, kind, *(metrics.get(key) for key in ("E_T_m", "E_R_rad", "E_p_px"))])
    return out


def _printed(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Table 2's numbers as evaluate and the report print them."""
    return [{k: f"{v:.4f}" if isinstance(v, float) else v for k, v in row.items()} for row in rows]


def outputs(root: Path) -> dict[str, str]:
    """What users read of a default-profile workspace, as digests."""
    labels = _rows(root, "labels", "sample_id")
    renders = _rows(root, "renders", "sample_id", drop=("seconds",))
    return {
        "Table 1 (calibration.json metrics)": _digest(_table1(root)),
        "Table 2 as printed (4 decimals)": _digest(_printed(_rows(root, "scores", "group"))),
        "Table 2 (scores manifest, every bit)": _digest(_rows(root, "scores", "group")),
        "labels (every column)": _digest(labels),
        "testbed captures (bytes)": _files(root, _rows(root, "captures", "sample_id"), "image_path"),
        "twin images and masks (bytes)": _files(root, renders, "image_path", "mask_path"),
        "renders rows (timings dropped)": _digest(renders),
        "predictions (timings dropped)": _digest(_rows(root, "predictions", "prediction_id", drop=("seconds",))),
        "poses": _digest(_rows(root, "poses", "sample_id")),
    }


def worktree_env(code: Path) -> dict[str, str]:
    """The environment that runs ``code``'s pipeline (its packages first on the path)."""
    return {**os.environ, "PYTHONPATH": str(code), "COLUMNS": "200"}


def _run_default(code: Path, workspace: Path) -> None:
    env = worktree_env(code)
    subprocess.run([sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); from pipeline.cli import main;"
                    " sys.argv = ['speedplus'] + sys.argv[2:]; main()", str(code), "run", "--profile", "default",
                    "--workspace", str(workspace)], check=True, cwd=code, env=env)


def main(*args: str) -> None:
    if not args:
        sys.exit(__doc__)
    ref, options = args[0], dict(zip(args[1::2], args[2::2], strict=True))
    scratch = Path(tempfile.mkdtemp(prefix="identity-"))
    before = Path(options["--before"]) if "--before" in options else None
    after = Path(options["--after"]) if "--after" in options else None
    if before is None:
        tree = scratch / "tree"
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), ref], cwd=REPO, check=True)
        before = scratch / "before"
        try:
            _run_default(tree, before)
        finally:  # the repository keeps no stray worktree (its workspaces stay in scratch)
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=REPO, check=False)
    if after is None:
        after = scratch / "after"
        _run_default(REPO, after)
    old, new = outputs(before), outputs(after)
    rows = [{"output": name, "before": old[name], "after": new[name], "identical": old[name] == new[name]}
            for name in old]
    report("identity", f"default profile: {ref} against this tree", rows, {"before_ref": ref})
    if not all(row["identical"] for row in rows):
        sys.exit("outputs differ")
