"""One image reader for every format a lab camera or a renderer writes (OpenImageIO)."""

from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio  # noqa: N813 - the library's documented alias
import pytest

from stages.common.image_io import (
    FileError,
    image_info,
    ingest_image,
    read_image,
    significant_bits,
    to_uint8,
)
from stages.common.patterns import PatternSpec, detect


def write(path: Path, rgb_or_grey: np.ndarray, dtype: str) -> Path:
    """Write with OpenImageIO (channels in RGB order, as files hold them)."""
    channels = 1 if rgb_or_grey.ndim == 2 else rgb_or_grey.shape[2]
    output = oiio.ImageOutput.create(str(path))
    assert output is not None, oiio.geterror()
    output.open(str(path), oiio.ImageSpec(rgb_or_grey.shape[1], rgb_or_grey.shape[0], channels, dtype))
    pixels = rgb_or_grey[:, :, None] if rgb_or_grey.ndim == 2 else rgb_or_grey
    assert output.write_image(np.ascontiguousarray(pixels)), output.geterror()
    output.close()
    return path


def sample_rgb(seed=0):
    return np.random.default_rng(seed).integers(0, 256, (24, 40, 3), dtype=np.uint8)


@pytest.mark.parametrize("suffix, dtype", [(".png", "uint8"), (".png", "uint16"), (".bmp", "uint8"),
                                           (".tif", "uint8"), (".tif", "uint16"), (".exr", "float"),
                                           (".exr", "half")])
@pytest.mark.parametrize("colour", [True, False])
def test_every_lossless_format_reads_back_exactly(tmp_path, suffix, dtype, colour):
    rgb = sample_rgb()
    data = rgb if colour else rgb[:, :, 1].copy()
    if dtype == "uint16":
        data = data.astype(np.uint16) * 251 + 3  # 16 significant bits, not 8-bit data scaled
    elif dtype in ("float", "half"):
        data = data.astype(np.float32) / 255.0 * 4.0  # HDR radiance beyond 1
        data = data.astype(np.float16).astype(np.float32) if dtype == "half" else data  # what half keeps
    path = write(tmp_path / f"image{suffix}", data, dtype)
    got = read_image(path)
    expected = data[:, :, ::-1] if colour else data
    assert got.dtype == expected.dtype and np.array_equal(got, expected)
    info = image_info(path)
    assert (info.width, info.height, info.channels) == (40, 24, 3 if colour else 1)


def test_jpeg_and_alpha_and_grey_conversion(tmp_path):
    rgb = sample_rgb()
    rgba = np.concatenate([rgb, np.full((24, 40, 1), 255, np.uint8)], axis=2)
    path = write(tmp_path / "alpha.png", rgba, "uint8")
    assert np.array_equal(read_image(path, "bgr"), rgb[:, :, ::-1])  # alpha dropped
    grey = read_image(path, "gray")
    assert np.abs(grey.astype(int) - cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)).max() == 0
    jpeg = write(tmp_path / "photo.jpg", rgb, "uint8")
    assert read_image(jpeg, "bgr").shape == (24, 40, 3)


def test_eight_bit_data_in_sixteen_bits_is_the_eight_bit_image(tmp_path):
    rgb = sample_rgb()
    for factor in (257, 256):
        path = write(tmp_path / f"x{factor}.tif", rgb.astype(np.uint16) * factor, "uint16")
        assert significant_bits(read_image(path)) == 8
        assert read_image(path, "gray").dtype == np.uint8
        assert np.array_equal(read_image(path, "bgr"), rgb[:, :, ::-1])
    twelve_bit = (rgb[:, :, 0].astype(np.uint16) * 16 + 5)
    assert significant_bits(twelve_bit) == 12
    stretched = to_uint8(twelve_bit)  # over its own range
    assert stretched.min() == 0 and stretched.max() == 255


def test_unreadable_files_are_errors_that_name_them(tmp_path):
    good = write(tmp_path / "good.png", sample_rgb(), "uint8")
    truncated = tmp_path / "truncated.png"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    text = tmp_path / "notes.png"
    text.write_text("not an image")
    for path, message in ((truncated, "truncated or corrupt"), (text, "not a readable image"),
                          (tmp_path / "missing.png", "image file not found")):
        with pytest.raises(FileError, match=f"{path.name}: {message}") as raised:
            read_image(path)
        assert "\n" not in str(raised.value)


def test_ingest_copies_png_and_converts_the_rest_without_loss(tmp_path):
    rgb = sample_rgb()
    png = write(tmp_path / "a.png", rgb, "uint8")
    stored, note = ingest_image(png, tmp_path / "w" / "a.png")
    assert note is None and stored.read_bytes() == png.read_bytes()
    tiff = write(tmp_path / "b.tif", rgb.astype(np.uint16) * 251, "uint16")
    stored, note = ingest_image(tiff, tmp_path / "w" / "b.png")
    assert stored.suffix == ".png" and "tiff uint16 3ch" in note and "lossless" in note
    assert np.array_equal(read_image(stored), read_image(tiff))
    rgba = np.concatenate([rgb, np.full((24, 40, 1), 200, np.uint8)], axis=2)
    stored, note = ingest_image(write(tmp_path / "d.tif", rgba, "uint8"), tmp_path / "w" / "d.png")
    assert "alpha channel dropped" in note and np.array_equal(read_image(stored), rgb[:, :, ::-1])
    signed = write(tmp_path / "e.tif", (rgb[:, :, 0].astype(np.int16) - 128), "int16")
    stored, note = ingest_image(signed, tmp_path / "w" / "e.png")  # no unsigned PNG holds it: kept
    assert stored.suffix == ".tif" and note is None and read_image(stored).min() < 0
    exr = write(tmp_path / "c.exr", rgb.astype(np.float32) / 7.0, "float")
    stored, note = ingest_image(exr, tmp_path / "w" / "c.png")
    assert stored.suffix == ".exr" and note is None and stored.read_bytes() == exr.read_bytes()


def chessboard_image(squares=(10, 7), px=24, margin=30, dtype=np.uint8):
    """A synthetic chessboard (H, W): ``squares`` squares of ``px`` pixels on a white margin;
    uint16: a dark exposure of a 12-bit camera (0-300 of 4095)."""
    width, height = squares[0] * px + 2 * margin, squares[1] * px + 2 * margin
    image = np.full((height, width), 1.0)
    for i in range(squares[0]):
        for j in range(squares[1]):
            if (i + j) % 2 == 0:
                image[margin + j * px:margin + (j + 1) * px, margin + i * px:margin + (i + 1) * px] = 0.1
    image = cv2.GaussianBlur(image, (0, 0), 1.0)
    if dtype == np.uint16:
        return np.rint(image * 300).astype(np.uint16)
    return np.rint(image * 255).astype(np.uint8)


def test_dark_twelve_bit_images_are_detected_over_their_own_range():
    spec = PatternSpec("chessboard", (9, 6), 0.02)
    truth = np.stack(np.meshgrid(np.arange(1, 10), np.arange(1, 7)), -1).reshape(-1, 2) * 24 + 30 - 0.5
    for dtype in (np.uint8, np.uint16):
        image = chessboard_image(dtype=dtype)
        assert significant_bits(image) == (8 if dtype == np.uint8 else 9)
        pixels, ids = detect(image, spec)
        assert len(ids) == 54
        error = np.linalg.norm(np.sort(pixels, axis=0) - np.sort(truth, axis=0), axis=1)
        assert error.max() < 0.1, dtype
