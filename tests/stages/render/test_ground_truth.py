"""Per-pixel ground truth of the synthetic images: geometry that agrees with the pose and
the lens, ids that mean their parts, radiance that is the PNG before tone mapping, and a
reader that names what is wrong."""

import json

import cv2
import numpy as np
import pytest

from core.engines import store
from manifests import Workspace
from pipeline.config import load_config
from stages.common import geometry as g
from stages.common import ground_truth
from stages.common.cameras import train_camera
from stages.common.ground_truth import GroundTruthError
from stages.common.tango import KEYPOINTS_M
from stages.common.tango_mesh import tango_parts
from stages.common.tone import Response, luminance
from stages.common.windows import Window
from stages.common.workspace_target import planned_target
from stages.render.jobs import train_jobs
from stages.render.worker import EXPOSURE, RenderWorker

ALL = ground_truth.RADIANCE + ground_truth.GEOMETRY


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Six training images of the default camera (960 x 600), with their ground truth."""
    root = tmp_path_factory.mktemp("ground_truth")
    config = load_config("default", None, ["render.train_spp=4"])
    camera = train_camera(config)
    worker = RenderWorker(camera, planned_target(config), 4, config.render.max_depth, 2)
    rows = [store(Workspace(root), worker.render(job)) for job in train_jobs(config)[:6]]
    rows = [row for row in rows if "rejected" not in row]
    assert len(rows) == 6
    return root, camera, rows, [ground_truth.read(root / row["ground_truth_path"], ALL) for row in rows]


def test_the_header_holds_the_camera_and_the_pose(rendered):
    _, camera, rows, files = rendered
    for row, file in zip(rows, files, strict=True):
        pose = g.transform_from_qt(row["q_vbs2tango_true"], row["r_Vo2To_vbs_true"])
        np.testing.assert_allclose(file.cam_from_target, pose, atol=1e-12)
        np.testing.assert_allclose(file.camera.camera_matrix, camera.camera_matrix)
        np.testing.assert_allclose(file.camera.dist, camera.dist)
        assert (file.camera.width, file.camera.height) == (camera.width, camera.height) == (row["width"],
                                                                                            row["height"])


def test_body_coordinates_project_back_to_their_pixel_through_the_lens(rendered):
    _, camera, _, files = rendered
    for file in files:
        on = file.channels["part"] > 0
        ys, xs = np.nonzero(on)
        body = file.stack(("P.X", "P.Y", "P.Z"))[on].astype(float)
        projected = g.project(file.cam_from_target, body, camera.camera_matrix, camera.dist)
        assert np.abs(projected - np.stack([xs, ys], 1)).max() < 0.5
        # depth is z of the same point in the camera frame
        np.testing.assert_allclose(file.channels["Z"][on], g.apply(file.cam_from_target, body)[:, 2], atol=1e-5)
        assert np.isnan(file.channels["Z"][~on]).all() and np.isnan(body).sum() == 0


def body_faces():
    """(normal (3,), corner indices) of the body's six faces in the Tango frame."""
    faces = []
    for name in ("solar_panel", "rear_panel", "sides"):
        part = tango_parts()[name]
        for a, b, c in part.vertices[part.faces]:
            normal = np.cross(b - a, c - a)
            corners = [i for i, k in enumerate(KEYPOINTS_M[:8]) if abs(np.dot(k - a, normal)) < 1e-9]
            faces.append((normal / np.linalg.norm(normal), corners))
    return faces


def test_depth_and_normals_at_each_visible_corner_give_its_depth(rendered):
    """The body is convex: a corner is visible when a face through it faces the camera.
    The plane of the pixel nearest the corner (its depth and normal) meets the corner's ray
    at the corner's depth."""
    _, camera, _, files = rendered
    faces, checked = body_faces(), 0
    for file in files:
        rotation, position = file.cam_from_target[:3, :3], file.cam_from_target[:3, 3]
        camera_in_target = -rotation.T @ position
        projected = g.project(file.cam_from_target, KEYPOINTS_M[:8], camera.camera_matrix, camera.dist)
        depth_of_corner = g.apply(file.cam_from_target, KEYPOINTS_M[:8])[:, 2]
        for index, (u, v) in enumerate(projected):
            visible = any(index in corners and np.dot(normal, camera_in_target - KEYPOINTS_M[index]) > 1e-6
                          for normal, corners in faces)
            x, y = int(round(u)), int(round(v))
            if not visible or not (0 <= x < camera.width and 0 <= y < camera.height):
                continue
            if file.channels["part"][y, x] not in [file.part_ids[n] for n in ("solar_panel", "rear_panel", "sides")]:
                continue  # the pixel centre is off the silhouette or on an antenna in front
            point = np.array([file.channels[f"P.{a}"][y, x] for a in "XYZ"], float)
            normal = np.array([file.channels[f"N.{a}"][y, x] for a in "XYZ"], float)
            surface_cam = rotation @ point + position
            ray = np.linalg.solve(camera.camera_matrix, [*cv2.undistortPointsIter(
                np.array([[[u, v]]]), camera.camera_matrix, camera.dist, None, camera.camera_matrix,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)).ravel(), 1.0])
            depth = np.dot(normal, surface_cam) / np.dot(normal, ray) * ray[2]
            assert abs(file.channels["Z"][y, x] - surface_cam[2]) < 1e-4
            assert abs(depth - depth_of_corner[index]) < 1e-3, (index, depth, depth_of_corner[index])
            checked += 1
    assert checked >= 2 * len(files)


def test_part_ids_mean_their_parts_and_match_the_mask(rendered):
    root, _, rows, files = rendered
    for row, file in zip(rows, files, strict=True):
        # the header names the ids: the background, then the mesh's parts in order
        assert file.part_ids == {"background": 0, "solar_panel": 1, "rear_panel": 2, "sides": 3, "antennas": 4}
        panel_normal = {file.part_ids["solar_panel"]: np.array([0, 0, 1.0]), file.part_ids["rear_panel"]: np.array(
            [0, 0, -1.0])}
        part = file.channels["part"]
        assert set(np.unique(part)) <= {0, 1, 2, 3, 4} and (part == np.round(part)).all()
        mask = cv2.imread(str(root / row["mask_path"]), cv2.IMREAD_UNCHANGED) > 0
        assert ((part > 0) == mask).all()
        normals = file.stack(("N.X", "N.Y", "N.Z"))
        for index, normal in panel_normal.items():
            if (part == index).any():
                np.testing.assert_allclose(normals[part == index], np.broadcast_to(
                    file.cam_from_target[:3, :3] @ normal, normals[part == index].shape), atol=1e-4)


def test_radiance_is_the_png_before_the_mono_cameras_tone(rendered):
    """The default camera is mono and linear (SPEED+'s): each image is one grey channel, the
    luminance of its radiance at the fixed exposure, clipped and quantised, nothing more. The
    file keeps the radiance in half floats (relative step 2^-11), so a level computed from it
    is within 255 * 2^-11 < 0.125 of the render's: the same wherever that is not within 0.125
    of a rounding boundary, and never more than one level off."""
    root, _, rows, files = rendered
    for row, file in zip(rows, files, strict=True):
        png = cv2.imread(str(root / row["image_path"]), cv2.IMREAD_UNCHANGED)
        radiance = file.stack(ground_truth.RADIANCE)
        assert png.ndim == 2 and np.isfinite(radiance).all()
        level = np.clip(luminance(radiance.astype(np.float64)) * EXPOSURE, 0, 1) * 255
        off = np.abs(np.round(level) - png.astype(np.float64))
        near_boundary = np.abs(level % 1.0 - 0.5) < 0.125
        assert off.max() <= 1 and (off[~near_boundary] == 0).all()
        assert png.max() > 100  # lit, not black


def test_a_cameras_gamma_and_colour_reach_the_image(rendered):
    """The same radiance through a gamma-2.2 mono camera is brighter in the mid-tones and
    never darker; a colour camera keeps three channels whose luminance is
    the mono image where no channel clips."""
    _, _, _, files = rendered
    radiance = files[0].stack(ground_truth.RADIANCE)
    linear, bent = Response("mono", 1.0).image(radiance), Response("mono", 2.2).image(radiance)
    middle = (linear > 20) & (linear < 200)
    assert middle.any() and (bent[middle] > linear[middle]).all()
    assert (bent >= linear).all() and (bent[linear == 255] == 255).all()
    colour = Response("colour", 1.0).image(radiance)
    assert colour.shape == (*linear.shape, 3)
    unclipped = (colour < 255).all(axis=-1)
    assert unclipped.mean() > 0.9
    assert np.abs(luminance(colour.astype(float)) - linear)[unclipped].max() <= 1.0


def test_the_switch_turns_the_ground_truth_off(tmp_path):
    config = load_config("smoke", None, ["render.train_spp=2"])
    worker = RenderWorker(train_camera(config), planned_target(config), 2, config.render.max_depth, 2, False)
    produced = worker.render(train_jobs(config)[0])
    assert produced.value["ground_truth_path"] is None and not any(p.endswith(".exr") for p in produced.files)


def test_a_bad_file_is_an_error_naming_file_and_key(rendered, tmp_path):
    root, camera, rows, files = rendered
    path = root / rows[0]["ground_truth_path"]
    with pytest.raises(GroundTruthError, match=r"channel nope missing"):
        ground_truth.read(path, ("Z", "nope"))
    truncated = tmp_path / "truncated.exr"
    truncated.write_bytes(path.read_bytes()[:2000])
    with pytest.raises(GroundTruthError, match="truncated.exr"):
        ground_truth.read(truncated)
    channels = {name: files[0].channels[name] for name in ground_truth.TRUTH}
    for header, key in ((json.dumps({"version": 99}), "version"), ("not json", "top level")):
        other = tmp_path / f"{key.replace(' ', '_')}.exr"
        ground_truth.write(other, channels, camera, files[0].cam_from_target, files[0].part_ids)
        _rewrite_header(other, header)
        with pytest.raises(GroundTruthError, match=rf"{other.name}: header speedplus:ground_truth, key \(?{key}"):
            ground_truth.read(other)


def test_radiance_is_kept_in_half_floats_where_it_fits_and_version_1_files_still_read(rendered, tmp_path):
    root, camera, rows, files = rendered
    import OpenImageIO as oiio  # noqa: N813

    image_input = oiio.ImageInput.open(str(root / rows[0]["ground_truth_path"]))
    spec = image_input.spec()
    image_input.close()
    formats = {name: str(spec.channelformat(index)) for index, name in enumerate(spec.channelnames)}
    assert formats == {name: "half" if name in ground_truth.RADIANCE else "float" for name in ALL}
    rng = np.random.default_rng(60)
    radiance = rng.lognormal(-2.0, 2.0, size=(40, 50, 3)).astype(np.float32)
    radiance[0, 0] = [65504.0, 1e-9, 0.0]  # half's largest finite value, and below its subnormals
    planes = ground_truth.radiance_planes(radiance)
    assert all(plane.dtype == np.float16 and plane.flags.c_contiguous for plane in planes)
    widened = np.stack(planes, axis=-1).astype(np.float32)
    normal = radiance >= np.float32(2.0 ** -14)  # half's smallest normal: relative steps above it
    assert (np.abs(widened - radiance)[normal] <= radiance[normal] * 2.0 ** -11).all()
    assert (np.abs(widened - radiance)[~normal] <= 2.0 ** -25).all()
    assert all(np.array_equal(plane.view(np.uint16), radiance[..., axis].astype(np.float16).view(np.uint16))
               for axis, plane in enumerate(planes))  # NumPy's rounding, bit for bit
    bits = rng.integers(0, 2 ** 32, size=(500, 600, 3), dtype=np.uint64).astype(np.uint32).view(np.float32)
    bits[~(np.abs(bits) <= ground_truth.HALF_MAX)] = 0.0  # any float32 in half's range, subnormals and -0 too
    assert np.array_equal(np.stack(ground_truth.radiance_planes(bits), axis=-1).view(np.uint16),
                          bits.astype(np.float16).view(np.uint16))
    for beyond in (65505.0, np.inf, np.nan):  # past half's largest value, or not finite: float32 kept
        radiance[3, 4, 1] = beyond
        kept = ground_truth.radiance_planes(radiance)
        assert all(plane.dtype == np.float32 for plane in kept)
        assert np.array_equal(np.stack(kept, axis=-1), radiance, equal_nan=True)
    older = tmp_path / "version1.exr"
    channels = {name: files[0].channels[name] for name in ground_truth.TRUTH}
    ground_truth.write(older, channels, camera, files[0].cam_from_target, files[0].part_ids)
    image_input = oiio.ImageInput.open(str(older))
    header = json.loads(image_input.spec().getattribute(ground_truth.HEADER_KEY))
    image_input.close()
    _rewrite_header(older, json.dumps({**header, "version": 1}))
    assert np.array_equal(ground_truth.read(older).channels["Z"], channels["Z"], equal_nan=True)


def _rewrite_header(path, text):
    import OpenImageIO as oiio  # noqa: N813

    source = oiio.ImageBuf(str(path))
    source.specmod().attribute(ground_truth.HEADER_KEY, text)
    assert source.write(str(path))


def test_files_written_one_after_another_each_hold_their_own_channels(tmp_path):
    """Files of other sizes and channels in between, and the next of the first size, each
    read back as written (noise: uniform tiles are read back in tests/stages/common/test_exr.py)."""
    rng = np.random.default_rng(60)
    camera = train_camera(load_config("smoke"))
    sizes = [(camera.height, camera.width, ("Z", "part")), (camera.height, camera.width, ALL),
             (camera.height, camera.width, ("Z", "part"))]
    written = []
    for index, (height, width, names) in enumerate(sizes):
        channels = {name: rng.normal(size=(height, width)).astype(np.float32) for name in names}
        path = tmp_path / f"{index}.exr"
        ground_truth.write(path, channels, camera, np.eye(4), {"body": 1})
        written.append((path, channels))
    for path, channels in written:
        read = ground_truth.read(path, tuple(channels))
        assert all(np.array_equal(read.channels[name], values) for name, values in channels.items()), path.name


@pytest.mark.parametrize("sensor", ["mono", "colour"])
def test_a_black_space_image_toned_in_its_window_is_the_whole_frames_tone(sensor):
    from types import SimpleNamespace

    from stages.common.windows import Window

    rng = np.random.default_rng(7)
    radiance = np.zeros((40, 64, 3), np.float32)
    window = Window(9, 5, 30, 21)
    radiance[window.slices()] = rng.uniform(0.0, 1.5, (21, 30, 3))
    worker = SimpleNamespace(response=Response(sensor, 2.2))
    whole = worker.response.image(radiance, EXPOSURE)
    assert np.array_equal(RenderWorker.tone(worker, radiance, window), whole)
    assert np.array_equal(RenderWorker.tone(worker, radiance, None), whole)
    empty = RenderWorker.tone(worker, np.zeros_like(radiance), Window(0, 0, 0, 0))
    assert empty.shape == whole.shape and not empty.any()


def test_the_earth_composited_in_the_window_is_the_whole_frames_composite():
    """Outside the window the render and its coverage are zero: compositing the Earth there
    only is the whole frame's ``rgb + (1 - alpha) * earth``, bit for bit."""
    from stages.common.earth import earth_background

    config = load_config("smoke", None, ["render.train_spp=4"])
    camera = train_camera(config)
    worker = RenderWorker(camera, planned_target(config), 4, config.render.max_depth, 1)
    jobs = [job for job in train_jobs(config) if job.earth][:3]
    assert jobs
    for job in jobs:
        radiance, _ = worker.radiance(job)
        rgba = worker.renderer.render(job.cam_from_target(), np.asarray(job.light_dir_cam), job.irradiance, job.seed)
        earth = earth_background(camera, np.asarray(job.light_dir_cam), job.irradiance,
                                 np.random.default_rng(job.seed))
        alpha = np.clip(rgba[..., 3:], 0.0, 1.0)
        window = worker.renderer.image_window(job.cam_from_target())
        assert window is not None and window.width * window.height < 0.5 * camera.width * camera.height
        assert np.array_equal(radiance, rgba[..., :3] + (1.0 - alpha) * earth), job.sample_id


@pytest.mark.parametrize("shape", ["tango", "cubesat"])
def test_the_ground_truth_of_the_window_is_the_whole_frames_file(monkeypatch, tmp_path, shape):
    """The worker writes an image's ground truth from the window's maps and, over black
    space, the window's radiance (``exr.Windowed``): its files are byte for byte those of
    maps cast at every pixel and written whole, over black space and over the Earth, for
    Tango and for a target of another shape (a 3U CubeSat)."""
    from bench.targets import cubesat3u
    from stages.common import surface
    from stages.common.target import load_target

    config = load_config("smoke", None, ["render.train_spp=4"])
    target = planned_target(config) if shape == "tango" else load_target(cubesat3u(tmp_path / "t"))
    worker = RenderWorker(train_camera(config), target, 4, config.render.max_depth, 1)
    jobs = train_jobs(config, target)
    jobs = [job for job in jobs if job.earth][:2] + [job for job in jobs if not job.earth][:2]
    whole = surface.TargetSurfaces.through_lens

    def every_pixel_cast(self, pose, camera, window):  # the whole image as the window
        maps = whole(self, pose, camera)
        return surface.WindowedMaps(maps, Window(0, 0, camera.width, camera.height), camera.height, camera.width,
                                    maps.ids)

    for job in jobs:
        assert worker.renderer.image_window(job.cam_from_target()) is not None  # the windowed path
        windowed = worker.render(job)
        with monkeypatch.context() as patch:
            patch.setattr(surface.TargetSurfaces, "in_window", every_pixel_cast)
            every_pixel = worker.render(job)
        assert windowed.files.keys() == every_pixel.files.keys() and len(windowed.files) == 3
        for name, data in windowed.files.items():
            assert data == every_pixel.files[name], (job.sample_id, name)
        assert np.array_equal(windowed.value["bbox_px"], every_pixel.value["bbox_px"])
