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
from stages.common.surface import TargetSurfaces
from stages.common.windows import Window, film_window, image_window
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


def test_a_window_holds_the_films_own_pixels_but_for_their_noise():
    """The window's render and Mitsuba's own film: the same light over the target, and each
    pixel as noisy (RGB and alpha): the same rays, the same box filter, other samples."""
    config = load_config("smoke")
    renderer = TargetRenderer(lens_camera(config.camera), planned_target(config), spp=64, max_depth=3, threads=1)
    cam_from_target = g.transform_from_qt([0.8, 0.2, -0.5, 0.26] / np.linalg.norm([0.8, 0.2, -0.5, 0.26]),
                                          [0.1, 0.05, 4.0])
    window = renderer.film_window(cam_from_target)
    assert window is not None and 2000 < window.width * window.height < 0.8 * 337 * 213
    windowed = np.array([renderer.render(cam_from_target, LIGHT, 3.0, seed) for seed in range(1, 5)])
    full = np.array([_full(renderer, cam_from_target, seed) for seed in range(1, 5)])
    lit = full[0][..., 3] > 0  # where the target is: the noise lives there
    for channel in range(4):
        # the image's mean over its seeds: the window's within the noise of the film's
        means = windowed[:, lit, channel].mean(axis=1), full[:, lit, channel].mean(axis=1)
        spread = np.sqrt(means[0].var(ddof=1) / 4 + means[1].var(ddof=1) / 4)
        assert abs(means[0].mean() - means[1].mean()) < 5 * spread, channel
        # pixel by pixel: each pixel's spread over the seeds, the window's as the film's (the
        # estimate's own spread, film against film over other seeds, reached 6% at 16 seeds)
        spreads = windowed[:, lit, channel].var(axis=0, ddof=1).mean(), full[:, lit, channel].var(axis=0, ddof=1).mean()
        assert 0.8 < spreads[0] / spreads[1] < 1.25, (channel, spreads)
    assert np.array_equal(windowed[0], renderer.render(cam_from_target, LIGHT, 3.0, 1))  # its seed, its bytes
    assert not np.array_equal(windowed[0], windowed[1])


def test_a_window_of_any_size_compiles_no_kernel(renderer):
    """Every window of every pose is one compiled kernel: after the first render, a window of
    another size and place compiles nothing."""
    light = LIGHT / np.linalg.norm(LIGHT)
    first = g.transform_from_qt([0.9, 0.1, 0.3, 0.1] / np.linalg.norm([0.9, 0.1, 0.3, 0.1]), [0.1, -0.2, 5.0])
    nearer = g.transform_from_qt([0.5, -0.5, 0.5, 0.5], [-0.6, 0.3, 3.0])
    sizes = {(renderer.film_window(pose).width, renderer.film_window(pose).height) for pose in (first, nearer)}
    assert len(sizes) == 2
    renderer.render(first, light, 3.0, 1)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        renderer.render(nearer, light, 4.0, 2)
        compiled = [k for k in dr.kernel_history() if str(k["type"]).endswith("JIT") and not k["cache_hit"]]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert compiled == []


@pytest.mark.parametrize(("seed", "margin_px"), [(0, 4), (1, 4), (2, 0), (3, 0)])
def test_the_windowed_distortion_is_the_whole_films(seed, margin_px):
    """A film zero outside a window, remapped in its image window only, is the whole remap,
    bit for bit; windows on the film's edge, and empty ones, among them; with the renders'
    margin round the lens's samples, and with none, where the remap replicates the border."""
    from stages.common.lens import Lens
    from stages.common.windows import distorted, replicates_border

    rng = np.random.default_rng(seed)
    lens = Lens(lens_camera(load_config("smoke").camera), margin_px=margin_px)
    assert lens.reaches_border == (margin_px == 0)
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
        if index < 4:  # the windows on the film's edge
            assert replicates_border(lens, film) == lens.reaches_border, film


@pytest.mark.parametrize("spp", [48, 64])
def test_a_windows_pixels_are_the_same_bits_whatever_the_thread_count(spp):
    """Whole targets' windows, and small windows whose launch Dr.Jit splits between its
    threads at a few packets (31 x 31 pixels at 64 samples differed there when a pixel's
    samples were lanes summed by atomic adds)."""
    config = load_config("smoke")
    renderer = TargetRenderer(lens_camera(config.camera), planned_target(config), spp=spp, max_depth=3, threads=1)
    try:
        for index, cam_from_target in enumerate(poses(62, 3)):
            window = renderer.film_window(cam_from_target)
            dr.set_thread_count(1)
            one = renderer.render(cam_from_target, LIGHT, 3.0, index)
            small = [renderer.loaded.render_window(window.x + 2, window.y + 2, size, size, spp, index)
                     for size in (9, 31, 45)]
            dr.set_thread_count(2)
            assert np.array_equal(one, renderer.render(cam_from_target, LIGHT, 3.0, index)), index
            for size, pixels in zip((9, 31, 45), small, strict=True):
                again = renderer.loaded.render_window(window.x + 2, window.y + 2, size, size, spp, index)
                assert np.array_equal(pixels, again), (index, size)
    finally:
        dr.set_thread_count(1)


def test_a_window_is_refused_for_a_sensor_whose_film_it_would_not_reproduce():
    """A stratified sampler (the virtual testbed's) would lose its strata in a window."""
    from stages.common.lens import RenderGeometry
    from stages.common.mitsuba_adapter import LoadedScene, load_mitsuba, sensor

    mi = load_mitsuba()
    stratified = sensor(mi, RenderGeometry(64, 48, 60.0), far_clip_m=10.0, pixel_format="rgba", sampler="multijitter")
    scene = LoadedScene(mi, {"type": "scene", "integrator": {"type": "path"}, "sensor": stratified})
    with pytest.raises(ValueError, match="independent samples"):
        scene.render_window(0, 0, 8, 8, 4, 1)
