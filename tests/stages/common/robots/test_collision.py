"""Capsule clearances (stages/common/robots/collision.py) against brute force, seeded."""

from __future__ import annotations

import numpy as np

from stages.common.robots.collision import capsules_clear, clear_of_box, inside_box, segment_distance


def _brute(p1, q1, p2, q2, n=401):
    s = np.linspace(0, 1, n)
    a = p1 + s[:, None] * (q1 - p1)
    b = p2 + s[:, None] * (q2 - p2)
    return np.linalg.norm(a[:, None] - b[None], axis=-1).min()


def test_segment_distance_is_the_closest_approach():
    rng = np.random.default_rng(0)
    for _ in range(200):
        p1, q1, p2, q2 = rng.normal(size=(4, 3))
        if rng.random() < 0.2:
            q2 = p2 + rng.normal(size=3) * 1e-13  # a point
        exact = segment_distance(p1, q1, p2, q2)
        brute = _brute(p1, q1, p2, q2)
        assert exact <= brute + 1e-12 and brute - exact < 2e-2 * (1 + brute)


def test_parallel_segments_and_batches():
    p1, q1 = np.array([0.0, 0, 0]), np.array([1.0, 0, 0])
    p2, q2 = np.array([0.5, 1, 0]), np.array([2.0, 1, 0])
    assert segment_distance(p1, q1, p2, q2) == 1.0
    batch = segment_distance(np.stack([p1, p1]), np.stack([q1, q1]), np.stack([p2, p2 + 3]), np.stack([q2, q2 + 3]))
    assert batch.shape == (2,) and batch[1] > batch[0]


def test_capsules_against_each_other_and_boxes():
    a = np.array([[0.0, 0, 0]])
    b = np.array([[1.0, 0, 0]])
    assert capsules_clear(a, b, np.array([0.1]), a + [0, 0.3, 0], b + [0, 0.3, 0], np.array([0.1]))
    assert not capsules_clear(a, b, np.array([0.1]), a + [0, 0.3, 0], b + [0, 0.3, 0], np.array([0.1]), 0.15)
    low, high = np.zeros(3), np.array([2.0, 2.0, 2.0])
    assert inside_box(a + 0.5, b + 0.5, np.array([0.2]), low, high)
    assert not inside_box(a + 0.1, b + 0.1, np.array([0.2]), low, high)
    assert clear_of_box(a + [0, 0, 3], b + [0, 0, 3], np.array([0.5]), low, high)
    assert not clear_of_box(a + [0, 0, 2.3], b + [0, 0, 2.3], np.array([0.5]), low, high)
