"""``speedplus view`` (stages/common/view.py): the recordings read back headless with
Rerun's own reader; the entities and their poses are the facility's, the planned and the
labelled ones."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from manifests import Workspace, read_manifest
from stages.common import geometry as g
from stages.common.robots.facility import load_facility
from stages.common.scores import ROTATION_THRESHOLD_RAD, TRANSLATION_THRESHOLD
from stages.common.view import MET, MISSED
from tests.conftest import speedplus

FACILITIES = Path(__file__).resolve().parents[2] / "facilities"


def read_back(path: Path) -> dict[str, list[dict]]:
    """Every row of the recording, by entity path (static rows first, then the timeline's)."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        rows.setdefault(chunk.entity_path, []).extend(chunk.to_record_batch().to_pylist())
    return rows


def test_a_facilitys_recording_holds_its_room_robots_motion_capture_and_lights(tmp_path):
    folder = tmp_path / "abb_rail"
    shutil.copytree(FACILITIES / "abb_rail", folder)
    result = speedplus("view", str(folder), "--no-open")
    assert result.returncode == 0, result.stderr
    rows = read_back(folder / "view.rrd")
    facility = load_facility(folder)
    room = next(r for r in rows["/room"] if "Boxes3D:half_sizes" in r)
    np.testing.assert_allclose(room["Boxes3D:half_sizes"][0], np.asarray(facility.spec.room_m) / 2)
    for robot in facility.robots:
        links = next(r for r in rows[f"/room/robots/{robot.spec.name}"] if "LineStrips3D:strips" in r)
        a, b, _ = robot.capsules(np.zeros(robot.chain.dof), 0.0)
        np.testing.assert_allclose(np.array(links["LineStrips3D:strips"]), np.stack([a, b], axis=1), atol=1e-6)
    cameras = [path for path in rows if path.startswith("/room/motion_capture/")]
    assert len(cameras) == len(facility.spec.motion_capture.cameras)
    assert len([path for path in rows if path.startswith("/room/lights/")]) == len(facility.spec.light_boxes) + (
        facility.spec.sun_lamp is not None)
    result = speedplus("view", str(tmp_path / "nothing"), "--no-open")
    assert result.returncode == 1 and "neither a facility folder" in result.stderr
    notes = tmp_path / "notes.txt"  # a file of the user's is never replaced
    notes.write_text("mine")
    result = speedplus("view", str(folder), "--out", str(notes), "--no-open")
    assert result.returncode == 1 and "not a Rerun recording" in result.stderr and notes.read_text() == "mine"


def test_a_workspaces_recording_holds_the_planned_poses_and_the_labels_errors(smoke_labelled, tmp_path):
    out = tmp_path / "w.rrd"
    result = speedplus("view", str(smoke_labelled.root), "--out", str(out), "--no-open")
    assert result.returncode == 0, result.stderr
    rows = read_back(out)
    workspace = Workspace(smoke_labelled.root)
    plan = read_manifest(workspace, "plan").to_pylist()
    facility = load_facility(None)
    fixture = facility.fixture("camera")
    camera = [r for r in rows["/room/camera"] if "Transform3D:translation" in r]
    assert [r["capture"] for r in camera] == list(range(len(plan)))
    for row, logged in zip(plan, camera, strict=True):
        world_from_cam = g.transform_from_qt(row["world_from_camee_q"], row["world_from_camee_t"]) @ fixture
        np.testing.assert_allclose(logged["Transform3D:translation"][0], world_from_cam[:3, 3], atol=1e-9)
        holder = facility.holder("camera")  # the arm drawn at the planned joints carries the camera there
        drawn = holder.world_from_tool(np.asarray(row["camera_joints_rad"]), row["rail_m"])
        np.testing.assert_allclose(drawn[:3, 3], world_from_cam[:3, 3], atol=1e-6)
    truth = {r["sample_id"]: r for r in read_manifest(workspace, "truth").to_pylist()}
    poses = {r["sample_id"]: r for r in read_manifest(workspace, "poses").to_pylist()}
    index = {row["sample_id"]: k for k, row in enumerate(plan)}
    labelled = {r["capture"]: r for r in rows["/room/target/labelled"]}
    assert set(labelled) == {index[s] for s in poses}
    for sample_id, pose in poses.items():
        true = g.transform_from_qt(truth[sample_id]["cam_from_target_q"], truth[sample_id]["cam_from_target_t"])
        label = g.transform_from_qt(pose["cam_from_target_q"], pose["cam_from_target_t"])
        met = (g.angular_distance(label[:3, :3], true[:3, :3]) < ROTATION_THRESHOLD_RAD
               and np.linalg.norm(label[:3, 3] - true[:3, 3]) / np.linalg.norm(true[:3, 3]) < TRANSLATION_THRESHOLD)
        colour = labelled[index[sample_id]]["Points3D:colors"][0]
        assert colour == pytest.approx(_packed(MET if met else MISSED)), sample_id
    images = [r for r in rows["/room/camera/image"] if "EncodedImage:blob" in r]
    assert len(images) == len(plan)


def _packed(rgb: tuple[int, int, int]) -> int:
    """Rerun's colour as it stores it: 0xRRGGBBAA."""
    return (rgb[0] << 24) | (rgb[1] << 16) | (rgb[2] << 8) | 255


def test_a_recordings_view_follows_its_captures(tmp_path):
    """A replayed ROS 2 bag has no plan: the camera follows the recorded flange at each
    capture, and no arm is drawn without the lab's own facility folder."""
    from tests.stages.acquire.test_rosbag import lab_bag

    workspace = tmp_path / "w"
    result = speedplus("acquire", "-w", str(workspace), "--backend", "replay", "--format", "rosbag", "--source",
                       str(lab_bag(tmp_path)))
    assert result.returncode == 0, result.stderr
    result = speedplus("view", str(workspace), "--no-open")
    assert result.returncode == 0 and "3 capture(s)" in result.stdout, result.stderr + result.stdout
    rows = read_back(workspace / "view.rrd")
    captures = sorted(read_manifest(Workspace(workspace), "captures").to_pylist(),
                      key=lambda r: (r["session"] != "calibration", r["sample_id"]))
    camera = [r for r in rows["/room/camera"] if "Transform3D:translation" in r]
    np.testing.assert_allclose([r["Transform3D:translation"][0] for r in camera],
                               [c["kuka_world_from_camee_t"] for c in captures], atol=1e-9)
    assert all("capture" not in r for path, found in rows.items() if path.startswith("/room/robots/") for r in found)
    pinhole = next(r for r in rows["/room/camera"] if "Pinhole:resolution" in r)
    assert list(pinhole["Pinhole:resolution"][0]) == [8, 6]  # the recorded camera, not the profile's
