"""The lens model's pixel rays: traced back through the distortion, cached per camera."""

import cv2
import numpy as np
import pytest

from stages.common import lens
from stages.common.kept import Kept
from stages.common.lens import LensCamera, pixel_rays

K = np.array([[900.0, 0, 159.5], [0, 900.0, 99.5], [0, 0, 1]])
DIST = np.array([-0.2238, 0.5141, -0.000665, -0.000214, -0.1312])


def test_pixel_rays_project_back_onto_their_pixels():
    camera = LensCamera(K, DIST, 320, 200)
    rays = pixel_rays(camera)
    assert rays.shape == (320 * 200, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    projected, _ = cv2.projectPoints(np.ascontiguousarray(rays[::97]), np.zeros(3), np.zeros(3), K, DIST)
    us, vs = np.meshgrid(np.arange(320.0), np.arange(200.0))
    np.testing.assert_allclose(projected.reshape(-1, 2), np.stack([us.ravel(), vs.ravel()], 1)[::97], atol=1e-6)


def test_pixel_rays_are_cached_per_camera_bit_for_bit_and_read_only(monkeypatch):
    camera = LensCamera(K, DIST, 320, 200)
    first = pixel_rays(camera)
    monkeypatch.setattr(lens, "_PIXEL_RAYS", Kept(4))
    fresh = pixel_rays(LensCamera(K.copy(), DIST.copy(), 320, 200))
    assert fresh.tobytes() == first.tobytes()  # a cached answer is the computed one
    assert pixel_rays(LensCamera(K.copy(), DIST.copy(), 320, 200)) is fresh
    other = pixel_rays(LensCamera(K, DIST * 0.5, 320, 200))
    assert other is not fresh and not np.array_equal(other, fresh)
    with pytest.raises(ValueError):
        fresh[0, 0] = 1.0


def test_pixel_directions_are_the_rays_axes_in_single_precision_cached_per_camera():
    camera = LensCamera(K, DIST, 320, 200)
    directions = lens.pixel_directions(camera)
    assert directions.shape == (3, 320 * 200) and directions.dtype == np.float32 and directions.flags.c_contiguous
    assert np.array_equal(directions, pixel_rays(camera).T.astype(np.float32))
    assert lens.pixel_directions(LensCamera(K.copy(), DIST.copy(), 320, 200)) is directions
    with pytest.raises(ValueError):
        directions[0, 0] = 1.0
