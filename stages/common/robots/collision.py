"""Clearance between capsules, and between capsules and boxes: the planner's collision
model of robot links (a segment swept by a sphere each), the room's walls and its
obstacles (their axis-aligned bounding boxes, so a clear verdict errs on the safe side).
"""

from __future__ import annotations

import numpy as np


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """(...) shortest distance between segments p1-q1 and p2-q2 (..., 3), broadcasting
    (Ericson, Real-Time Collision Detection, 2005, section 5.1.9: closest points of two
    segments, with the parameters clamped to [0, 1])."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    denominator = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denominator > 1e-12, np.clip((b * f - c * e) / denominator, 0.0, 1.0), 0.0)
        s = np.where(a > 1e-12, s, 0.0)
        t = np.where(e > 1e-12, (b * s + f) / e, 0.0)
        # t outside [0, 1]: clamp it and recompute s for the clamped t
        t_clamped = np.clip(t, 0.0, 1.0)
        # (a point for the second segment: t = 0, and s is the first's closest point to it)
        s = np.where(((t != t_clamped) | (e <= 1e-12)) & (a > 1e-12), np.clip((b * t_clamped - c) / a, 0.0, 1.0), s)
    closest1 = p1 + s[..., None] * d1
    closest2 = p2 + t_clamped[..., None] * d2
    return np.linalg.norm(closest1 - closest2, axis=-1)


def capsules_clear(a1: np.ndarray, b1: np.ndarray, r1: np.ndarray, a2: np.ndarray, b2: np.ndarray,
                   r2: np.ndarray, clearance_m: float = 0.0) -> bool:
    """Whether every capsule of set 1 (C1, 3 ends; radii C1) is at least ``clearance_m`` from
    every capsule of set 2."""
    distance = segment_distance(a1[:, None], b1[:, None], a2[None, :], b2[None, :])
    return bool(np.all(distance >= r1[:, None] + r2[None, :] + clearance_m))


def inside_box(a: np.ndarray, b: np.ndarray, radius: np.ndarray, low: np.ndarray, high: np.ndarray,
               clearance_m: float = 0.0) -> bool:
    """Whether capsules (C, 3 ends; radii C) lie inside the box [low, high] with ``clearance_m``
    to spare (a capsule is inside when both ends are, shrunk by its radius: the box is convex)."""
    margin = (radius + clearance_m)[:, None]
    ends = np.stack([a, b])
    return bool(np.all(ends >= low + margin) and np.all(ends <= high - margin))


def clear_of_box(a: np.ndarray, b: np.ndarray, radius: np.ndarray, low: np.ndarray, high: np.ndarray,
                 samples: int = 16) -> bool:
    """Whether capsules (C, 3 ends; radii C) keep out of the box [low, high]: points along each
    axis, every 1/``samples`` of it, stay farther than the radius from the box."""
    fractions = np.linspace(0.0, 1.0, samples + 1)[None, :, None]
    points = a[:, None, :] + fractions * (b - a)[:, None, :]  # (C, S, 3)
    outside = np.maximum(np.maximum(low - points, points - high), 0.0)
    distance = np.linalg.norm(outside, axis=-1)
    step = np.linalg.norm(b - a, axis=-1) / samples / 2  # a point between samples is at most this nearer
    return bool(np.all(distance > (radius + step)[:, None]))
