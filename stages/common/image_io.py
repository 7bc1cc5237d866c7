"""Every image file the pipeline reads goes through ``read_image`` (OpenImageIO: PNG 8/16-bit,
BMP, TIFF 8/16-bit/float, JPEG, EXR; grey or colour); the images stages write are PNGs,
written atomically (a crash never leaves half an image).

Pixel conventions: arrays are (H, W) grey or (H, W, 3) in OpenCV's BGR order, in the file's
own type (uint8, uint16 or float32); an alpha channel is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from manifests.files import write_bytes_atomic
from speedplus.errors import FileError

#: file types the readers accept (by suffix, case-insensitive)
IMAGE_SUFFIXES = (".png", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg", ".exr")


@dataclass(frozen=True)
class ImageInfo:
    """What a file holds: size (px), channels, pixel type (``uint8``, ``uint16``, ``float32``), format."""

    width: int
    height: int
    channels: int
    dtype: str
    format: str  # OpenImageIO's format name: png, bmp, tiff, jpeg, openexr

    def describe(self) -> str:
        return f"{self.format} {self.dtype} {self.channels}ch {self.width}x{self.height}"


def _open(path: Path):  # OpenImageIO.ImageInput
    import OpenImageIO as oiio  # noqa: N813 - the library's own documented alias

    if not path.is_file():
        raise FileError(path, "image file not found")
    image_input = oiio.ImageInput.open(str(path))
    if image_input is None:
        raise FileError(path, f"not a readable image ({_one_line(oiio.geterror()) or 'unknown format'})")
    return image_input


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _dtype(spec) -> str:  # spec: OpenImageIO.ImageSpec
    """uint8 and uint16 as they are; anything else (signed, 32-bit, half, float) as float32,
    which holds it exactly, so no integer conversion can clip or rescale it."""
    name = str(spec.format)
    return name if name in ("uint8", "uint16") else "float32"


def image_info(path: Path) -> ImageInfo:
    """Size, channels and pixel type of an image file, without decoding its pixels."""
    image_input = _open(path)
    try:
        spec = image_input.spec()
        return ImageInfo(spec.width, spec.height, spec.nchannels, _dtype(spec), image_input.format_name())
    finally:
        image_input.close()


def read_image(path: Path, mode: Literal["gray", "bgr", "unchanged"] = "unchanged") -> np.ndarray:
    """Decode a whole image (every pixel checked: a truncated file is an error naming it).

    ``gray``: (H, W); ``bgr``: (H, W, 3); ``unchanged``: (H, W) for grey files, else (H, W, 3).
    The pixel type is the file's (uint8, uint16, else float32), except that ``gray`` and
    ``bgr`` return 16-bit files holding 8-bit data (every value x * 257 or x * 256) as uint8,
    so that converting a camera's 8-bit images to 16 bits changes nothing downstream."""
    image_input = _open(path)
    try:
        spec = image_input.spec()
        dtype = _dtype(spec)
        pixels = image_input.read_image(0, 0, 0, min(spec.nchannels, 4), "float" if dtype == "float32" else dtype)
        if pixels is None or image_input.has_error:
            raise FileError(path, f"truncated or corrupt image ({_one_line(image_input.geterror())})")
    finally:
        image_input.close()
    pixels = np.asarray(pixels, dtype=dtype)
    if mode != "unchanged" and pixels.dtype == np.uint16 and significant_bits(pixels) == 8:
        pixels = to_uint8(pixels)  # 8-bit data stored in 16 bits: exactly the 8-bit file's pixels
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    channels = pixels.shape[2]
    if channels in (2, 4):  # drop alpha
        pixels = pixels[:, :, : channels - 1]
    if pixels.shape[2] == 3:
        pixels = np.ascontiguousarray(pixels[:, :, ::-1])  # OpenImageIO gives RGB
        if mode == "gray":
            return cv2.cvtColor(pixels, cv2.COLOR_BGR2GRAY)
        return pixels
    grey = np.ascontiguousarray(pixels[:, :, 0])
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR) if mode == "bgr" else grey


def significant_bits(image: np.ndarray) -> int:
    """How many bits per sample the data really uses: 8 for uint8 (and for 16-bit data that
    is 8-bit data times 257 or shifted left by 8), else the smallest power-of-two range
    that holds the maximum (12-bit cameras write 0-4095 into 16 bits); 32 for floats."""
    if image.dtype == np.uint8:
        return 8
    if image.dtype == np.uint16:
        if np.all(image % 257 == 0) or np.all(image % 256 == 0):
            return 8
        return max(8, int(np.ceil(np.log2(int(image.max()) + 1))))
    return 32


def to_uint8(image: np.ndarray) -> np.ndarray:
    """An 8-bit version for detectors and networks that need one (OpenCV's chessboard and
    ArUco detectors). 8-bit data stored in 16 bits gives exactly its 8-bit bytes back; data
    with more significant bits (a 12- or 16-bit camera, a renderer's floats) is stretched
    from its 0.1th to its 99.9th percentile, so that a dark exposure keeps its contrast:
    a 12-bit chessboard spanning 0-300 of 4095 is found in none of 12 real views when
    scaled by its bit depth (0-18 levels), in all 12 when stretched."""
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16 and significant_bits(image) == 8:
        return (image // 257 if np.all(image % 257 == 0) else image >> 8).astype(np.uint8)
    values = np.nan_to_num(image.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    low, high = np.percentile(values, [0.1, 99.9])
    if high <= low:
        high = low + 1.0
    return np.clip(np.rint((values - low) / (high - low) * 255.0), 0, 255).astype(np.uint8)


def encode_png(image: np.ndarray) -> bytes:
    """The PNG file of ``image`` (H, W) or (H, W, 3) BGR, uint8 or uint16."""
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"could not encode a {image.dtype} image of shape {image.shape} as PNG")
    return encoded.tobytes()


def write_png_atomic(path: Path, image: np.ndarray) -> None:
    """Write ``image`` (H, W) or (H, W, 3) BGR, uint8 or uint16, as a PNG at ``path``."""
    write_bytes_atomic(path, encode_png(image))


def decode_image(data: bytes, name: str, mode: Literal["gray", "bgr", "unchanged"] = "unchanged") -> np.ndarray:
    """``read_image`` of a file's bytes (sent to a worker that cannot see the file);
    ``name`` (its workspace path) gives the format by its suffix and names it in errors."""
    import tempfile

    suffix = Path(name).suffix.lower()
    with tempfile.TemporaryDirectory(prefix="speedplus-image-") as folder:
        path = Path(folder) / f"image{suffix}"
        path.write_bytes(data)
        try:
            return read_image(path, mode)
        except FileError as error:
            raise FileError(name, str(error).split(": ", 1)[-1]) from None


def ingest_image(source: Path, destination_png: Path) -> tuple[Path, str | None]:
    """Bring a recorded image into the workspace without loss. PNGs are copied byte for
    byte; other 8- and 16-bit unsigned formats (BMP, TIFF, JPEG's decoded pixels) are
    written as a PNG of the same type and colour channels (an alpha channel, which no
    stage reads, is dropped and said so); anything else (EXR, float or signed TIFF) is
    copied as it is, with its own suffix. Returns (the stored file, what was converted or None)."""
    from manifests.files import copy_atomic

    info = image_info(source)
    pixels = read_image(source)  # decodes every pixel: a truncated file fails here, naming it
    if info.format == "png":
        copy_atomic(source, destination_png)
        return destination_png, None
    if pixels.dtype not in (np.uint8, np.uint16):  # float data has no lossless PNG form
        stored = destination_png.with_suffix(source.suffix.lower())
        copy_atomic(source, stored)
        return stored, None
    write_png_atomic(destination_png, pixels)
    alpha = ", alpha channel dropped" if info.channels in (2, 4) else ""
    return destination_png, f"{info.describe()} -> png (lossless{alpha})"
