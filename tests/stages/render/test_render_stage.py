"""`speedplus render` on the smoke profile: twins, bad labels, engines, resume, training set."""

import json
import shutil

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from manifests import Workspace, list_parts, read_manifest
from pipeline.config import load_config
from tests.conftest import reseal, speedplus

VOLATILE = ("seconds",)  # wall time: the only column allowed to differ between two runs


def copy_of(ws, tmp_path, name):
    shutil.copytree(ws.root, tmp_path / name, ignore=shutil.ignore_patterns("renders"))
    shutil.rmtree(tmp_path / name / "manifests" / "renders", ignore_errors=True)
    return Workspace(tmp_path / name)


@pytest.fixture(scope="module")
def twins(smoke_labelled, tmp_path_factory):
    ws = copy_of(smoke_labelled, tmp_path_factory.mktemp("twins"), "w")
    result = speedplus("render", "--workspace", str(ws.root))
    assert result.returncode == 0, result.stderr
    return ws


def stable(table):
    return table.drop_columns(list(VOLATILE)).sort_by("sample_id")


def same_files(a, b, paths):
    return all(a.resolve(p).read_bytes() == b.resolve(p).read_bytes() for p in paths)


def test_a_twin_for_every_label(twins):
    labels = read_manifest(twins, "labels").to_pylist()
    renders = {r["sample_id"]: r for r in read_manifest(twins, "renders").to_pylist()}
    assert set(renders) == {label["sample_id"] for label in labels}
    calibration = json.loads((twins.root / "calibration.json").read_text())["intrinsics"]
    captures = {r["sample_id"]: r["image_path"] for r in read_manifest(twins, "captures").to_pylist()}
    for label in labels:
        render = renders[label["sample_id"]]
        image = cv2.imread(str(twins.resolve(render["image_path"])), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(twins.resolve(render["mask_path"])), cv2.IMREAD_UNCHANGED)
        # the default camera is mono: a grey twin, as its capture
        assert image.shape == (calibration["height"], calibration["width"]) and mask.shape == image.shape
        capture = cv2.imread(str(twins.resolve(captures[label["sample_id"]])), cv2.IMREAD_UNCHANGED)
        assert capture.shape == image.shape
        assert (mask == 255).sum() > 100 and set(np.unique(mask)) <= {0, 255}
        near_model = cv2.dilate(mask, np.ones((5, 5), np.uint8)) > 0  # edge pixels are partly covered
        # empty space around the model; only antennas thinner than half a pixel show outside the mask
        assert (image[~near_model] > 0).sum() < 0.02 * (mask == 255).sum()
        assert image[mask == 255].mean() > 5  # the model is lit
        np.testing.assert_allclose(render["q_vbs2tango_true"], label["q_vbs2tango_true"])
        np.testing.assert_allclose(render["r_Vo2To_vbs_true"], label["r_Vo2To_vbs_true"])
        np.testing.assert_allclose(render["keypoints_px"], label["keypoints_px"], atol=1e-9)
        assert np.linalg.norm(render["light_dir_cam"]) == pytest.approx(1.0)
    assert json.loads((twins.root / "renders" / "twins" / "rejected.json").read_text()) == []


def test_sunlamp_twins_are_lit_from_the_lamp(twins):
    config = load_config(None, twins.config_path)
    plan = {r["sample_id"]: r for r in read_manifest(twins, "plan").to_pylist()}
    from stages.acquire.virtual import VirtualTestbed, robots

    testbed = VirtualTestbed(config, twins)
    for render in read_manifest(twins, "renders").to_pylist():
        sample = plan[render["sample_id"]]
        if sample["light"] != "sunlamp":
            continue
        state = robots.move(config, testbed.truth, sample, np.random.default_rng(
            [config.virtual.seed, 1, int(sample["sample_id"][3:])]))
        towards = np.asarray(config.testbed.sun_lamp_position_m) - state.world_from_target[:3, 3]
        true_dir = g_rot(state.world_from_cam).T @ (towards / np.linalg.norm(towards))
        angle = np.degrees(np.arccos(np.clip(np.dot(true_dir, render["light_dir_cam"]), -1, 1)))
        assert angle < 1.0  # aligned with the lamp within the calibration's accuracy


def g_rot(transform):
    return np.asarray(transform)[:3, :3]


def test_bad_labels_are_rejected_with_their_reason_and_the_rest_rendered(smoke_labelled, tmp_path):
    ws = copy_of(smoke_labelled, tmp_path, "bad")
    part = list_parts(ws, "labels")[0]
    table = pq.read_table(part)
    rows = table.to_pylist()
    bad_q, behind = rows[0]["sample_id"], rows[1]["sample_id"]
    rows[0]["q_vbs2tango_true"] = [0.9, 0.1, 0.0, 0.0]
    rows[1]["r_Vo2To_vbs_true"] = [0.0, 0.0, -7.0]
    pq.write_table(pa.Table.from_pylist(rows, schema=table.schema), part)
    reseal(ws, "labels")
    result = speedplus("render", "--workspace", str(ws.root))
    assert result.returncode == 0, result.stderr
    assert f"{bad_q} not rendered: quaternion is not unit" in result.stderr.replace("\n", " ")
    rejected = json.loads((ws.root / "renders" / "twins" / "rejected.json").read_text())
    assert {r["sample_id"] for r in rejected} == {bad_q, behind}
    assert "behind the camera" in next(r["reason"] for r in rejected if r["sample_id"] == behind)
    rendered = set(read_manifest(ws, "renders").column("sample_id").to_pylist())
    all_ids = set(read_manifest(ws, "labels", validate=False).column("sample_id").to_pylist())
    assert rendered == all_ids - {bad_q, behind}


def test_interrupted_render_resumes_without_duplicates(twins, smoke_labelled, tmp_path):
    ws = copy_of(smoke_labelled, tmp_path, "killed")
    # two spawned workers (the smoke profile renders in one process): killed with their driver, they
    # must not outlive it holding its pipes, and the twins they rendered are the one process's bytes
    killed = speedplus("render", "--workspace", str(ws.root), "--workers", "2",
                       env={"SPEEDPLUS_FAULT_KILL_AT_PART": "2"})
    assert killed.returncode == -9 and len(list_parts(ws, "renders")) == 1
    recorded = pq.read_table(list_parts(ws, "renders")[0]).to_pylist()[0]
    ws.resolve(recorded["ground_truth_path"]).unlink()  # a file lost after its row was recorded
    resumed = speedplus("render", "--workspace", str(ws.root))
    assert resumed.returncode == 0 and "resumed" in resumed.stdout, resumed.stderr
    assert f"name files that are missing ({recorded['ground_truth_path']}" in resumed.stderr.replace("\n", "")
    assert ws.resolve(recorded["ground_truth_path"]).read_bytes() == twins.resolve(
        recorded["ground_truth_path"]).read_bytes()
    got, reference = read_manifest(ws, "renders"), read_manifest(twins, "renders")
    assert stable(got).equals(stable(reference))  # every label once, same rows
    paths = got.column("image_path").to_pylist() + got.column("mask_path").to_pylist()
    assert same_files(ws, twins, paths)


def test_training_set_is_reproducible_and_separate_from_the_twins(twins, tmp_path):
    args = ["--set", "train", "--count", "6", "--set", "render.train_resolution_scale=0.5"]
    first = speedplus("render", "--workspace", str(twins.root), *args)
    assert first.returncode == 0, first.stderr
    other = Workspace(tmp_path / "other")
    second = speedplus("render", "--profile", "smoke", "--workspace", str(other.root), *args)
    assert second.returncode == 0, second.stderr
    train = read_manifest(twins, "train")
    assert train.num_rows == 6 and set(train.column("set").to_pylist()) == {"train"}
    paths = train.column("image_path").to_pylist() + train.column("mask_path").to_pylist()
    assert all(p.startswith("renders/train/") for p in paths)
    assert same_files(twins, other, paths)
    assert stable(train).equals(stable(read_manifest(other, "train")))
    backgrounds = {True: [], False: []}
    for row in train.to_pylist():
        image = cv2.imread(str(twins.resolve(row["image_path"])))
        mask = cv2.imread(str(twins.resolve(row["mask_path"])), cv2.IMREAD_UNCHANGED)
        assert image.shape[:2] == (100, 160) and (mask == 255).any()
        backgrounds[row["earth"]].append(image[cv2.dilate(mask, np.ones((5, 5), np.uint8)) == 0].mean())
    assert backgrounds[True] and backgrounds[False]
    assert max(backgrounds[False]) < 0.2 and min(backgrounds[True]) > 1  # space is black (but for thin antennas)
    # the twins are untouched, and the workspace's configuration still renders twins
    assert read_manifest(twins, "renders").num_rows == 8
    assert load_config(None, twins.config_path).render.set == "twin"
    status = speedplus("status", "--workspace", str(twins.root))
    assert "render" in status.stdout and "stale" not in status.stdout


def test_unreadable_calibration_is_an_error_naming_the_file(smoke_labelled, tmp_path):
    ws = copy_of(smoke_labelled, tmp_path, "broken")
    (ws.root / "calibration.json").write_text("{")
    result = speedplus("render", "--workspace", str(ws.root))
    assert result.returncode == 1 and "calibration.json" in result.stderr and "not valid JSON" in result.stderr
    assert "Traceback" not in result.stderr
