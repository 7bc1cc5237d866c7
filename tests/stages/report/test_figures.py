"""The report's brightening: NumPy's percentile and float32 scaling, faster."""

import numpy as np
import pytest

from stages.report.figures import brighten, percentile_8bit


def test_the_8bit_percentile_is_numpys_to_the_bit():
    """Seeded property: any size, spread and quantile, grey or colour."""
    rng = np.random.default_rng(0)
    for case in range(2000):
        size = int(rng.integers(1, 4000))
        shape = (size,) if case % 3 else (size, 3)
        image = np.clip(rng.gamma(rng.uniform(0.2, 3), rng.uniform(1, 60), shape), 0, 255).astype(np.uint8)
        q = float(rng.choice([99.5, 50.0, 0.1, 100.0, 0.0, rng.uniform(0, 100)]))
        assert percentile_8bit(image, q) == np.percentile(image, q)


def test_brightening_is_the_float32_scaling_of_every_pixel():
    rng = np.random.default_rng(1)
    for gain in (None, 1.0, 3.7, 16.0):
        image = np.clip(rng.gamma(0.6, 20, (120, 90, 3)), 0, 255).astype(np.uint8)
        expected_gain = gain or float(np.clip(230.0 / max(np.percentile(image, 99.5), 1.0), 1.0, 16.0))
        expected = np.clip(image.astype(np.float32) * expected_gain, 0, 255).astype(np.uint8)
        np.testing.assert_array_equal(brighten(image, gain), expected)
    dark = np.zeros((8, 8), np.uint8)
    np.testing.assert_array_equal(brighten(dark), dark)  # a black image gains 16x of nothing
    assert brighten(np.zeros((0, 3), np.uint8)).shape == (0, 3)


def test_brightening_keeps_the_shape_and_a_quantile_outside_0_100_is_refused():
    rng = np.random.default_rng(2)
    for shape in ((50,), (20, 30), (20, 30, 1), (20, 30, 3)):
        image = rng.integers(0, 40, shape).astype(np.uint8)
        assert brighten(image).shape == shape
    with pytest.raises(ValueError, match="not in"):
        percentile_8bit(np.zeros(4, np.uint8), 100.5)
