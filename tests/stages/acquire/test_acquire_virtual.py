"""The virtual acquisition end to end (smoke profile): manifests, images, truth, resume."""

import json

import cv2
import numpy as np
import pytest

from manifests import Workspace, list_parts, read_manifest
from stages.common import geometry as g
from stages.common import tango
from stages.common.patterns import PatternSpec, detect
from tests.conftest import speedplus


@pytest.fixture(scope="module")
def smoke_workspace(smoke_labelled):
    """The session's smoke workspace (acquired, then calibrated and labelled): read only."""
    return smoke_labelled


def test_captures_truth_and_images(smoke_workspace):
    ws = smoke_workspace
    captures = read_manifest(ws, "captures").to_pylist()
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    assert len(captures) == 24 and set(truth) == {c["sample_id"] for c in captures}
    for row in captures:
        image = cv2.imread(str(ws.resolve(row["image_path"])), cv2.IMREAD_UNCHANGED)
        assert image.shape == (200, 320) and image.dtype == np.uint8
        assert row["status"] == "ok"
    hidden = json.loads(ws.truth_path.read_text())
    assert {"cam_from_camee", "target_from_targetee", "cam_from_camrb", "target_from_targetrb"} <= set(hidden)
    session = json.loads(ws.session_path.read_text())
    assert session["sources"] == ["kuka", "vicon"] and session["pattern"]["kind"] == "charuco"
    # each session's captures carry their exposure times, in plan order, from 0
    for name in ("calibration", "dataset"):
        times = [r["capture_time_s"] for r in sorted(captures, key=lambda r: r["sample_id"]) if r["session"] == name]
        assert times[0] == 0.0 and all(b > a for a, b in zip(times, times[1:], strict=False))
    assert set(hidden["unmodelled"]["camera_by_session"]) == {"calibration", "dataset"}


def test_images_show_the_board_where_the_truth_puts_it(smoke_workspace):
    """Detected ChArUco corners land where the true pose projects them: the conventions of
    plan, testbed, renderer and lens model agree."""
    ws = smoke_workspace
    session = json.loads(ws.session_path.read_text())
    spec = PatternSpec.from_json(session["pattern"])
    camera_matrix, dist = np.array(session["camera"]["K"]), np.array(session["camera"]["dist"])
    target_from_board = g.transform_from_qt(spec.target_from_pattern_q, spec.target_from_pattern_t)
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    errors, detected = [], 0
    calibration = [c for c in read_manifest(ws, "captures").to_pylist() if c["session"] == "calibration"]
    for row in calibration:
        corners, ids = detect(cv2.imread(str(ws.resolve(row["image_path"])), cv2.IMREAD_GRAYSCALE), spec)
        if len(ids) < 6:
            continue
        detected += 1
        cam_from_target = g.transform_from_qt(truth[row["sample_id"]]["cam_from_target_q"],
                                              truth[row["sample_id"]]["cam_from_target_t"])
        expected = g.project(cam_from_target @ target_from_board, spec.object_points()[ids], camera_matrix, dist)
        errors.append(np.linalg.norm(expected - corners, axis=1))
    errors = np.concatenate(errors)
    assert detected >= 0.75 * len(calibration)  # 320 x 200 is tiny; the default profile is checked in bench
    assert np.median(errors) < 0.5 and np.percentile(errors, 95) < 1.5


def test_model_is_in_frame_and_visible_in_every_dataset_capture(smoke_workspace):
    ws = smoke_workspace
    session = json.loads(ws.session_path.read_text())
    camera_matrix, dist = np.array(session["camera"]["K"]), np.array(session["camera"]["dist"])
    truth = {r["sample_id"]: r for r in read_manifest(ws, "truth").to_pylist()}
    for row in read_manifest(ws, "captures").to_pylist():
        if row["session"] != "dataset":
            continue
        image = cv2.imread(str(ws.resolve(row["image_path"])), cv2.IMREAD_GRAYSCALE)
        cam_from_target = g.transform_from_qt(truth[row["sample_id"]]["cam_from_target_q"],
                                              truth[row["sample_id"]]["cam_from_target_t"])
        pixels = g.project(cam_from_target, tango.KEYPOINTS_M * session["mockup_scale"], camera_matrix, dist)
        assert np.all((pixels >= 0) & (pixels <= [image.shape[1] - 1, image.shape[0] - 1]))
        x0, y0 = np.floor(pixels.min(axis=0)).astype(int)
        x1, y1 = np.ceil(pixels.max(axis=0)).astype(int)
        inside = image[y0:y1 + 1, x0:x1 + 1]
        assert np.percentile(inside, 99) > 3 * max(np.median(image), 1)  # something lit is there


def test_truth_maps_are_the_mock_up_at_its_true_pose(smoke_workspace):
    """Depth and part ids at the TRUE pose for every dataset capture: the mock-up's
    silhouette in the testbed scene itself, at the mock-up's depth."""
    from pipeline.config import load_config
    from stages.acquire.virtual import VirtualTestbed
    from stages.common import ground_truth
    from stages.common.tango_mesh import tango_parts

    ws = smoke_workspace
    testbed = VirtualTestbed(load_config(None, ws.config_path), ws)
    plan = {r["sample_id"]: r for r in read_manifest(ws, "plan").to_pylist()}
    truth = read_manifest(ws, "truth").to_pylist()
    assert {r["sample_id"] for r in truth if r["maps_path"]} == {
        r["sample_id"] for r in read_manifest(ws, "captures").to_pylist() if r["session"] == "dataset"}
    scale = json.loads(ws.session_path.read_text())["mockup_scale"]
    for row in (r for r in truth if r["maps_path"]):
        maps = ground_truth.read(ws.resolve(row["maps_path"]))
        cam_from_target = g.transform_from_qt(row["cam_from_target_q"], row["cam_from_target_t"])
        np.testing.assert_allclose(maps.cam_from_target, cam_from_target, atol=1e-12)
        assert maps.length_scale == scale
        on = maps.channels["part"] > 0
        silhouette = testbed.silhouette(plan[row["sample_id"]])
        assert (on & silhouette).sum() / (on | silhouette).sum() > 0.9  # the scene's model, seen by its lens
        vertices = np.concatenate([part.vertices for part in tango_parts().values()])
        corners_z = g.apply(cam_from_target, vertices * scale)[:, 2]
        depth = maps.channels["Z"][on]
        assert depth.min() >= corners_z.min() - 1e-3 and depth.max() <= corners_z.max() + 1e-3
        assert np.isnan(maps.channels["Z"][~on]).all()


def test_interrupted_acquisition_resumes_without_duplicates_or_gaps(smoke_workspace, tmp_path):
    reference = read_manifest(smoke_workspace, "captures").sort_by("sample_id")
    ws = tmp_path / "killed"
    assert speedplus("plan", "--profile", "smoke", "--workspace", str(ws)).returncode == 0
    # two spawned workers (the smoke profile captures in one process), killed with their driver
    killed = speedplus("acquire", "--workspace", str(ws), "--workers", "2", env={"SPEEDPLUS_FAULT_KILL_AT_PART": "3"})
    assert killed.returncode == -9
    assert len(list_parts(Workspace(ws), "captures")) + len(list_parts(Workspace(ws), "truth")) == 2
    resumed = speedplus("acquire", "--workspace", str(ws))
    assert resumed.returncode == 0 and "resumed" in resumed.stdout, resumed.stderr
    got = read_manifest(Workspace(ws), "captures").sort_by("sample_id")
    assert got.equals(reference)
    truth = read_manifest(Workspace(ws), "truth")
    assert sorted(truth.column("sample_id").to_pylist()) == got.column("sample_id").to_pylist()
    for name in ("captures", "truth"):  # killed and resumed: the same bytes as uninterrupted
        assert ([p.read_bytes() for p in list_parts(Workspace(ws), name)]
                == [p.read_bytes() for p in list_parts(smoke_workspace, name)]), name
    for name in got.column("image_path").to_pylist():  # a worker's render history changes nothing
        a = cv2.imread(str(Workspace(ws).resolve(name)), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(smoke_workspace.resolve(name)), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(a, b), name


def test_a_captures_truth_maps_cast_in_its_window_are_the_full_casts_bytes(smoke_workspace, monkeypatch):
    """Issue 60: a dataset capture's ground truth is ray-cast only in the image window that
    can hold the mock-up (``stages.common.windows``), smaller than the image; its EXR is
    byte for byte the one a cast at every pixel writes (at the truth's pose as its manifest
    rounds it)."""
    from pipeline.config import load_config
    from stages.acquire.virtual import VirtualTestbed
    from stages.common import surface

    ws = smoke_workspace
    testbed = VirtualTestbed(load_config(None, ws.config_path), ws)
    rows = [r for r in read_manifest(ws, "truth").to_pylist() if r["maps_path"]]
    assert rows
    in_window, full_cast, windows = surface.TargetSurfaces.in_window, surface.TargetSurfaces.through_lens, []

    def windowed_cast(self, pose, camera, window):
        windows.append((window, camera.width * camera.height))
        return in_window(self, pose, camera, window)

    def every_pixel(self, pose, camera, window):  # the whole image's maps, written as they are
        return full_cast(self, pose, camera)

    for row in rows:
        cam_from_target = g.transform_from_qt(row["cam_from_target_q"], row["cam_from_target_t"])
        monkeypatch.setattr(surface.TargetSurfaces, "in_window", windowed_cast)
        windowed = testbed.truth_maps("dataset", cam_from_target)
        monkeypatch.setattr(surface.TargetSurfaces, "in_window", every_pixel)
        assert testbed.truth_maps("dataset", cam_from_target) == windowed
    assert len(windows) == len(rows)
    assert all(window.width * window.height < pixels for window, pixels in windows)  # less than the image


def test_the_sample_counts_allowed_are_those_mitsubas_stratified_sampler_takes_as_given():
    from core.config.facility import stratified_grid
    from stages.common.mitsuba_adapter import load_mitsuba

    mi = load_mitsuba()
    for spp in range(1, 65):
        taken = mi.load_dict({"type": "multijitter", "sample_count": spp}).sample_count()
        assert stratified_grid(spp)[1] == taken, spp


def test_the_films_blur_has_the_footprint_of_the_gaussian_filter_it_replaces():
    """A box-filtered pixel integrates its own square (variance 1/12 px^2 an axis); the blur
    widens that to the 0.4 px Gaussian's 0.16, keeps the light and moves nothing."""
    from stages.acquire.virtual.scene import sensor_blur

    impulse = np.zeros((9, 9), np.float32)
    impulse[4, 4] = 1.0
    blurred = sensor_blur(impulse)
    ys, xs = np.mgrid[0:9, 0:9] - 4
    assert blurred.sum() == pytest.approx(1.0, abs=1e-6)
    assert (xs * blurred).sum() == pytest.approx(0.0, abs=1e-7) and (ys * blurred).sum() == pytest.approx(0.0, abs=1e-7)
    assert (xs**2 * blurred).sum() + 1.0 / 12.0 == pytest.approx(0.4**2, abs=1e-6)
    rng = np.random.default_rng(3)
    film = rng.uniform(0.0, 1.0, (40, 60)).astype(np.float32)
    assert sensor_blur(film).mean() == pytest.approx(film.mean(), rel=2e-3)
