"""A camera's response (``stages.common.tone``), converted a band of rows at a time: the same
codes as the definition applied to the whole frame, whatever the frame's height."""

import numpy as np
import pytest

from stages.common.tone import LUMINANCE, Response


def definition(radiance: np.ndarray, response: Response, exposure: float) -> np.ndarray:
    """Clip, gamma and round of the luminance (mono) or the channels (colour), whole frame."""
    scaled = radiance.astype(np.float64) * exposure
    linear = scaled @ np.array(LUMINANCE) if response.sensor == "mono" else scaled
    return np.round(np.clip(linear, 0.0, 1.0) ** (1.0 / response.gamma) * 255.0).astype(np.uint8)


@pytest.mark.parametrize("sensor, gamma", [("mono", 1.0), ("mono", 2.2), ("colour", 1.0), ("colour", 2.2)])
@pytest.mark.parametrize("height", [1, 31, 32, 97])
def test_banded_codes_equal_the_whole_frames(sensor, gamma, height):
    rng = np.random.default_rng(height)
    radiance = rng.uniform(-0.1, 1.3, (height, 45, 3)).astype(np.float32)
    response = Response(sensor, gamma)
    image = response.image(radiance, 0.8)
    expected = definition(radiance, response, 0.8)
    assert image.shape == expected.shape and image.dtype == np.uint8
    # the dot product may round the luminance differently in its last bit: one code at most,
    # and only where the value sits on a rounding boundary
    assert np.abs(image.astype(int) - expected).max() <= 1
    assert (image != expected).mean() < 0.01
