"""A camera's response (``stages.common.tone``), converted a band of rows at a time: the same
codes as the definition applied to the whole frame, whatever the frame's height."""

import numpy as np
import pytest

from stages.common.tone import Response, encode8, luminance


def whole_frame(radiance: np.ndarray, response: Response, exposure: float) -> np.ndarray:
    """The response's arithmetic on the whole frame at once."""
    scaled = radiance.astype(np.float64) * exposure
    return encode8(luminance(scaled) if response.sensor == "mono" else scaled, response.gamma)


@pytest.mark.parametrize("sensor, gamma", [("mono", 1.0), ("mono", 2.2), ("colour", 1.0), ("colour", 2.2)])
@pytest.mark.parametrize("height", [1, 31, 32, 97])
def test_banded_codes_equal_the_whole_frames(sensor, gamma, height):
    rng = np.random.default_rng(height)
    radiance = rng.uniform(-0.1, 1.3, (height, 45, 3)).astype(np.float32)
    response = Response(sensor, gamma)
    image = response.image(radiance, 0.8)
    expected = whole_frame(radiance, response, 0.8)
    assert image.shape == expected.shape and image.dtype == np.uint8
    assert np.array_equal(image, expected)
