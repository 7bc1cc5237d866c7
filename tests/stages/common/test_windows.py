"""Rendering and ray casting only where the target can be (issue 60): on seeded poses, some
half out of the image, the windowed twin differs from the full film's only in its noise, and
the windowed mask and ground truth are the full ray cast's, pixel for pixel."""

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
