"""A workspace's target: ``plan --target DIR`` plans for a stranger's object and copies
it into ``W/target``, the later stages read that copy (not the lab's folder), its content
is in every fingerprint, and a bad folder or a retired setting is refused before anything
is written."""

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from core.config import ConfigError
from manifests import Workspace, read_manifest
from manifests.target import TARGET_FILE, target_digest, target_files
from pipeline import registry, runner
from pipeline.config import load_config
from stages.common import geometry as g
from stages.common.workspace_target import digest, workspace_folder, workspace_target
from stages.label.stage import label_row
from tests.target_folders import boulder, cubesat


def speedplus(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True,
                          env={**os.environ, "COLUMNS": "200"}, cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """A smoke plan of the full-size CubeSat mock-up (GLB, mm, no keypoints), made with
    --target, at SPEED+'s distances in Tango diameters (6.5-9.5 m of 1.37 m)."""
    root = tmp_path_factory.mktemp("cubesat")
    source = cubesat(root / "lab" / "cubesat")
    ws = root / "w"
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(ws), "--target", str(source), "--set",
                       "plan.dataset_range_m=[0, 1e9]", "--set", "plan.dataset_range_diameters=[4.75, 6.94]")
    assert result.returncode == 0, result.stderr
    return source, Workspace(ws)


def test_plan_copies_the_target_and_the_later_stages_read_the_copy(planned):
    source, ws = planned
    copy = ws.root / "target"
    assert target_files(copy) == target_files(source) == ["cubesat.glb", TARGET_FILE]
    assert target_digest(copy) == target_digest(source)
    config = load_config(None, ws.config_path)
    assert config.target.path == str(source)
    # the lab moves its folder away: the workspace keeps its own copy
    moved = source.parent / "elsewhere"
    shutil.move(source, moved)
    try:
        assert workspace_folder(config, ws) == copy
        assert workspace_target(config, ws).name == "cubesat6u"
    finally:
        shutil.move(moved, source)


def test_the_plan_is_of_the_stranger_target(planned):
    _, ws = planned
    config = load_config(None, ws.config_path)
    target = workspace_target(config, ws)
    rows = read_manifest(ws, "plan").to_pylist()
    dataset = [r for r in rows if r["session"] == "dataset"]
    assert {r["view"] for r in dataset} == {"plus_z", "minus_z"}
    assert {r["view"] for r in rows if r["session"] == "calibration"} == {"plus_z"}
    camera = config.camera
    for row in dataset:
        cam_from_target = g.transform_from_qt(row["cam_from_target_q"], row["cam_from_target_t"])
        # the view is the camera's side of the body, and every chosen keypoint is in the image
        camera_in_target = g.invert(cam_from_target)[:3, 3]
        assert target.view_of(camera_in_target, target.mockup_scale) == row["view"]
        pixels = g.project(cam_from_target, target.keypoints_m * target.mockup_scale, camera.camera_matrix(),
                           camera.dist_coeffs())
        assert np.all((pixels >= 0) & (pixels <= [camera.width_px - 1, camera.height_px - 1]))
        # the body centre's distance, in diameters
        centre = g.apply(cam_from_target, (target.centre_m * target.mockup_scale)[None])[0]
        diameters = np.linalg.norm(centre) / target.mockup_scale / target.diameter_m
        assert 4.75 <= diameters <= 6.94


def test_the_target_content_is_in_every_fingerprint(planned, tmp_path):
    source, ws = planned
    config = load_config(None, ws.config_path)
    plan, label = registry.stage("plan"), registry.stage("label")
    before = runner.fingerprint_payload(plan, config, ws)["target"]
    assert before == target_digest(source)
    (source / TARGET_FILE).write_text((source / TARGET_FILE).read_text().replace("mass_kg = 9.0", "mass_kg = 9.5"))
    try:
        assert runner.fingerprint_payload(plan, config, ws)["target"] != before  # the plan is stale
        # a later stage reads W/target, unchanged until the plan is made again
        assert label.target_folder == "workspace" and digest(config, ws) == before
    finally:
        (source / TARGET_FILE).write_text((source / TARGET_FILE).read_text().replace("mass_kg = 9.5", "mass_kg = 9.0"))


def test_labels_carry_the_targets_own_keypoints_and_views(tmp_path):
    config = load_config("smoke", overrides=[f"target.path={boulder(tmp_path / 'boulder')}"])
    target = workspace_target(config, Workspace(tmp_path / "w"))
    cam_from_target = g.make_transform(g.axis_angle_matrix("y", np.pi / 2), [0.0, 0.0, 4.0])
    q, t = g.transform_to_qt(cam_from_target)
    pose = {"sample_id": "img000000", "cam_from_target_q": q, "cam_from_target_t": t, "vicon_accepted": True,
            "sigma_t_m": [1e-3] * 3, "sigma_r_rad": 1e-4}
    camera = config.camera
    row = label_row(pose, {"light": "sunlamp"}, camera.camera_matrix(), camera.dist_coeffs(), target, "a.jpg")
    assert len(row["keypoints_px"]) == 5
    # the y turn maps body +x onto the camera's -z: towards the camera, which is on the +x side
    assert row["view"] == "east"
    np.testing.assert_allclose(row["r_Vo2To_vbs_true"], t / target.mockup_scale)


def test_a_bad_target_folder_is_refused_before_anything_is_written(tmp_path):
    folder = cubesat(tmp_path / "cubesat", unit="m")  # a mesh in mm declared as metres: a 540 m mock-up
    result = speedplus("plan", "--profile", "smoke", "--workspace", str(tmp_path / "w"), "--target", str(folder))
    assert result.returncode == 1
    assert "target.toml" in result.stderr and "length_unit" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "w").exists()
    missing = speedplus("plan", "--profile", "smoke", "--workspace", str(tmp_path / "w"), "--target",
                        str(tmp_path / "nowhere"))
    assert missing.returncode == 1 and "nowhere" in missing.stderr and "Traceback" not in missing.stderr


def test_the_mockup_settings_moved_into_the_target_folder(tmp_path):
    # an older workspace wrote the built-in values: they load, the target holds them
    assert load_config("smoke", overrides=["testbed.mockup_scale=0.5", "virtual.model_mass_kg=4.0"])
    with pytest.raises(ConfigError, match=r"testbed.mockup_scale is now the target's own: set \[mockup\] scale"):
        load_config("smoke", overrides=["testbed.mockup_scale=0.3"])
    rel = ("[[0.9, 0.8, 1.02], [-0.9, 0.85, 1.02], [0.85, -0.9, 1.02], [1.03, 0.2, 0.5], [-1.03, -0.3, 0.3], "
           "[0.2, 1.03, 0.2]]")
    assert load_config("smoke", overrides=[f"virtual.target_markers_rel={rel}"])  # the markers now in Tango's folder
    with pytest.raises(ConfigError, match=r"target_markers_rel is now the target's own: set \[mockup\] markers"):
        load_config("smoke", overrides=["virtual.target_markers_rel=[[0.5, 0.5, 1.02]]"])


def test_a_replayed_session_gets_its_target_copied_too(tmp_path):
    """A recording has no plan: acquire copies the target (real data: Ali et al.'s KUKA)."""
    from tests.stages.acquire.test_handeye import kuka_folder

    source = kuka_folder(tmp_path / "kuka", images=3)
    folder = boulder(tmp_path / "boulder")
    result = speedplus("acquire", "-w", str(tmp_path / "w"), "--backend", "replay", "--format", "handeye",
                       "--source", str(source), "--target", str(folder))
    assert result.returncode == 0, result.stderr
    assert target_digest(tmp_path / "w" / "target") == target_digest(folder)


def test_a_failed_command_puts_the_workspaces_target_back(tmp_path):
    from tests.stages.acquire.test_handeye import kuka_folder

    source = kuka_folder(tmp_path / "kuka", images=3)
    ws = tmp_path / "w"
    assert speedplus("acquire", "-w", str(ws), "--backend", "replay", "--format", "handeye", "--source",
                     str(source)).returncode == 0  # the built-in Tango
    before = target_digest(ws / "target")
    (source / "dataset.toml").write_text((source / "dataset.toml").read_text().replace(
        'layout = "rowmajor4x4"', 'layout = "rowmajor"'))
    failed = speedplus("acquire", "-w", str(ws), "--force", "--target", str(boulder(tmp_path / "boulder")))
    assert failed.returncode == 1 and "layout" in failed.stderr
    assert target_digest(ws / "target") == before and not (ws / ".target.new").exists()
