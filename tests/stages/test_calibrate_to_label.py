"""calibrate -> fuse -> label -> export on the smoke profile, and their bad inputs."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from manifests import Workspace, list_parts, read_manifest
from tests.conftest import reseal


def speedplus(*args):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True,
                          env={**os.environ, "COLUMNS": "200"}, timeout=900)


@pytest.fixture(scope="module")
def labelled(smoke_labelled):
    return smoke_labelled


TESTBED_ONLY = 'export.sets=["testbed"]'  # the smoke workspace has no renders


def copy_of(ws, tmp_path, name):
    shutil.copytree(ws.root, tmp_path / name)
    return Workspace(tmp_path / name)


def test_calibration_json_has_the_designed_layout(labelled):
    calibration = json.loads((labelled.root / "calibration.json").read_text())
    assert set(calibration["intrinsics"]) >= {"K", "dist", "width", "height", "rms_px"}
    for source, z, x in (("kuka", "cam_from_camee", "target_from_targetee"),
                         ("vicon", "cam_from_camrb", "target_from_targetrb")):
        entry = calibration[source]
        assert set(entry[z]) == {"q", "t"} and set(entry[x]) == {"q", "t"}
        assert len(entry["sigma_t_m"]) == 3 and entry["sigma_r_rad"] > 0
        for kind in ("in_sample", "cross_validated", "truth"):
            assert set(entry["metrics"][kind]) == {"E_T_m", "E_R_rad", "E_p_px"}
    assert set(calibration["kuka"]["target_from_targetee_by_fixture"]) == {"minus_x", "plus_x"}
    assert len(calibration["rejection"]["sigma_t_m"]) == 3
    assert calibration["fused"]["metrics"]["in_sample"]["E_T_m"][0] > 0


def test_calibrated_offsets_are_close_to_the_hidden_truth(labelled):
    calibration = json.loads((labelled.root / "calibration.json").read_text())
    truth = json.loads(labelled.truth_path.read_text())
    estimated, true = np.array(calibration["kuka"]["cam_from_camee"]["t"]), np.array(truth["cam_from_camee"]["t"])
    assert np.linalg.norm(estimated - true) < 0.01  # a few mm from 16 tiny images
    assert calibration["kuka"]["metrics"]["truth"]["E_T_m"][0] < 0.01


def test_labels(labelled):
    labels = read_manifest(labelled, "labels").to_pylist()
    poses = {p["sample_id"]: p for p in read_manifest(labelled, "poses").to_pylist()}
    assert len(labels) == 8 and set(poses) == {r["sample_id"] for r in labels}
    for row in labels:
        pose = poses[row["sample_id"]]
        assert row["label_source"] == ("fused" if pose["vicon_accepted"] else "kuka_only")
        assert pose["vicon_accepted"] == (pose["reject_reason"] is None)
        keypoints = np.array(row["keypoints_px"])
        assert keypoints.shape == (11, 2) and np.all((keypoints > 0) & (keypoints < [320, 200]))
        np.testing.assert_allclose(row["bbox_px"], [*keypoints.min(axis=0), *keypoints.max(axis=0)])
        assert 6.0 < np.linalg.norm(row["r_Vo2To_vbs_true"]) < 10.0  # full scale


def test_export_records_every_copy_resumes_and_stays_in_its_folder(labelled, tmp_path):
    ws = copy_of(labelled, tmp_path, "exporting")
    out = tmp_path / "out"
    # the copied workspace recorded an export to another folder: this one replaces that record
    assert speedplus("export", "-w", str(ws.root), "--out", str(out), "--set", TESTBED_ONLY).returncode == 0
    rows = read_manifest(ws, "export_speedplus").to_pylist()
    assert len(rows) == read_manifest(ws, "labels").num_rows and all((out / r["file"]).is_file() for r in rows)
    annotations = (out / "lightbox" / "test.json").read_bytes()
    # a killed export: some images copied but not recorded, the marker not written
    for part in list_parts(ws, "export_speedplus"):
        part.unlink()
    ws.marker_path("export_speedplus").unlink()
    (out / rows[0]["file"]).unlink()
    (out / "lightbox" / "test.json").unlink()
    again = speedplus("export", "-w", str(ws.root), "--out", str(out))  # the same command resumes
    assert again.returncode == 0, again.stderr
    assert all((out / r["file"]).is_file() for r in rows)
    assert (out / "lightbox" / "test.json").read_bytes() == annotations
    assert "up to date" in speedplus("export", "-w", str(ws.root), "--out", str(out)).stdout
    # a labels file edited to climb out of the export folder
    part = list_parts(ws, "labels")[0]
    table = pq.read_table(part)
    names = table.column("filename").to_pylist()
    names[0] = "../../escaped.png"
    pq.write_table(table.set_column(table.schema.get_field_index("filename"), "filename", pa.array(names)), part)
    reseal(ws, "labels")
    bad = speedplus("export", "-w", str(ws.root), "--out", str(out), "--force")
    message = " ".join(bad.stderr.split())
    assert bad.returncode == 1 and "would leave the export folder" in message and "Traceback" not in message
    assert not (tmp_path / "escaped.png").exists() and not (out.parent.parent / "escaped.png").exists()


def test_fuse_and_label_never_open_the_truth(labelled, tmp_path):
    blind = copy_of(labelled, tmp_path, "blind")
    shutil.rmtree(blind.manifest_dir("truth"))
    blind.truth_path.unlink()
    for stage in ("fuse", "label"):
        result = speedplus(stage, "--workspace", str(blind.root), "--force")
        assert result.returncode == 0, result.stderr
    for name in ("poses", "labels"):
        expected = read_manifest(labelled, name).sort_by("sample_id")
        assert read_manifest(blind, name).sort_by("sample_id").equals(expected)


def test_one_source_is_enough(labelled, tmp_path):
    ws = copy_of(labelled, tmp_path, "kuka_only")
    session = json.loads(ws.session_path.read_text())
    session["sources"] = ["kuka"]
    ws.session_path.write_text(json.dumps(session))
    for stage in ("calibrate", "fuse", "label"):
        result = speedplus(stage, "--workspace", str(ws.root), "--force")
        assert result.returncode == 0, result.stderr
    calibration = json.loads((ws.root / "calibration.json").read_text())
    assert calibration["vicon"] is None and calibration["fused"] is None
    poses = read_manifest(ws, "poses").to_pylist()
    assert all(not p["vicon_accepted"] and p["reject_reason"] == "no motion capture in this session" for p in poses)
    assert {r["label_source"] for r in read_manifest(ws, "labels").to_pylist()} == {"kuka_only"}


def test_too_few_detections_is_a_clear_error(labelled, tmp_path):
    ws = copy_of(labelled, tmp_path, "few")
    result = speedplus("calibrate", "--workspace", str(ws.root), "--force", "--set", "calibrate.min_corners=500")
    assert result.returncode == 1
    assert "0 usable calibration samples, at least 8 needed" in " ".join(result.stderr.split())


def test_captures_not_in_the_plan_are_refused(labelled, tmp_path):
    ws = copy_of(labelled, tmp_path, "stranger")
    part = list_parts(ws, "captures")[0]
    table = pq.read_table(part)
    ids = table.column("sample_id").to_pylist()
    ids[0] = "cal999999"
    table = table.set_column(0, table.schema.field(0), pa.array(ids))
    pq.write_table(table, part)
    reseal(ws, "captures")
    result = speedplus("calibrate", "--workspace", str(ws.root), "--force")
    assert result.returncode == 1 and "cal999999 are not in the plan" in " ".join(result.stderr.split())


def test_non_finite_telemetry_names_file_row_and_column(labelled, tmp_path):
    ws = copy_of(labelled, tmp_path, "nan")
    part = list_parts(ws, "captures")[0]
    table = pq.read_table(part)
    index = table.column_names.index("kuka_world_from_camee_t")
    values = table.column(index).to_pylist()
    values[1] = [0.0, float("nan"), 1.0]
    table = table.set_column(index, table.schema.field(index), pa.array(values, type=table.schema.field(index).type))
    pq.write_table(table, part)
    reseal(ws, "captures")
    result = speedplus("calibrate", "--workspace", str(ws.root), "--force")
    message = " ".join(result.stderr.split())
    assert result.returncode == 1
    assert "part-00000.parquet, row 1" in message and "kuka_world_from_camee_t" in message and "not finite" in message


@pytest.mark.parametrize("text", ["{", '{"calibration_lever_sq_m2": [0, 0, 0], "kuka": {}}', '{"version": 1}'])
def test_unreadable_calibration_stops_fuse_naming_the_file(labelled, tmp_path, text):
    ws = copy_of(labelled, tmp_path, "broken")
    (ws.root / "calibration.json").write_text(text)
    result = speedplus("fuse", "--workspace", str(ws.root), "--force")
    assert result.returncode == 1, result.stderr
    message = " ".join(result.stderr.split())  # the console wraps long lines
    assert "calibration.json" in message and "rerun calibrate" in message
    assert "Traceback" not in message


def test_calibration_does_not_depend_on_the_order_acquire_wrote_the_captures(labelled, tmp_path):
    """Acquire's workers finish in any order; calibrate's folds and sums must not follow it."""
    from manifests.io import part_fingerprints, write_part

    ws = copy_of(labelled, tmp_path, "reversed")
    captures = read_manifest(ws, "captures")
    (fingerprint,) = part_fingerprints(ws, "captures")
    for part in list_parts(ws, "captures"):
        part.unlink()
    write_part(ws, "captures", captures.take(list(range(captures.num_rows))[::-1]), fingerprint)
    reseal(ws, "captures")
    assert read_manifest(ws, "captures").column("sample_id").to_pylist()[0] == captures.column("sample_id")[-1].as_py()
    result = speedplus("calibrate", "-w", str(ws.root), "--force")
    assert result.returncode == 0, result.stderr
    assert (ws.root / "calibration.json").read_bytes() == (labelled.root / "calibration.json").read_bytes()


def test_same_seed_same_bytes_whatever_the_worker_count(labelled, tmp_path):
    """Acquire's workers finish in another order with two workers than with the smoke
    profile's one; every manifest and JSON file up to the labels must still be the same bytes."""
    from pipeline.config import load_config

    assert load_config("smoke").run.workers == 1  # the reference ran in one process
    other = tmp_path / "two-workers"
    result = speedplus("run", "--profile", "smoke", "--workspace", str(other), "--until", "label",
                       "--set", "run.workers=2", "--set", "run.part_rows=5")
    assert result.returncode == 0, result.stderr
    for name in ("plan", "captures", "truth", "calibration_samples", "poses", "labels"):
        mine = [p.read_bytes() for p in list_parts(Workspace(other), name)]
        assert mine == [p.read_bytes() for p in list_parts(labelled, name)], name
    for name in ("session.json", "calibration.json", "fusion.json", "truth.json"):
        assert (other / name).read_bytes() == (labelled.root / name).read_bytes(), name
