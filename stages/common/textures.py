"""Procedural textures of the looks (``stages.common.looks``). The mock-up's make it look
unlike the CAD model: wrinkled multi-layer-insulation foil (a normal map), a solar-cell
grid with reflective cover glass, a riveted aluminium panel with handling marks and a
mottled rock. The synthetic twin's solar cells are a clean regular grid. All are numpy
arrays, deterministic for a seed, in texture space (row 0 = v 0, as Mitsuba reads them).
"""

from __future__ import annotations

import cv2
import numpy as np


def smooth_noise(rng: np.random.Generator, size: int, octaves: tuple[tuple[float, float], ...]) -> np.ndarray:
    """(size, size) sum of Gaussian-blurred white noise: (blur sigma px, amplitude) per octave."""
    field = np.zeros((size, size))
    for sigma, amplitude in octaves:
        noise = cv2.GaussianBlur(rng.standard_normal((size, size)), (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        field += amplitude * noise / (noise.std() + 1e-12)
    return field


def normal_map_from_height(height: np.ndarray, strength: float) -> np.ndarray:
    """Tangent-space normal map (H, W, 3) in [0, 1] of a height field (texture pixels)."""
    dy, dx = np.gradient(height)
    normals = np.stack([-strength * dx, -strength * dy, np.ones_like(height)], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return (normals * 0.5 + 0.5).astype(np.float32)


def foil_normal_map(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Crumpled foil: creases (ridged noise) over broad undulations."""
    broad = smooth_noise(rng, size, ((48.0, 1.0), (24.0, 0.5)))
    creases = np.abs(smooth_noise(rng, size, ((14.0, 1.0), (7.0, 0.3))))
    height = 6.0 * broad - 5.0 * creases
    return normal_map_from_height(height, strength=1.0)


def solar_cells(rng: np.random.Generator, size: int = 512, cells: tuple[int, int] = (6, 8)) -> np.ndarray:
    """Dark cells with silver bus bars and gaps (H, W, 3) reflectance in [0, 1]."""
    image = np.zeros((size, size, 3), dtype=np.float32)
    rows, cols = cells
    shade = 0.05 + 0.02 * rng.uniform(size=(rows, cols))
    cell_h, cell_w = size / rows, size / cols
    v, u = np.mgrid[0:size, 0:size]
    row, col = np.minimum((v / cell_h).astype(int), rows - 1), np.minimum((u / cell_w).astype(int), cols - 1)
    image[...] = np.stack([shade[row, col] * 0.8, shade[row, col] * 0.9, shade[row, col] * 1.4], axis=-1)
    in_v, in_u = (v % cell_h) / cell_h, (u % cell_w) / cell_w
    gaps = (in_v < 0.03) | (in_v > 0.97) | (in_u < 0.03) | (in_u > 0.97)
    fingers = (np.abs(((in_u * 12) % 1.0) - 0.5) < 0.04) & ~gaps
    image[gaps] = 0.55
    image[fingers] = 0.35
    return np.clip(image, 0, 1)


def rear_panel(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Brushed aluminium panels with seams, rivets and smudges (H, W, 3) specular tint."""
    v, u = np.mgrid[0:size, 0:size] / size
    base = 0.75 + 0.08 * smooth_noise(rng, size, ((40.0, 1.0),))
    brushed = cv2.GaussianBlur(rng.standard_normal((size, size)), (0, 0), sigmaX=12.0, sigmaY=0.6)
    base += 0.04 * brushed / (brushed.std() + 1e-12)
    seams = (np.abs(u - 0.5) < 0.004) | (np.abs(v - 0.33) < 0.004) | (np.abs(v - 0.66) < 0.004)
    base[seams] = 0.25
    for cu in np.linspace(0.06, 0.94, 12):
        for cv in (0.04, 0.3, 0.36, 0.63, 0.69, 0.96):
            base[np.hypot(u - cu, v - cv) < 0.006] = 0.45
    smudges = np.clip(smooth_noise(rng, size, ((18.0, 1.0),)), 0.8, None) - 0.8
    base -= 0.25 * smudges
    return np.repeat(np.clip(base, 0.05, 1.0)[..., None], 3, axis=-1).astype(np.float32)


def clean_solar_cells(cells: tuple[int, int] = (8, 12), px_per_cell: int = 24) -> np.ndarray:
    """Diffuse reflectance (H, W, 3) of a regular solar-cell array: dark blue cells, silver
    bus bars and a thin frame (the synthetic model's clean look; the mock-up's is noisy)."""
    rows, cols = cells
    h, w = rows * px_per_cell, cols * px_per_cell
    vs, us = np.mgrid[0:h, 0:w]
    image = np.empty((h, w, 3), np.float32)
    image[:] = (0.02, 0.03, 0.09)
    gap = ((us % px_per_cell) < 2) | ((vs % px_per_cell) < 2)
    fingers = (us % (px_per_cell // 3)) == 0
    image[fingers] = (0.12, 0.12, 0.14)
    image[gap] = (0.55, 0.55, 0.58)
    return image


def mottled_rock(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Diffuse reflectance (H, W, 3) of a painted rock replica: grey-brown with blotches and
    grain (the synthetic twin's rock is one flat colour)."""
    field = smooth_noise(rng, size, ((12.0, 1.0), (3.0, 0.5), (0.8, 0.25)))
    shade = np.clip(0.22 + 0.06 * field, 0.05, 0.6)
    return np.stack([shade * 1.08, shade, shade * 0.9], axis=-1).astype(np.float32)
