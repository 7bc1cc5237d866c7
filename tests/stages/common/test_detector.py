"""The detector's contract: boxes decoded from its maps, mapped to the image, and the
metadata it is refused without."""

import numpy as np
import pytest

from speedplus.errors import InputError
from stages.common.detector import DetectorContract, decode_boxes, parse_detector_contract, to_image, whole_image
from stages.reference.detect import STRIDE, box_iou, mask_targets, zoom


def test_a_mask_decodes_to_its_box_within_a_fifth_of_a_mask_pixel():
    """Seeded: a target's mask at the input's resolution, averaged over the heatmap's
    pixels as the training targets are, decodes to the box of the mask's pixels (their
    centres) within a fifth of a heatmap pixel, wherever its edges fall in a pixel; a
    smaller, fainter blob elsewhere does not move it."""
    rng = np.random.default_rng(3)
    height, width = 128, 192
    for _ in range(50):
        x0, y0 = rng.integers(2, 100), rng.integers(2, 60)
        x1, y1 = x0 + rng.integers(12, 80), y0 + rng.integers(10, 60)
        mask = np.zeros((1, height, width), np.uint8)
        mask[0, y0:y1 + 1, x0:x1 + 1] = 255
        heat = mask_targets(mask)
        heat[0, 0, 60:62, 2:4] = np.maximum(heat[0, 0, 60:62, 2:4], 0.7)  # a false blob, smaller
        boxes, confidence = decode_boxes(heat, width, height)
        assert confidence[0] == pytest.approx(1.0)
        assert np.abs(boxes[0] - [x0, y0, x1, y1]).max() <= 0.2 * STRIDE + 1e-9, (boxes[0], (x0, y0, x1, y1))
        assert box_iou(boxes, np.array([[x0, y0, x1, y1]], float))[0] > 0.9


def test_an_empty_mask_gives_the_whole_input_at_no_confidence():
    boxes, confidence = decode_boxes(np.zeros((1, 1, 64, 96)), 192, 128)
    np.testing.assert_allclose(boxes[0], [0.0, 0.0, 191.0, 127.0])
    assert confidence[0] == 0.0


def test_boxes_map_to_the_image_with_pixel_centres_aligned():
    contract = DetectorContract(256, 160, "gray", (0.449,), (0.226,))
    whole = np.array([[-0.5, -0.5, 255.5, 159.5]])  # the input's whole extent
    np.testing.assert_allclose(to_image(whole, contract, 960, 600), [[-0.5, -0.5, 959.5, 599.5]])


def test_a_white_square_is_where_the_whole_image_puts_it():
    contract = DetectorContract(256, 160, "gray", (0.449,), (0.226,))
    image = np.zeros((600, 960, 3), np.uint8)
    image[150:300, 375:600] = 255
    pixels = whole_image(image, contract)
    assert pixels.shape == (160, 256, 1)
    rows, cols = np.nonzero(pixels[..., 0] > 127)
    box = to_image(np.array([[cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5]]), contract,
                   960, 600)[0]
    np.testing.assert_allclose(box, [374.5, 149.5, 599.5, 299.5], atol=2.0)


def test_zoom_moves_each_box_with_its_mask():
    rng = np.random.default_rng(5)
    masks = np.zeros((6, 160, 256), np.uint8)
    boxes = np.empty((6, 4))
    for index in range(6):
        x0, y0 = rng.integers(40, 150), rng.integers(30, 90)
        masks[index, y0:y0 + 40, x0:x0 + 60] = 255
        boxes[index] = (x0 - 0.5, y0 - 0.5, x0 + 59.5, y0 + 39.5)
    images = np.repeat(masks[..., None], 1, axis=-1)
    _, zoomed, moved = zoom(images, masks, boxes, rng)
    for mask, box in zip(zoomed, moved, strict=True):
        rows, cols = np.nonzero(mask > 127)
        if len(rows) == 0:
            continue
        seen = np.array([cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5])
        clipped = np.clip(box, [-0.5, -0.5, -0.5, -0.5], [255.5, 159.5, 255.5, 159.5])
        assert np.abs(seen - clipped).max() <= 1.5


def test_metadata_without_the_contract_is_refused_naming_the_file_and_key():
    good = DetectorContract(256, 160, "gray", (0.449,), (0.226,)).metadata()
    assert parse_detector_contract(good, "d.onnx") == DetectorContract(256, 160, "gray", (0.449,), (0.226,))
    for key in good:
        with pytest.raises(InputError, match=f"d.onnx: .*{key}"):
            parse_detector_contract({k: v for k, v in good.items() if k != key}, "d.onnx")
    with pytest.raises(InputError, match="speedplus.channels=rgb"):
        parse_detector_contract({**good, "speedplus.channels": "rgb"}, "d.onnx")


def test_the_box_scale_is_the_held_out_median_ratio_and_is_bounded():
    from stages.reference.detect import box_scale, scaled

    rng = np.random.default_rng(2)
    truth = np.concatenate([rng.uniform(0, 50, (40, 2)), rng.uniform(100, 150, (40, 2))], axis=1)
    found = scaled(truth, 1 / 1.25)  # the detector sees 80% of each side
    assert box_scale(found, truth) == pytest.approx(1.25)
    np.testing.assert_allclose(scaled(found, 1.25), truth)
    good = DetectorContract(256, 160, "gray", (0.449,), (0.226,), box_scale=1.25).metadata()
    assert parse_detector_contract(good, "d.onnx").box_scale == 1.25
    with pytest.raises(InputError, match="d.onnx: speedplus.box_scale=5.0"):
        parse_detector_contract({**good, "speedplus.box_scale": "5.0"}, "d.onnx")
