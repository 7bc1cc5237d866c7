"""The training images' Earth (``stages.common.earth``): its texture lookup is bilinear
interpolation that wraps in longitude and clamps in latitude, and the planet it draws is a
lit sphere seen through the lens, on seeded orbits."""

import numpy as np
import pytest

from stages.common import earth
from stages.common.lens import LensCamera, pixel_rays

CAMERA = LensCamera(np.array([[300.0, 0, 159.5], [0, 300.0, 99.5], [0, 0, 1]]),
                    np.array([-0.2, 0.1, 0.001, -0.001, 0.0]), 320, 200)


def exact_bilinear(texture: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Texture (H, W, C) at (N,) continuous pixel coordinates, u wrapping and v clamped,
    in double precision: the definition the lookup must follow."""
    height, width = texture.shape[:2]
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    left, right = u0 % width, (u0 + 1) % width
    top, bottom = np.clip(v0, 0, height - 1), np.clip(v0 + 1, 0, height - 1)
    upper = texture[top, left] * (1 - fu) + texture[top, right] * fu
    lower = texture[bottom, left] * (1 - fu) + texture[bottom, right] * fu
    return upper * (1 - fv) + lower * fv


def test_the_texture_lookup_is_bilinear_wraps_in_longitude_and_clamps_in_latitude():
    texture = earth.albedo_map().astype(float)
    height, width = texture.shape[:2]
    rng = np.random.default_rng(60)
    u = np.concatenate([rng.uniform(-0.5, width - 0.5, 4000), [-0.5, -0.25, width - 0.75, width - 0.5]])
    v = np.concatenate([rng.uniform(-0.5, height - 0.5, 4000), [-0.5, 3.0, height - 0.5, height - 0.6]])
    looked_up = earth._bilinear(width, u.astype(np.float32)[None], v.astype(np.float32)[None])[0]
    expected = exact_bilinear(texture, u, v)
    # OpenCV's remap steps its weights by 1/32 of a pixel: the error is at most half a step
    # of the largest neighbour difference
    step = np.abs(np.diff(texture, axis=1)).max() + np.abs(np.diff(texture, axis=0)).max()
    assert np.abs(looked_up - expected).max() <= step / 64 + 1e-5
    assert np.abs(looked_up - expected).mean() < 2e-3
    # across the seam: half way between the last column and the first
    seam = earth._bilinear(width, np.float32([[width - 0.5]]), np.float32([[10.0]]))[0, 0]
    assert seam == pytest.approx(0.5 * (texture[10, -1] + texture[10, 0]), abs=step / 64 + 1e-5)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_earth_is_a_lit_sphere_seen_through_the_lens(seed):
    rng = np.random.default_rng(seed)
    altitude = rng.uniform(300e3, 1500e3)
    nadir = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), 1.0])
    nadir /= np.linalg.norm(nadir)
    # the sun near the horizon of the point below: the terminator crosses the image
    light = np.cross(nadir, rng.normal(size=3)) + rng.normal(0, 0.1, 3)
    light /= np.linalg.norm(light)
    centre = nadir * (earth.EARTH_RADIUS_M + altitude)
    image, seen = earth.earth_image(CAMERA, centre, np.eye(3), light, 3.0)
    assert image.shape == (200, 320, 3) and image.dtype == np.float32 and np.isfinite(image).all()
    rays = pixel_rays(CAMERA)
    along = rays @ centre
    hit = ((along**2 - (centre @ centre - earth.EARTH_RADIUS_M**2)) > 0) & (along > 0)
    assert seen == hit.any()
    flat = image.reshape(-1, 3)
    assert (flat[~hit] == 0).all() and (flat >= 0).all()
    # where the sun is below the horizon only the limb's haze shows: far darker than the day
    # side (seen from low orbit, the image's normals turn by a few degrees only)
    distance = along - np.sqrt(np.maximum(along**2 - (centre @ centre - earth.EARTH_RADIUS_M**2), 0))
    normals = (rays * distance[:, None] - centre) / earth.EARTH_RADIUS_M
    day = hit & (normals @ light > 0.02)
    night = hit & (normals @ light < -0.02)
    assert day.sum() > 1000 and night.sum() > 1000
    assert flat[night].mean() < 0.1 * flat[day].mean()


def test_an_earth_behind_the_camera_is_not_seen():
    image, seen = earth.earth_image(CAMERA, np.array([0.0, 0.0, -(earth.EARTH_RADIUS_M + 5e5)]), np.eye(3),
                                    np.array([0.0, 0.0, 1.0]), 3.0)
    assert not seen and not image.any()
