"""The ONNX model contract, crops, heatmap decoding and pose recovery."""

import numpy as np
import pytest

from pipeline.errors import InputError
from stages.common import geometry as g
from stages.common import tango
from stages.common.pose_model import (
    ModelContract,
    crop_window,
    decode_heatmaps,
    parse_contract,
    pose_from_keypoints,
    prepare,
)

CONTRACT = ModelContract(192, 192, "rgb", (0.5, 0.5, 0.5), (0.25, 0.25, 0.25), "heatmaps", tango.KEYPOINTS_M.copy(),
                         "oracle_box")
K = np.array([[1494.3, 0, 479.5], [0, 1494.2, 299.5], [0, 0, 1.0]])
DIST = np.array([-0.2238, 0.5141, -0.000665, -0.000214, -0.1312])


def test_contract_round_trips_through_metadata():
    parsed = parse_contract(CONTRACT.metadata(), "m.onnx")
    assert parsed.metadata() == CONTRACT.metadata()
    assert parsed.metadata()["speedplus.keypoints"] == "tango11"


@pytest.mark.parametrize(("key", "value", "message"), [
    ("speedplus.output", None, "'speedplus.output' missing"),
    ("speedplus.output", "boxes", "expected keypoints or heatmaps or pose"),
    ("speedplus.input_size", "192", "WIDTHxHEIGHT"),
    ("speedplus.channels", "bgr", "rgb or gray"),
    ("speedplus.normalize", "0.5,0.5/0.2,0.2,0.2", "3 means / 3 positive"),
    ("speedplus.keypoints", "[[0, 0, 1]]", "at least 4 points"),
    ("speedplus.crop", "detector", "full or oracle_box"),
    ("speedplus.contract", "2", "expected 1"),
])
def test_contract_errors_name_the_key(key, value, message):
    metadata = CONTRACT.metadata()
    if value is None:
        del metadata[key]
    else:
        metadata[key] = value
    with pytest.raises(InputError, match="m.onnx") as error:
        parse_contract(metadata, "m.onnx")
    assert message in str(error.value) and key in str(error.value)


def test_heatmap_peaks_decode_to_sub_pixel_positions():
    rng = np.random.default_rng(0)
    h, w = 48, 48
    truth = rng.uniform(3, 44, (2, 11, 2))
    ys, xs = np.mgrid[0:h, 0:w]
    heatmaps = np.exp(-((xs - truth[..., 0, None, None]) ** 2 + (ys - truth[..., 1, None, None]) ** 2) / 2.0)
    points, confidence = decode_heatmaps(heatmaps.astype(np.float32), 192, 192)
    # heatmap pixel centres spread evenly over the input: x_in = (x_hm + 0.5) * 4 - 0.5
    np.testing.assert_allclose(points, (truth + 0.5) * 4 - 0.5, atol=0.35)
    assert np.all(confidence > 0.75)  # the peak is within half a heatmap pixel of the nearest centre


def test_pose_from_keypoints_recovers_the_pose_despite_outliers():
    rng = np.random.default_rng(1)
    for q in g.random_quats(rng, 5):
        cam_from_target = g.transform_from_qt(q, [0.3, -0.2, 8.0])
        pixels = g.project(cam_from_target, tango.KEYPOINTS_M, K, DIST)
        pixels[[2, 7]] += rng.uniform(30, 60, (2, 2))  # two wild keypoints
        q_found, t_found = pose_from_keypoints(pixels, tango.KEYPOINTS_M, K, DIST, reprojection_px=3.0)
        assert g.quat_angular_distance(q_found, q) < 1e-6
        np.testing.assert_allclose(t_found, [0.3, -0.2, 8.0], atol=1e-5)


def test_no_pose_from_garbage():
    assert pose_from_keypoints(np.zeros((11, 2)), tango.KEYPOINTS_M, K, DIST, reprojection_px=3.0) is None


def test_prepare_maps_pixels_both_ways():
    image = np.zeros((600, 960, 3), np.uint8)
    box = np.array([400.0, 250.0, 520.0, 330.0])
    image[290, 460] = (0, 0, 255)  # one red pixel (BGR) at the box centre
    pixels, image_from_input = prepare(image, CONTRACT, box)
    assert pixels.shape == (192, 192, 3)
    x0, y0, w, h = crop_window(CONTRACT, 960, 600, box)
    assert w == h == 150 and abs((x0 + (w - 1) / 2) - 460) <= 0.5 and abs((y0 + (h - 1) / 2) - 290) <= 0.5
    # the brightest input pixel lies where the map sends the red pixel
    peak = np.unravel_index(pixels[..., 0].argmax(), pixels.shape[:2])
    at = np.linalg.inv(image_from_input) @ [460, 290, 1.0]
    assert abs(peak[1] - at[0]) <= 1 and abs(peak[0] - at[1]) <= 1
    full = ModelContract(240, 150, "gray", (0.5,), (0.25,), "keypoints", tango.KEYPOINTS_M.copy(), "full")
    pixels, image_from_input = prepare(image, full, None)
    assert pixels.shape == (150, 240, 1)
    np.testing.assert_allclose(image_from_input @ [-0.5, -0.5, 1], [-0.5, -0.5, 1])  # image corners agree
    np.testing.assert_allclose(image_from_input @ [239.5, 149.5, 1], [959.5, 599.5, 1])


def test_oracle_crop_needs_a_box():
    with pytest.raises(InputError, match="needs the label's box"):
        prepare(np.zeros((10, 10, 3), np.uint8), CONTRACT, None)
