"""A writer of OpenEXR files of float32 and half (float16) channels: single-part, tiled
(``TILE`` x ``TILE`` pixels, one level), ZIP-compressed; what any OpenEXR reader reads whole
(OpenImageIO's ``read_image`` among them; docs/formats.md). Reading stays with OpenImageIO.

Why our own writer (issue 60; docs/architecture.md section 7): a twin's eleven planes of
ground truth are 101 MB at 1920 x 1200 and, outside the few tiles the target covers, one
value per channel (zero radiance and part, NaN geometry). OpenImageIO compressed every
byte of them (0.28 s a twin, and 0.05 s to interleave them for it); here a tile whose every
channel holds one value is compressed once per value and size and its bytes reused, and
the others go through libdeflate (``deflate``: zlib's format at twice zlib's speed, and the
same bytes for the same pixels in every process: ISA-L's deflate, used before, twice as fast
again, once gave a twin's tile other bytes in a Ray worker than in a local run, its pixels
the same), so that a twin's file costs 0.07 s and one over the Earth, whose radiance is
noise in every tile, 0.37 s (0.15 s with its radiance in half floats: half the bytes, and
no noise in the mantissa bits a half does not keep). A plane may come as its window and a
fill (``Windowed``: a ray cast or a render made only where the target can be), whose tiles
outside the window are never made or scanned: the file is the whole plane's. The pixels
read back bit for bit, NaN payloads included (``tests/stages/common/test_exr.py``).

The layout, from OpenEXR's "OpenEXR File Layout" (openexr.com, version 2 of the format),
all little-endian:

- magic ``20000630`` (int32), then version 2 with the ``tiled`` flag (``0x200``; ``0x400``
  where a name is longer than 31 bytes);
- the header: attributes ``name\\0 type\\0 size(int32) value``, sorted by name, ended by
  ``\\0``: ``channels`` (chlist: per channel, sorted by name, ``name\\0``, pixel type 1 =
  HALF or 2 = FLOAT (a plane of float16 is HALF, any other FLOAT), pLinear 0, three reserved
  bytes, x and y sampling 1; then ``\\0``), ``compression``
  (3 = ZIP), ``dataWindow`` and ``displayWindow`` (box2i: 0, 0, width - 1, height - 1),
  ``lineOrder`` (0 = increasing y), ``pixelAspectRatio`` 1, ``screenWindowCenter`` (0, 0),
  ``screenWindowWidth`` 1, ``tiles`` (tiledesc: x size, y size, mode 0 = one level, round
  down), and the caller's string attributes;
- the offset table: one uint64 file offset per tile, rows of tiles top to bottom, each
  left to right;
- the tiles in that order: tile x, tile y, level x 0, level y 0, data size (int32 each),
  data. A tile's pixels are, row by row, each channel's run of that row (channels sorted
  by name); a tile at the right or bottom edge holds only the pixels inside the image.
  ZIP: the bytes split into the even-indexed then the odd-indexed, each byte replaced by
  its difference from the one before plus 128 (mod 256), then deflated in zlib's format;
  a tile whose compressed bytes would be no fewer than its pixels' is stored as they are.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass

import deflate
import numpy as np

from stages.common.kept import Kept

MAGIC = 20000630
FORMAT_VERSION = 2
TILED_FLAG = 0x200
LONG_NAMES_FLAG = 0x400
HALF = 1
FLOAT = 2
#: OpenEXR's pixel type of each plane dtype the writer keeps
PIXEL_TYPES = {np.dtype("<f2"): HALF, np.dtype("<f4"): FLOAT}
ZIP_COMPRESSION = 3
#: tile side, px: 570 tiles at 1920 x 1200, of which a twin's target covers a few dozen
TILE = 64
#: libdeflate's fastest level of 1-12: its files a little smaller than ISA-L's level 2 made
LEVEL = 1
#: attribute names of the format's other kinds of file (multi-part, deep): a reader takes them at their word
RESERVED = frozenset({"name", "type", "version", "chunkCount", "maxSamplesPerPixel"})

#: compressed data of uniform tiles by (width, height, the channels' values as bytes)
_UNIFORM: Kept[bytes] = Kept(64)


def _attribute(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _header(names: list[str], types: list[int], width: int, height: int, strings: dict[str, str]) -> bytes:
    channels = b"".join(name.encode() + b"\0" + struct.pack("<iB3xii", kind, 0, 1, 1)
                        for name, kind in zip(names, types, strict=True)) + b"\0"
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    attributes = {
        "channels": ("chlist", channels),
        "compression": ("compression", struct.pack("<B", ZIP_COMPRESSION)),
        "dataWindow": ("box2i", window),
        "displayWindow": ("box2i", window),
        "lineOrder": ("lineOrder", struct.pack("<B", 0)),
        "pixelAspectRatio": ("float", struct.pack("<f", 1.0)),
        "screenWindowCenter": ("v2f", struct.pack("<2f", 0.0, 0.0)),
        "screenWindowWidth": ("float", struct.pack("<f", 1.0)),
        "tiles": ("tiledesc", struct.pack("<IIB", TILE, TILE, 0)),
    }
    for key, text in strings.items():
        if key in attributes or key in RESERVED:
            raise ValueError(f"EXR attribute {key!r} is the format's own")
        if not 0 < len(key.encode()) <= 255 or "\0" in key:
            raise ValueError(f"EXR attribute name {key!r}: 1-255 bytes without NUL")
        attributes[key] = ("string", text.encode())
    long_names = max(len(name.encode()) for name in [*attributes, *names]) > 31
    flags = FORMAT_VERSION | TILED_FLAG | (LONG_NAMES_FLAG if long_names else 0)
    return (struct.pack("<ii", MAGIC, flags)
            + b"".join(_attribute(key, *attributes[key]) for key in sorted(attributes)) + b"\0")


def zip_data(raw: bytes | np.ndarray) -> bytes:
    """A chunk's pixel bytes (or a contiguous array of them, read as its bytes) as OpenEXR's
    ZIP stores them (module docstring)."""
    data = np.frombuffer(raw, np.uint8) if isinstance(raw, bytes) else raw.reshape(-1).view(np.uint8)
    half = (len(data) + 1) // 2
    split = np.empty_like(data)
    if len(data) % 2 == 0:  # the byte pairs read as little-endian uint16: their low and high bytes
        pairs = data.view("<u2")
        np.copyto(split[:half], pairs, casting="unsafe")  # the low byte (a truncation, not a clip)
        np.right_shift(pairs, 8, out=split[half:], casting="unsafe")
    else:
        split[:half], split[half:] = data[0::2], data[1::2]
    predicted = np.empty_like(split)
    predicted[:1] = split[:1]
    np.subtract(split[1:], split[:-1], out=predicted[1:])
    predicted[1:] += np.uint8(128)
    packed = deflate.zlib_compress(memoryview(predicted).cast("B"), LEVEL)
    return packed if len(packed) < len(data) else data.tobytes()


@dataclass(frozen=True)
class Windowed:
    """A plane of ``shape`` (H, W) that holds ``values`` (h, w) from row ``top``, column
    ``left`` on and ``fill`` everywhere else: what a render or a ray cast that works only
    where the target can be (``stages.common.windows``) gives, written without a frame of
    fill ever being made or scanned (the same file as the whole plane's)."""

    values: np.ndarray
    top: int
    left: int
    shape: tuple[int, int]
    fill: float


@dataclass(frozen=True)
class _Plane:
    """A plane as the writer reads it: ``region`` (float32 or float16) from tile row ``row``
    and tile column ``column`` on, covering whole tiles (or up to the image's edge), and
    ``fill`` (a 0-d array of the region's little-endian dtype, so that its bytes are the
    file's on any host) in every tile outside it; a whole plane is its own region."""

    region: np.ndarray
    row: int
    column: int
    fill: np.ndarray

    @classmethod
    def of(cls, plane: np.ndarray | Windowed) -> _Plane:
        values = plane.values if isinstance(plane, Windowed) else plane
        dtype = "<f2" if np.asarray(values).dtype == np.float16 else "<f4"
        if not isinstance(plane, Windowed):
            # views kept as they are (a normal's axis of an (H, W, 3) array): a copy is 9 MB of page faults
            return cls(np.asarray(plane, dtype=dtype), 0, 0, np.zeros((), dtype))
        values, (height, width) = np.asarray(values, dtype=dtype), plane.shape
        (h, w), top, left = values.shape, plane.top, plane.left
        if min(top, left) < 0 or top + h > height or left + w > width:
            raise ValueError(f"a window of {h} x {w} at ({top}, {left}) outside the {height} x {width} plane")
        fill = np.asarray(plane.fill, dtype)
        if h == 0 or w == 0:
            return cls(np.empty((0, 0), dtype), 0, 0, fill)
        row, column = top // TILE, left // TILE
        bottom, right = min(-(-(top + h) // TILE) * TILE, height), min(-(-(left + w) // TILE) * TILE, width)
        region = np.full((bottom - row * TILE, right - column * TILE), fill, dtype)
        y, x = top - row * TILE, left - column * TILE
        region[y:y + h, x:x + w] = values
        return cls(region, row, column, fill)

    def tiles(self) -> tuple[slice, slice]:
        """The tile rows and columns the region covers."""
        return (slice(self.row, self.row - (-self.region.shape[0] // TILE)),
                slice(self.column, self.column - (-self.region.shape[1] // TILE)))

    def tile(self, row: int, column: int, height: int, width: int) -> np.ndarray:
        """Tile (``row``, ``column``) of ``height`` x ``width`` pixels."""
        rows, columns = self.tiles()
        if rows.start <= row < rows.stop and columns.start <= column < columns.stop:
            y, x = (row - self.row) * TILE, (column - self.column) * TILE
            return self.region[y:y + height, x:x + width]
        return _fill_tile(self.fill.tobytes(), self.fill.dtype.str)[:height, :width]


@functools.lru_cache(maxsize=8)
def _fill_tile(value: bytes, dtype: str) -> np.ndarray:
    """A read-only tile (TILE, TILE) of one value (its bytes, of ``dtype``): the tiles outside a
    windowed plane's region, sliced from one array (an Earth image stacks 4,000 of them)."""
    tile = np.full((TILE, TILE), np.frombuffer(value, dtype)[0], dtype)
    tile.flags.writeable = False
    return tile


def _bytes(tile: np.ndarray) -> np.ndarray:
    """(h, w * itemsize) uint8: a tile's rows as bytes (a strided view, such as one axis of
    an (H, W, 3) array, copied first)."""
    return (tile if tile.strides[-1] == tile.itemsize else np.ascontiguousarray(tile)).view(np.uint8)


def _shape(plane: np.ndarray | Windowed) -> tuple[int, int]:
    return tuple(plane.shape) if isinstance(plane, Windowed) else np.shape(plane)


def _uniform_of(plane: np.ndarray) -> np.ndarray:
    """(rows, columns) bool: the tiles of ``plane`` (H, W) that hold one value (bit for bit:
    NaNs of one payload are one value); edge tiles judged on the pixels they hold."""
    height, width = plane.shape
    rows, columns = -(-height // TILE), -(-width // TILE)
    uniform = np.ones((rows, columns), bool)
    whole_rows, whole_columns = height // TILE, width // TILE
    bits = plane.view(np.uint16 if plane.itemsize == 2 else np.uint32)
    if whole_rows and whole_columns:
        inner = bits[:whole_rows * TILE, :whole_columns * TILE]
        # each pixel against its tile's first, reduced along rows, then along each tile's
        # columns: reductions over adjacent axes, a third faster than over both at once
        first = np.repeat(inner[::TILE, ::TILE], TILE, axis=1)
        same = np.logical_and.reduce(inner.reshape(whole_rows, TILE, -1) == first[:, None, :], axis=1)
        uniform[:whole_rows, :whole_columns] = np.logical_and.reduce(
            same.reshape(whole_rows, whole_columns, TILE), axis=2)
    for row in range(rows):  # the partial tiles of the right and bottom edges
        for column in range(whole_columns if row < whole_rows else 0, columns):
            block = bits[row * TILE:(row + 1) * TILE, column * TILE:(column + 1) * TILE]
            uniform[row, column] = bool((block == block.flat[0]).all())
    return uniform


def _uniform_tiles(planes: list[_Plane], rows: int, columns: int) -> np.ndarray:
    """(rows, columns) bool: tiles in which every plane holds one value; a plane's tiles
    outside its region hold its fill."""
    uniform = np.ones((rows, columns), bool)
    for plane in planes:
        if not uniform.any():
            break
        if plane.region.size:
            uniform[plane.tiles()] &= _uniform_of(plane.region)
    return uniform


def _uniform_data(values: bytes, width: int, height: int, sizes: tuple[int, ...]) -> bytes:
    """A uniform tile's data: ``values`` the channels' one value each, ``sizes`` their bytes."""
    def compute() -> bytes:
        starts = np.cumsum((0, *sizes[:-1]))
        row = b"".join(values[start:start + size] * width for start, size in zip(starts, sizes, strict=True))
        return zip_data(row * height)

    return _UNIFORM.get((width, height, values, sizes), compute)


def encode(channels: dict[str, np.ndarray | Windowed], strings: dict[str, str] | None = None) -> bytes:
    """The file of ``channels`` {name: (H, W) float32-able, or ``Windowed``}, every plane of
    one shape, with ``strings`` {attribute name: text} in its header; a plane of float16
    values is written as HALF, any other as FLOAT."""
    names = sorted(channels)
    if not names:
        raise ValueError("an EXR needs at least one channel")
    if any(not 0 < len(name.encode()) <= 255 or "\0" in name for name in names):
        raise ValueError(f"EXR channel names of 1-255 bytes without NUL expected, got {names}")
    shapes = [_shape(channels[name]) for name in names]
    height, width = shapes[0]
    if any(shape != (height, width) for shape in shapes) or width < 1 or height < 1:
        raise ValueError(f"EXR channels of one non-empty shape expected, got {shapes}")
    planes = [_Plane.of(channels[name]) for name in names]
    header = _header(names, [PIXEL_TYPES[plane.region.dtype] for plane in planes], width, height,
                     dict(strings or {}))
    rows, columns = -(-height // TILE), -(-width // TILE)
    uniform = _uniform_tiles(planes, rows, columns)
    sizes = tuple(plane.region.itemsize for plane in planes)
    corners = np.empty((rows, columns, sum(sizes)), np.uint8)  # each tile's first pixel, its bytes
    for plane, start in zip(planes, np.cumsum((0, *sizes[:-1])), strict=True):
        span = corners[..., start:start + plane.region.itemsize]
        span[...] = np.frombuffer(plane.fill.tobytes(), np.uint8)
        span[plane.tiles()] = plane.region[::TILE, ::TILE, None].view(np.uint8)
    chunks = []
    for row in range(rows):
        tile_height = min(TILE, height - row * TILE)
        for column in range(columns):
            tile_width = min(TILE, width - column * TILE)
            if uniform[row, column]:
                data = _uniform_data(corners[row, column].tobytes(), tile_width, tile_height, sizes)
            else:  # each row of the tile: every channel's run, as bytes
                data = zip_data(np.concatenate(
                    [_bytes(plane.tile(row, column, tile_height, tile_width)) for plane in planes], axis=1))
            chunks.append((struct.pack("<5i", column, row, 0, 0, len(data)), data))
    # each chunk: 20 bytes of coordinates and size, then its data; the file joined once
    sizes = [20 + len(data) for _, data in chunks]
    offsets = np.cumsum([0, *sizes[:-1]], dtype=np.uint64) + np.uint64(len(header) + 8 * len(chunks))
    return b"".join([header, offsets.astype("<u8").tobytes(), *(part for chunk in chunks for part in chunk)])
