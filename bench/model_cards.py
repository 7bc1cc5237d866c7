"""Add a workspace's Table 2 to the shipped models' cards (``models/<name>.json``).

    python -m bench model_cards data/default17

Reads the workspace's ``scores`` manifest (``speedplus evaluate`` with the shipped models)
and writes, into each model's card, the mean SPEED score with its 95% interval, the median
SPEED score and rotation error, and the shares of failures and without a pose per crop,
domain and configuration, with the workspace's profile and the
digest of the model that was scored (a card never describes another model's results).
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from bench.common import report
from manifests import Workspace, read_manifest
from manifests.files import write_json_atomic
from manifests.integrity import sha256

MODELS = Path(__file__).resolve().parents[1] / "models"


def main(*args: str) -> None:
    if not args:
        raise SystemExit("usage: python -m bench model_cards WORKSPACE")
    workspace = Workspace(args[0])
    profile = tomllib.loads(workspace.config_path.read_text())["profile"]
    scores = read_manifest(workspace, "scores").to_pylist()
    rows = []
    for path in sorted(MODELS.glob("*.onnx")):
        name = path.stem
        mine = [row for row in scores if row["model"] == name]
        if not mine:
            continue
        card_path = path.with_suffix(".json")
        card = json.loads(card_path.read_text())
        table = {}
        for row in mine:
            table[row["group"].split("/", 1)[1]] = {
                "images": row["count"], "mean_speed_score": round(row["mean_score_speed"], 4),
                "mean_speed_score_95": [round(row["mean_score_speed_low"], 4), round(row["mean_score_speed_high"], 4)],
                "median_speed_score": round(row["median_score_speed"], 4),
                "failure_share": round(row["failure_share"], 4),
                "median_rotation_error_deg": round(row["median_err_q_deg"], 3),
                "no_pose_share": round(1 - row["pose_found_share"], 4),
                **({"mean_box_iou": round(row["mean_box_iou"], 3)} if row["mean_box_iou"] is not None else {})}
        card["table2"] = {"profile": profile, "model_sha256": sha256(path), "groups": table}
        write_json_atomic(card_path, card)
        for crop in ("oracle_box", "self"):
            synthetic, testbed = table.get(f"{crop}/synthetic/all/all"), table.get(f"{crop}/testbed/all/all")
            if synthetic and testbed:
                rows.append({"model": name, "crop": crop, "synthetic": synthetic["mean_speed_score"],
                             "testbed": testbed["mean_speed_score"],
                             "gap": round(testbed["mean_speed_score"] - synthetic["mean_speed_score"], 4)})
    report("model_cards", f"Table 2 ({profile} profile) written into the model cards", rows)
