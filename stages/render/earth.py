"""An Earth-like background for training images: a lit planet seen from low orbit behind
the target, composited under the render (whose background is empty space).

The planet is a sphere of Earth's radius ray-traced per pixel through the lens model, lit
by the same sun as the target (Lambert), coloured by smooth 3-D value noise (oceans,
land, clouds), with a thin bright limb. Deterministic for a given generator.
"""

from __future__ import annotations

import numpy as np

from stages.lens import LensCamera, undistort_pixels

EARTH_RADIUS_M = 6_371_000.0
OCEAN = np.array([0.02, 0.06, 0.16])
LAND = np.array([0.10, 0.11, 0.06])
CLOUD = np.array([0.75, 0.75, 0.78])


def _value_noise(points: np.ndarray, rng: np.random.Generator, octaves: int = 5) -> np.ndarray:
    """Fractal value noise in [0, 1] at unit-sphere points (N, 3)."""
    lattice = rng.random((32, 32, 32))
    total, amplitude, norm = np.zeros(len(points)), 1.0, 0.0
    for octave in range(octaves):
        scaled = (points + 1.0) * (2.0 * 2**octave)
        base = np.floor(scaled).astype(int)
        frac = scaled - base
        smooth = frac * frac * (3 - 2 * frac)
        value = np.zeros(len(points))
        for corner in range(8):
            offset = np.array([(corner >> 0) & 1, (corner >> 1) & 1, (corner >> 2) & 1])
            weight = np.prod(np.where(offset, smooth, 1 - smooth), axis=1)
            index = (base + offset) % 32
            value += weight * lattice[index[:, 0], index[:, 1], index[:, 2]]
        total += amplitude * value
        norm += amplitude
        amplitude *= 0.5
    return total / norm


def earth_background(camera: LensCamera, light_dir_cam: np.ndarray, irradiance: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Linear radiance (H, W, 3) of the Earth seen by ``camera``, lit from ``light_dir_cam``
    (3,) with ``irradiance`` W/m^2, for an orbit altitude of 300-1500 km with the planet somewhere behind the target."""
    altitude = rng.uniform(300e3, 1500e3)
    # the nadir direction: mostly away from the camera, tilted so that the limb often shows
    nadir = np.array([rng.normal(0, 0.6), rng.normal(0, 0.6), 1.0])
    nadir /= np.linalg.norm(nadir)
    centre = nadir * (EARTH_RADIUS_M + altitude)
    us, vs = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    normalised = undistort_pixels(np.stack([us.ravel(), vs.ravel()], 1), camera)
    rays = np.concatenate([normalised, np.ones((len(normalised), 1))], 1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    # ray-sphere intersection from the camera (origin)
    along = rays @ centre
    miss_sq = along**2 - (centre @ centre - EARTH_RADIUS_M**2)
    hit = (miss_sq > 0) & (along > 0)
    image = np.zeros((len(rays), 3))
    if not hit.any():
        return image.reshape(camera.height, camera.width, 3).astype(np.float32)
    distance = along[hit] - np.sqrt(miss_sq[hit])
    normals = (rays[hit] * distance[:, None] - centre) / EARTH_RADIUS_M
    spin = np.linalg.qr(rng.normal(size=(3, 3)))[0]  # a random longitude/latitude under the camera
    surface = normals @ spin.T
    land = _value_noise(surface, rng) > 0.55
    clouds = np.clip((_value_noise(surface * 1.7, rng) - 0.45) * 3.0, 0.0, 1.0)
    albedo = np.where(land[:, None], LAND, OCEAN)
    albedo = albedo * (1 - clouds[:, None]) + CLOUD * clouds[:, None]
    sun = np.clip(normals @ np.asarray(light_dir_cam, float), 0.0, None)
    facing = np.clip(-(normals * rays[hit]).sum(axis=1), 0.0, 1.0)  # 0 at the limb
    haze = (1.0 - facing) ** 8  # the atmosphere seen edge-on
    radiance = irradiance / np.pi * (albedo * sun[:, None] + 0.5 * np.array([0.3, 0.5, 1.0]) * haze[:, None]
                                     * np.clip(sun[:, None] + 0.2, 0.0, 1.0))
    image[hit] = radiance
    return image.reshape(camera.height, camera.width, 3).astype(np.float32)
