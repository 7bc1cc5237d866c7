"""The EXR writer (stages/common/exr.py): what OpenEXR's own readers read back, bit for bit."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from stages.common import exr


def _read(path) -> tuple[dict[str, np.ndarray], object]:
    import OpenImageIO as oiio  # noqa: N813

    image_input = oiio.ImageInput.open(str(path))
    assert image_input is not None, oiio.geterror()
    spec = image_input.spec()
    pixels = np.asarray(image_input.read_image(0, 0, 0, spec.nchannels, "float"), np.float32)
    assert not image_input.has_error
    image_input.close()
    pixels = pixels.reshape(spec.height, spec.width, spec.nchannels)
    return {name: pixels[..., i] for i, name in enumerate(spec.channelnames)}, spec


def _planes(rng: np.random.Generator, height: int, width: int, names: list[str],
            halves: frozenset[str] = frozenset()) -> dict[str, np.ndarray]:
    """Noise with uniform regions (zero, NaN, a constant), NaNs of two payloads, infinities and
    -0; float32, or float16 for the names in ``halves`` (subnormals among them)."""
    channels = {}
    for name in names:
        half = name in halves
        plane = rng.normal(size=(height, width)).astype(np.float16 if half else np.float32)
        top, left = rng.integers(0, height), rng.integers(0, width)
        plane[:top, :] = rng.choice([0.0, np.nan, 5.5])
        plane[:, :left] = rng.choice([0.0, np.nan, -2.0])
        bits = plane.view(np.uint16 if half else np.uint32)
        bits[rng.random((height, width)) < 0.01] = 0x7E01 if half else 0x7FC00001  # a NaN of another payload
        plane[rng.random((height, width)) < 0.01] = rng.choice([np.inf, -np.inf, -0.0, 3e-7 if half else 1e-40])
        channels[name] = plane
    return channels


def _float_bits(plane: np.ndarray) -> np.ndarray:
    """A plane's values as float32 bits: a half widened exactly (NaN payloads shifted), as
    OpenEXR's readers widen it."""
    return plane.astype(np.float32).view(np.uint32)


@pytest.mark.parametrize("seed", range(6))
def test_every_channel_reads_back_bit_for_bit(tmp_path, seed):
    rng = np.random.default_rng(seed)
    height, width = [(1, 1), (63, 65), (64, 64), (130, 200), (200, 129), (65, 1)][seed]
    names = ["part", "Z", "N.X", "B", "a_channel_name_of_more_than_31_bytes"][: 1 + seed % 5]
    halves = frozenset(name for index, name in enumerate(names) if (index + seed) % 2)
    channels = _planes(rng, height, width, names, halves)
    path = tmp_path / "planes.exr"
    path.write_bytes(exr.encode(channels, {"speedplus:note": "a header"}))
    read, spec = _read(path)
    assert (spec.width, spec.height, spec.tile_width) == (width, height, exr.TILE)
    assert spec.getattribute("compression") == "zip" and spec.getattribute("speedplus:note") == "a header"
    assert sorted(read) == sorted(names)
    formats = {name: str(spec.channelformat(index)) for index, name in enumerate(spec.channelnames)}
    assert formats == {name: "half" if name in halves else "float" for name in names}
    for name, plane in channels.items():
        assert np.array_equal(read[name].view(np.uint32), _float_bits(plane)), name


def test_opencv_reads_it_too(tmp_path):
    """A second reader: OpenCV's own build of OpenEXR (its EXR codec enabled before import)."""
    rng = np.random.default_rng(3)
    channels = _planes(rng, 150, 70, ["B", "G", "R"], frozenset({"G"}))
    path = tmp_path / "colour.exr"
    path.write_bytes(exr.encode(channels))
    script = ("import sys, cv2, numpy as np; image = cv2.imread(sys.argv[1], cv2.IMREAD_UNCHANGED); "
              "np.save(sys.argv[2], image)")
    done = subprocess.run([sys.executable, "-c", script, str(path), str(tmp_path / "read.npy")],
                          env={**os.environ, "OPENCV_IO_ENABLE_OPENEXR": "1"}, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    image = np.load(tmp_path / "read.npy")
    for axis, name in enumerate("BGR"):
        assert np.array_equal(image[..., axis], channels[name].astype(np.float32), equal_nan=True), name


@pytest.mark.parametrize("dtype", [np.float32, np.float16])
def test_uniform_tiles_are_told_from_others_exactly(dtype):
    """The vectorised test against one tile at a time, on tiles one pixel away from uniform."""
    rng = np.random.default_rng(60)
    height, width = 3 * exr.TILE + 17, 2 * exr.TILE + 5
    planes = [np.zeros((height, width), dtype), np.full((height, width), np.nan, dtype)]
    for _ in range(12):
        plane = planes[rng.integers(2)]
        plane[rng.integers(height), rng.integers(width)] = rng.choice([1.0, -0.0, np.nan, 0.0])
    bits = np.uint16 if dtype == np.float16 else np.uint32
    planes[1].view(bits)[5, 5] = 0x7E01 if dtype == np.float16 else 0x7FC00001  # NaN of another bit pattern
    rows, columns = -(-height // exr.TILE), -(-width // exr.TILE)
    expected = np.array([[all(len(np.unique(p[r * exr.TILE:(r + 1) * exr.TILE, c * exr.TILE:(c + 1) * exr.TILE]
                                             .view(bits))) == 1 for p in planes)
                          for c in range(columns)] for r in range(rows)])
    assert np.array_equal(exr._uniform_tiles([exr._Plane.of(p) for p in planes], rows, columns), expected)
    assert 0 < expected.sum() < expected.size


@pytest.mark.parametrize("seed", range(6))
def test_a_windowed_plane_is_written_as_the_whole_plane_it_stands_for(seed):
    """A plane given as its window and a fill (what a render or a ray cast made only where the
    target can be) gives the file of the whole plane, byte for byte: windows on and off the
    tile grid, at the image's edges, empty or the whole image, beside whole planes of noise
    (the Earth's radiance) or alone, of float32 or of half floats."""
    rng = np.random.default_rng(seed)
    height, width = int(rng.integers(1, 4 * exr.TILE)), int(rng.integers(1, 5 * exr.TILE))
    top, left = int(rng.integers(0, height)), int(rng.integers(0, width))
    h, w = int(rng.integers(0, height - top + 1)), int(rng.integers(0, width - left + 1))
    if seed == 0:
        top, left, h, w = 0, 0, height, width
    channels, whole = {}, {}
    for name, fill, dtype in (("Z", np.nan, np.float32), ("part", 0.0, np.float32), ("N.X", 1.0, np.float16)):
        plane = np.full((height, width), fill, dtype)
        values = rng.normal(size=(h, w)).astype(dtype)
        values[rng.random((h, w)) < 0.7] = fill  # much of a window is background too
        plane[top:top + h, left:left + w] = values
        channels[name], whole[name] = exr.Windowed(values, top, left, (height, width), fill), plane
    if seed % 2:
        whole["R"] = channels["R"] = rng.normal(size=(height, width)).astype([np.float32, np.float16][seed // 2 % 2])
    assert exr.encode(channels) == exr.encode(whole)


def test_a_window_outside_its_plane_is_refused():
    with pytest.raises(ValueError, match="outside"):
        exr.encode({"Z": exr.Windowed(np.zeros((4, 4), np.float32), 10, 0, (12, 12), 0.0)})


def test_same_planes_same_bytes_whatever_was_written_before():
    """The uniform tiles' kept data is keyed by their values and size: images of other values
    in between change nothing."""
    rng = np.random.default_rng(8)
    first = _planes(rng, 140, 150, ["Z", "part"])
    before = exr.encode(first)
    for fill in (0.0, 1.0, np.nan):
        exr.encode({"Z": np.full((140, 150), fill, np.float32), "part": np.full((140, 150), fill, np.float32)})
    assert exr.encode(first) == before


def test_incompressible_tiles_are_stored_as_they_are(tmp_path):
    noise = np.random.default_rng(9).integers(0, 2**32, (70, 70), dtype=np.uint32).view(np.float32)
    raw = np.ascontiguousarray(noise[:64, :64]).tobytes()
    assert exr.zip_data(raw) == raw
    path = tmp_path / "noise.exr"
    path.write_bytes(exr.encode({"Y": noise}))
    assert np.array_equal(_read(path)[0]["Y"].view(np.uint32), noise.view(np.uint32))


@pytest.mark.parametrize(("channels", "strings", "message"), [
    ({}, {}, "at least one channel"),
    ({"Z": np.zeros((4, 4)), "part": np.zeros((4, 5))}, {}, "one non-empty shape"),
    ({"Z": np.zeros((0, 4))}, {}, "one non-empty shape"),
    ({"Z": np.zeros((4, 4))}, {"tiles": "mine"}, "format's own"),
    ({"Z": np.zeros((4, 4))}, {"type": "scanlineimage"}, "format's own"),
    ({"Z": np.zeros((4, 4))}, {"": "x"}, "1-255 bytes"),
    ({"Z": np.zeros((4, 4))}, {"a\0b": "x"}, "1-255 bytes"),
    ({"": np.zeros((4, 4))}, {}, "channel names"),
])
def test_what_it_cannot_write_is_refused(channels, strings, message):
    with pytest.raises(ValueError, match=message):
        exr.encode(channels, strings)


def test_planes_that_are_views_of_a_wider_array_read_back_as_they_are(tmp_path):
    """A surface normal's axes are strided views of an (H, W, 3) array, written without a copy."""
    normals = np.random.default_rng(4).normal(size=(90, 140, 3)).astype(np.float32)
    channels = {f"N.{axis}": normals[..., i] for i, axis in enumerate("XYZ")}
    path = tmp_path / "normals.exr"
    path.write_bytes(exr.encode(channels))
    read = _read(path)[0]
    assert all(np.array_equal(read[f"N.{axis}"], normals[..., i]) for i, axis in enumerate("XYZ"))


def test_uniform_tiles_of_other_values_each_channel_read_back_as_they_are(tmp_path):
    """Large regions of one value per channel, other in each (0, 1.5, NaN of two payloads,
    -0): the tiles compressed once and kept, written twice (the second from what was kept)."""
    height, width = 3 * exr.TILE + 10, 2 * exr.TILE + 30
    channels = {"A": np.zeros((height, width), np.float32), "B": np.full((height, width), 1.5, np.float32),
                "C": np.full((height, width), np.nan, np.float32), "D": np.full((height, width), -0.0, np.float32)}
    channels["C"].view(np.uint32)[:exr.TILE, :] = 0x7FC00001
    channels["B"][exr.TILE:2 * exr.TILE, exr.TILE:] = 2.5
    channels["A"][5, 7] = 3.0  # one tile that is not uniform
    for index in range(2):
        path = tmp_path / f"uniform{index}.exr"
        path.write_bytes(exr.encode(channels))
        read = _read(path)[0]
        for name, plane in channels.items():
            assert np.array_equal(read[name].view(np.uint32), plane.view(np.uint32)), (index, name)
