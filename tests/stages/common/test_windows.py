"""Rendering and ray casting only where the target can be (issue 60): on seeded poses, some
half out of the image, the windowed twin differs from the full film's only in its noise, and
the windowed mask and ground truth are the full ray cast's, pixel for pixel."""

import drjit as dr
import numpy as np
import pytest

from pipeline.config import load_config
from stages.acquire.virtual.sensor import lens_camera
from stages.common import geometry as g
from stages.common import tango
from stages.common.lens import RenderGeometry
from stages.common.mitsuba_adapter import sensor_to_world
from stages.common.surface import TargetSurfaces
from stages.common.windows import Window, film_window, image_window, kernel_window
from stages.common.workspace_target import planned_target
from stages.render.scene import TargetRenderer

LIGHT = np.array([0.3, -0.4, -0.866])


@pytest.fixture(scope="module")
def renderer():
    camera = lens_camera(load_config("default").camera)  # 960 x 600 with the SPEED+ lens distortion
    return TargetRenderer(camera, planned_target(load_config("default")), spp=32, max_depth=3, threads=2)


def poses(seed: int, n: int) -> list[np.ndarray]:
    """cam_from_target (4, 4): random attitudes 5-10 m away, the centre anywhere up to past
    the image's edge (a target half out of the frame)."""
    rng = np.random.default_rng(seed)
    out = []
    for q in g.random_quats(rng, n):
        depth = rng.uniform(5.0, 10.0)
        centre = np.array([rng.uniform(-0.38, 0.38) * depth, rng.uniform(-0.24, 0.24) * depth, depth])
        out.append(g.transform_from_qt(q, centre - g.quat_to_matrix(q) @ tango.BODY_CENTRE_M))
    return out


def _full(renderer: TargetRenderer, cam_from_target: np.ndarray, seed: int) -> np.ndarray:
    """The whole film rendered, as before windows."""
    original = renderer.film_window
    renderer.film_window = lambda _: None
    try:
        return renderer.render(cam_from_target, LIGHT, 3.0, seed)
    finally:
        renderer.film_window = original


def test_the_window_holds_every_pixel_the_full_render_lights(renderer):
    fluxes = []
    for index, cam_from_target in enumerate(poses(60, 8)):
        windowed = renderer.render(cam_from_target, LIGHT, 3.0, seed=index)
        full = _full(renderer, cam_from_target, seed=index)
        window = image_window(renderer.lens, renderer.film_window(cam_from_target))
        outside = np.ones(full.shape[:2], bool)
        if window is not None and not window.empty:
            outside[window.slices()] = False
        assert np.all(full[outside] == 0) and np.all(windowed[outside] == 0)  # black space, both
        if full[..., 3].sum() > 50:  # enough of the target in the frame to compare its light
            fluxes.append((windowed[..., :3].sum(), full[..., :3].sum()))
            coverage = windowed[..., 3].sum() / full[..., 3].sum()
            assert abs(coverage - 1) < 0.02, coverage  # alpha: the same silhouette, to its sampling noise
    ratios = np.array([w / f for w, f in fluxes])
    assert len(ratios) >= 4 and np.all(np.abs(ratios - 1) < 0.05) and abs(ratios.mean() - 1) < 0.02, ratios


@pytest.mark.parametrize("shape", ["tango", "cubesat3u"])
def test_the_windowed_ray_cast_is_the_full_one_pixel_for_pixel(renderer, shape, tmp_path):
    """Tango, and a 3U CubeSat whose whip antennas are 4 mm thick: thin parts far from the
    body are where a window drawn round too few points would cut."""
    from bench.targets import cubesat3u
    from stages.common.target import load_target
    from stages.common.windows import film_window as window_of

    target = planned_target(load_config("default")) if shape == "tango" else load_target(cubesat3u(tmp_path / "t"))
    surfaces = TargetSurfaces(target.parts)
    points = np.concatenate([part.vertices for part in target.parts.values()])
    camera = renderer.lens.camera
    scale = 1.0 if shape == "tango" else 0.3  # the CubeSat at the same share of the image, 5-10 m / 3.3
    for cam_from_target in poses(61, 10):
        cam_from_target = cam_from_target.copy()
        cam_from_target[:3, 3] *= scale
        window = image_window(renderer.lens, window_of(renderer.lens.geometry, cam_from_target, points))
        windowed = surfaces.through_lens(cam_from_target, camera, window)
        full = surfaces.through_lens(cam_from_target, camera)
        np.testing.assert_array_equal(windowed.part, full.part)
        np.testing.assert_array_equal(windowed.depth_m, full.depth_m)
        np.testing.assert_array_equal(windowed.body_m, full.body_m)


def test_a_target_behind_the_camera_or_out_of_the_frame_gets_no_window_or_an_empty_one(renderer):
    geometry, points = renderer.lens.geometry, renderer.points_m
    behind = g.transform_from_qt([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -0.1])  # the camera inside the target
    assert film_window(geometry, behind, points) is None
    aside = g.transform_from_qt([1.0, 0.0, 0.0, 0.0], [50.0, 0.0, 5.0])
    window = film_window(geometry, aside, points)
    assert window is not None and window.empty
    assert image_window(renderer.lens, window) == Window(0, 0, 0, 0)


def test_a_kernel_window_holds_its_window_inside_the_film_at_a_size_of_the_ladder():
    geometry = RenderGeometry(991, 623, 1494.3)
    rng = np.random.default_rng(60)
    for _ in range(500):
        x, y = int(rng.integers(0, geometry.width)), int(rng.integers(0, geometry.height))
        window = Window(x, y, int(rng.integers(1, geometry.width - x + 1)),
                        int(rng.integers(1, geometry.height - y + 1)))
        grown = kernel_window(window, geometry)
        assert grown.x <= window.x and grown.y <= window.y
        assert grown.x + grown.width >= window.x + window.width and grown.y + grown.height >= window.y + window.height
        assert grown.x >= 0 and grown.y >= 0
        assert grown.x + grown.width <= geometry.width and grown.y + grown.height <= geometry.height
        for size, limit in ((grown.width, geometry.width), (grown.height, geometry.height)):
            step = 1 << max(0, size.bit_length() - 3)
            assert size % step == 0 or size == limit  # a size of the ladder, or the whole film
        assert grown.width <= 1.25 * window.width + 1 and grown.height <= 1.25 * window.height + 1


def test_a_window_sensor_casts_the_full_films_rays_through_the_same_pixels(renderer):
    mi, geometry = renderer.mi, renderer.lens.geometry
    full = mi.load_dict(renderer.sensor_spec)
    q = np.array([0.9, 0.1, -0.3, 0.2])
    world_from_cam = g.transform_from_qt(q / np.linalg.norm(q), [0.3, -1.0, 2.0])
    params = mi.traverse(full)
    params["to_world"] = sensor_to_world(mi, world_from_cam)
    params.update()

    def directions(sensor, xs, ys, width, height):
        ray, _ = sensor.sample_ray(0.0, 0.0, mi.Point2f((xs + 0.5) / width, (ys + 0.5) / height), mi.Point2f(0.5, 0.5))
        d = np.stack([np.array(ray.d.x), np.array(ray.d.y), np.array(ray.d.z)], 1).astype(np.float64)
        return d / np.linalg.norm(d, axis=1, keepdims=True), np.stack([np.array(ray.o.x), np.array(ray.o.y),
                                                                        np.array(ray.o.z)], 1)

    for window in (Window(400, 67, 320, 384), Window(0, 0, 64, 48), Window(geometry.width - 96, geometry.height - 40,
                                                                            96, 40)):
        sensor = renderer.windows.aimed(window.x, window.y, window.width, window.height, world_from_cam)
        ys, xs = np.mgrid[0:window.height:7, 0:window.width:5]
        xs, ys = xs.ravel().astype(np.float32), ys.ravel().astype(np.float32)
        inside, origin = directions(sensor, xs, ys, window.width, window.height)
        expected, expected_origin = directions(full, xs + window.x, ys + window.y, geometry.width, geometry.height)
        angle_px = np.linalg.norm(inside - expected, axis=1) * geometry.focal_px  # small angles, in film pixels
        assert angle_px.max() < 2e-3, window
        assert np.abs(origin - expected_origin).max() < 1e-6


def test_a_window_of_a_size_met_before_compiles_no_kernel(renderer):
    light = LIGHT / np.linalg.norm(LIGHT)
    first = g.transform_from_qt([0.9, 0.1, 0.3, 0.1] / np.linalg.norm([0.9, 0.1, 0.3, 0.1]), [0.1, -0.2, 5.0])
    moved = first.copy()
    moved[0, 3] += 0.03  # the window moves by a few pixels and keeps its size
    assert renderer.film_window(first) != renderer.film_window(moved)
    assert (renderer.film_window(first).width, renderer.film_window(first).height) == \
        (renderer.film_window(moved).width, renderer.film_window(moved).height)
    renderer.render(first, light, 3.0, 1)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        renderer.render(moved, light, 4.0, 2)
        compiled = [k for k in dr.kernel_history() if str(k["type"]).endswith("JIT") and not k["cache_hit"]]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert compiled == []


def test_a_worker_keeps_the_sensors_of_its_latest_window_sizes_only(renderer):
    """Each loaded window sensor holds its film: a worker keeps ``KEPT`` of them, the most
    recently used, however many sizes a dataset brings."""
    from stages.common.mitsuba_adapter import WindowSensors

    world_from_cam = np.eye(4)
    for size in range(WindowSensors.KEPT + 10):
        renderer.windows.aimed(0, 0, 16 + size, 16, world_from_cam)
    renderer.windows.aimed(0, 0, 16, 16, world_from_cam)  # evicted, loaded again
    kept = list(renderer.windows._loaded)
    assert len(kept) == WindowSensors.KEPT and kept[-1] == (16, 16) and (17, 16) not in kept


@pytest.mark.parametrize("seed", range(4))
def test_the_windowed_distortion_is_the_whole_films(seed):
    """A film zero outside a window, remapped in its image window only, is the whole remap,
    bit for bit; windows on the film's edge, and empty ones, among them."""
    from stages.common.lens import Lens
    from stages.common.windows import distorted

    rng = np.random.default_rng(seed)
    lens = Lens(lens_camera(load_config("smoke").camera))
    geometry = lens.geometry
    edges = [Window(0, 0, 40, 30), Window(geometry.width - 9, 5, 9, 60), Window(0, 0, geometry.width, geometry.height),
             Window(12, geometry.height - 3, 100, 3), Window(30, 30, 0, 0)]
    for index in range(30):
        x, y = int(rng.integers(0, geometry.width)), int(rng.integers(0, geometry.height))
        film = edges[index] if index < len(edges) else Window(
            x, y, int(rng.integers(0, geometry.width - x + 1)), int(rng.integers(0, geometry.height - y + 1)))
        pinhole = np.zeros((geometry.height, geometry.width, 4), np.float32)
        pinhole[film.slices()] = rng.uniform(0.0, 2.0, (film.height, film.width, 4))
        assert np.array_equal(distorted(lens, pinhole, film, image_window(lens, film)), lens.distort(pinhole)), film
