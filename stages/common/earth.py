"""An Earth-like background for training images: a lit planet seen from low orbit behind
the target, composited under the render (whose background is empty space).

The planet is a sphere of Earth's radius ray-traced per pixel through the lens model, lit
by the same sun as the target (Lambert), coloured by a fixed albedo map of smooth 3-D
value noise (oceans, land, clouds) seen in a random orientation, with a thin bright limb.
Deterministic for a given generator.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from stages.common.lens import LensCamera, pixel_directions, pixel_rays

EARTH_RADIUS_M = 6_371_000.0
OCEAN = np.array([0.02, 0.06, 0.16])
LAND = np.array([0.10, 0.11, 0.06])
CLOUD = np.array([0.75, 0.75, 0.78])
#: the albedo map's width in pixels (its height is half)
ALBEDO_WIDTH = 2048


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


@functools.lru_cache(maxsize=1)
def albedo_map(width: int = ALBEDO_WIDTH) -> np.ndarray:
    """Equirectangular albedo (width / 2, width, 3) float32 of an Earth-like planet: oceans,
    land and clouds from fixed-seed value noise on the sphere. Built once (seconds) and
    kept in the user's cache directory, so that recycled workers load it."""
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "speedplus" / f"earth-{width}-v1.npy"
    if cache.exists():
        try:
            return np.load(cache)
        except (OSError, ValueError):
            pass  # a damaged cache file is rebuilt
    texture = _build_albedo_map(width)
    cache.parent.mkdir(parents=True, exist_ok=True)
    temporary = cache.with_name(f".{cache.name}.{os.getpid()}.tmp")
    with open(temporary, "wb") as handle:
        np.save(handle, texture)
    os.replace(temporary, cache)
    return texture


def _build_albedo_map(width: int) -> np.ndarray:
    height = width // 2
    lat = (0.5 - (np.arange(height) + 0.5) / height) * np.pi
    lon = ((np.arange(width) + 0.5) / width * 2 - 1) * np.pi
    lon_grid, lat_grid = np.meshgrid(lon, lat)
    points = np.stack([np.cos(lat_grid) * np.cos(lon_grid), np.cos(lat_grid) * np.sin(lon_grid),
                       np.sin(lat_grid)], axis=-1).reshape(-1, 3)
    rng = np.random.default_rng(0xEA27)
    land = _value_noise(points * 2.0, rng, octaves=7) > 0.55
    clouds = np.clip((_value_noise(points * 6.0, rng, octaves=6) - 0.45) * 3.0, 0.0, 1.0)
    albedo = np.where(land[:, None], LAND, OCEAN)
    albedo = albedo * (1 - clouds[:, None]) + CLOUD * clouds[:, None]
    return albedo.reshape(height, width, 3).astype(np.float32)


@functools.lru_cache(maxsize=2)
def _wrapped(width: int) -> np.ndarray:
    """The albedo map with one column of the other side added left and right and its first
    and last rows repeated (H + 2, W + 2, 3), so that a bilinear lookup wraps in longitude
    and clamps in latitude with nothing but a replicated border."""
    texture = albedo_map(width)
    wrapped = np.concatenate([texture[:, -1:], texture, texture[:, :1]], axis=1)
    return np.ascontiguousarray(np.concatenate([wrapped[:1], wrapped, wrapped[-1:]], axis=0))


def _bilinear(width: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The albedo map of ``width`` at continuous pixel coordinates ``u``, ``v`` (H, W) float32,
    u in [-0.5, width - 0.5) wrapping round, v clamped: (H, W, 3) float32. OpenCV's remap
    (its interpolation weights in steps of 1/32 pixel): about 12 ms for a 1920 x 1200 frame,
    where numpy's fancy indexing took 1.4 s."""
    import cv2

    return cv2.remap(_wrapped(width), u + 1.0, v + 1.0, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


#: image rows the Earth is computed for at once: its temporaries stay in the cache
_BAND_ROWS = 32


def earth_image(camera: LensCamera, centre_cam_m: np.ndarray, cam_from_planet: np.ndarray,
                light_dir_cam: np.ndarray, irradiance: float) -> tuple[np.ndarray, bool]:
    """Linear radiance (H, W, 3) of the Earth whose centre is at ``centre_cam_m`` (3,) in the
    camera frame, its surface turned by ``cam_from_planet`` (3, 3), lit from ``light_dir_cam``
    (3,) with ``irradiance`` W/m^2; and whether any pixel sees it. Computed a band of rows
    at a time: each pixel is on its own, so the values are those of the whole frame at once,
    and at 1920 x 1200 it takes 0.09 CPU-s instead of 0.4-1.0 (here every fresh frame-sized
    temporary is paid in page faults)."""
    rays, directions = pixel_rays(camera), pixel_directions(camera)  # cached per camera
    image = np.zeros((camera.height, camera.width, 3), np.float32)
    seen = False
    for row in range(0, camera.height, _BAND_ROWS):
        rows = min(_BAND_ROWS, camera.height - row)
        band = slice(row * camera.width, (row + rows) * camera.width)
        seen |= _earth_band(rays[band], directions[:, band], image[row:row + rows], centre_cam_m, cam_from_planet,
                            light_dir_cam, irradiance)
    return image, seen


def _earth_band(rays: np.ndarray, directions: np.ndarray, out: np.ndarray, centre_cam_m: np.ndarray,
                cam_from_planet: np.ndarray, light_dir_cam: np.ndarray, irradiance: float) -> bool:
    """The Earth's radiance through the rows of ``rays`` (R * W, 3), float64, and the same
    ``directions`` (3, R * W) float32, into ``out`` (R, W, 3); whether any of them sees it."""
    import cv2
    centre = np.asarray(centre_cam_m, float)
    along = rays @ centre
    miss_sq = along**2 - (centre @ centre - EARTH_RADIUS_M**2)
    hit = (miss_sq > 0) & (along > 0)
    if not hit.any():
        return False
    # every pixel at once, the misses zeroed at the end; single precision after the hit test
    # (which needs double): a normal's direction to 1e-7, half the memory traffic
    distance = np.where(hit, along - np.sqrt(np.maximum(miss_sq, 0.0)), 0.0).astype(np.float32)
    normals = directions * distance
    normals -= centre.astype(np.float32)[:, None]
    normals *= np.float32(1.0 / EARTH_RADIUS_M)
    turn = np.asarray(cam_from_planet, np.float32)
    surface = [normals[0] * turn[0, axis] + normals[1] * turn[1, axis] + normals[2] * turn[2, axis]
               for axis in range(3)]
    # the albedo map's pixel coordinates: longitude from -pi (u = -0.5), latitude from +pi/2 (v = -0.5)
    longitude, latitude = np.arctan2(surface[1], surface[0]), np.arcsin(np.clip(surface[2], -1, 1))
    u = (longitude + np.float32(np.pi)) * np.float32(ALBEDO_WIDTH / (2 * np.pi)) - 0.5
    v = (np.float32(0.5) - latitude / np.float32(np.pi)) * np.float32(ALBEDO_WIDTH // 2) - 0.5
    shape = out.shape[:2]
    albedo = _bilinear(ALBEDO_WIDTH, u.reshape(shape), v.reshape(shape))
    light = np.asarray(light_dir_cam, np.float32)
    sun = np.clip(normals[0] * light[0] + normals[1] * light[1] + normals[2] * light[2], 0.0, None)
    facing = np.clip(-(normals * directions).sum(axis=0), 0.0, 1.0)  # 0 at the limb
    haze = (1.0 - facing) ** 8  # the atmosphere seen edge-on
    glow = haze * np.clip(sun + np.float32(0.2), 0.0, 1.0)
    scale = np.float32(irradiance / np.pi)
    sun *= scale * hit
    glow *= scale * np.float32(0.5) * hit
    sun, glow, hit = sun.reshape(shape), glow.reshape(shape), hit.reshape(shape)
    # a colour plane at a time: the same float32 operations as over (R, W, 3) with the light
    # broadcast along the colours, at a third of the time (no inner loop of three)
    planes = []
    for plane, tint in zip(cv2.split(albedo), (0.3, 0.5, 1.0), strict=True):
        plane *= sun
        plane += glow * np.float32(tint)
        planes.append(np.where(hit, plane, np.float32(0.0)))  # a miss is black, whatever its arithmetic
    out[...] = cv2.merge(planes)
    return True


def earth_background(camera: LensCamera, light_dir_cam: np.ndarray, irradiance: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Linear radiance (H, W, 3) of the Earth seen by ``camera``, lit from ``light_dir_cam``
    (3,) with ``irradiance`` W/m^2, for an orbit altitude of 300-1500 km with the planet
    somewhere behind the target and a random region of it below."""
    altitude = rng.uniform(300e3, 1500e3)
    # the nadir direction: mostly away from the camera, tilted so that the limb often shows
    nadir = np.array([rng.normal(0, 0.6), rng.normal(0, 0.6), 1.0])
    nadir /= np.linalg.norm(nadir)
    spin = np.linalg.qr(rng.normal(size=(3, 3)))[0]  # which part of the planet is below
    return earth_image(camera, nadir * (EARTH_RADIUS_M + altitude), spin.T, light_dir_cam, irradiance)[0]
