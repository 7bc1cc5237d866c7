"""A model's input from an image, as its contract says: the crop (the whole image, or a
square of ``CROP_MARGIN`` times the label's box), resized, and normalised; with the affine
map from input pixels back to image pixels."""

from __future__ import annotations

import cv2
import numpy as np

from speedplus.errors import InputError
from stages.common.model_contract import CROP_MARGIN, ModelContract


def crop_window(contract: ModelContract, width: int, height: int, box: np.ndarray | None) -> tuple[int, ...]:
    """The image window (x0, y0, w, h) in pixels that becomes the network input: the whole
    image, or a square of 1.25 times the box's larger side centred on the box."""
    if contract.crop == "full":
        return 0, 0, width, height
    if box is None or not np.all(np.isfinite(box)):
        raise InputError("speedplus.crop=oracle_box needs the label's box")
    centre = (np.asarray(box[:2], float) + np.asarray(box[2:], float)) / 2
    side = int(np.ceil(CROP_MARGIN * max(box[2] - box[0], box[3] - box[1], 8.0)))
    x0, y0 = (int(round(c - (side - 1) / 2)) for c in centre)
    return x0, y0, side, side


def prepare(image_bgr: np.ndarray, contract: ModelContract, box: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The input image (H, W, C) uint8 (RGB or gray) and the (3, 3) affine map from input
    pixels to image pixels (pixel centres at integer coordinates in both)."""
    height, width = image_bgr.shape[:2]
    x0, y0, w, h = crop_window(contract, width, height, box)
    window = _window(image_bgr, x0, y0, w, h)
    shrinking = w > contract.width or h > contract.height
    resized = cv2.resize(window, (contract.width, contract.height),
                         interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    pixels = resized[..., ::-1] if contract.channels == "rgb" else cv2.cvtColor(resized, cv2.COLOR_BGR2GRAY)[..., None]
    scale_x, scale_y = w / contract.width, h / contract.height
    image_from_input = np.array([[scale_x, 0, x0 + 0.5 * scale_x - 0.5], [0, scale_y, y0 + 0.5 * scale_y - 0.5],
                                 [0, 0, 1.0]])
    return np.ascontiguousarray(pixels), image_from_input


def _window(image: np.ndarray, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """The pixels (h, w, ...) of an image's window at (x0, y0), black outside the image: a
    view where the window is inside (an integer shift needs no resampling), else padded."""
    height, width = image.shape[:2]
    left, top, right, bottom = max(x0, 0), max(y0, 0), min(x0 + w, width), min(y0 + h, height)
    if right <= left or bottom <= top:
        return np.zeros((h, w, *image.shape[2:]), image.dtype)
    inside = image[top:bottom, left:right]
    if (left, top, right, bottom) == (x0, y0, x0 + w, y0 + h):
        return inside
    return cv2.copyMakeBorder(inside, top - y0, y0 + h - bottom, left - x0, x0 + w - right, cv2.BORDER_CONSTANT,
                              value=0)


def points_box(points_px: np.ndarray) -> np.ndarray:
    """x_min, y_min, x_max, y_max [px] of points (K, 2): the labels' box definition."""
    points_px = np.asarray(points_px, float)
    return np.concatenate([points_px.min(axis=0), points_px.max(axis=0)])


def apply_affine(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (..., 2) through a (3, 3) affine map (e.g. ``prepare``'s image_from_input)."""
    return np.asarray(points, float) @ affine[:2, :2].T + affine[:2, 2]


def normalise(pixels: np.ndarray, contract: ModelContract) -> np.ndarray:
    """(..., H, W, C) values in [0, 1] -> (..., C, H, W) float32 normalised as the contract says."""
    out = (pixels - np.asarray(contract.mean, np.float32)) / np.asarray(contract.std, np.float32)
    return np.ascontiguousarray(np.moveaxis(out.astype(np.float32), -1, -3))


def normalise_uint8(pixels: np.ndarray, contract: ModelContract) -> np.ndarray:
    """``normalise`` of (..., H, W, C) uint8 pixels scaled to [0, 1], by a table of the 256
    values of each channel: the same float32 values, without converting every pixel."""
    table = normalise((np.arange(256, dtype=np.float32) / 255.0)[None, :, None], contract)[:, 0]  # (C, 256)
    channels = pixels.shape[-1]
    rows = pixels.reshape(-1, pixels.shape[-2], channels) if channels > 1 else pixels.reshape(-1, pixels.shape[-2])
    looked_up = cv2.LUT(np.ascontiguousarray(rows), np.ascontiguousarray(table.T[None]))
    return np.ascontiguousarray(np.moveaxis(looked_up.reshape(pixels.shape), -1, -3))
