"""``export --format session`` (stages/export/session.py): the captures written as a lab's
logger would, and read back by ``acquire --backend replay --format session``: the same
images byte for byte, the same poses, readings, rail and times."""

from __future__ import annotations

import hashlib
import shutil

import numpy as np
import pyarrow.parquet as pq

from tests.conftest import speedplus

NOT_LOGGED = {"vicon_targetrb_used", "vicon_targetrb_residual_m", "move_s"}  # replay leaves them null
PATHS = {"image_path", "source_image", "image_conversion"}


def assert_same_row(row: dict, again: dict, skipped: set[str], tolerance: float) -> None:
    """Two captures rows alike, column by column (a quaternion up to its sign), but ``skipped``."""
    for column, value in row.items():
        if column in skipped:
            continue
        if isinstance(value, list) and value and isinstance(value[0], float):
            sign = -1.0 if column.endswith("_q") and np.dot(value, again[column]) < 0 else 1.0
            assert np.allclose(value, sign * np.asarray(again[column]), rtol=0, atol=tolerance), column
        elif isinstance(value, float):
            assert abs(value - again[column]) < tolerance, column
        else:
            assert value == again[column], (row["sample_id"], column)


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_session_export_replays_to_the_same_captures(smoke_labelled, tmp_path):
    workspace = tmp_path / "w"
    shutil.copytree(smoke_labelled.root, workspace)
    result = speedplus("export", "-w", str(workspace), "--format", "session")
    assert result.returncode == 0, result.stderr
    out = workspace / "export" / "session"
    assert {p.name for p in out.iterdir()} >= {"session.toml", "robot.csv", "mocap.csv", "images"}
    replayed = tmp_path / "replayed"
    result = speedplus("acquire", "-w", str(replayed), "--profile", "smoke", "--backend", "replay", "--format",
                       "session", "--source", str(out))
    assert result.returncode == 0, result.stderr
    before = {r["sample_id"]: r for r in pq.read_table(workspace / "manifests" / "captures").to_pylist()}
    after = {r["sample_id"]: r for r in pq.read_table(replayed / "manifests" / "captures").to_pylist()}
    assert set(before) == set(after)
    for sample_id, row in before.items():
        again = after[sample_id]
        assert _digest(workspace / row["image_path"]) == _digest(replayed / again["image_path"])
        assert_same_row(row, again, NOT_LOGGED | PATHS, 1e-12)
    # a lab's recording, run to its report: no truth to measure the labels against, and it says so
    result = speedplus("run", "-w", str(replayed))
    assert result.returncode == 0, result.stderr
    page = (replayed / "report" / "index.html").read_text()
    first = page[page.index("How good the labels are</h2>"):page.index("What the figures mean</h2>")]
    assert "A recording has no truth" in first and "cross-validated fused error" in first, first
    assert "meet both SPEED+ thresholds" not in first and "mean SPEED score" in first
