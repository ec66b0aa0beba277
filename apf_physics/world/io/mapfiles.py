"""Grid maps users bring: ROS map_server maps, map images and MovingAI benchmarks, as plain numpy.

:func:`read_ros_map` reads a ROS ``map_server`` YAML and its image, :func:`read_image` an image
alone (PGM, PNG or BMP, thresholded as ``map_server`` does), :func:`read_movingai_map` a
MovingAI ``.map`` and :func:`read_movingai_scen` its ``.scen`` scenarios;
:func:`scenario_points` puts a scenario's start and goal in world coordinates.
(:func:`~apf_physics.common.geometry.occupancy_rectangles` cuts the occupied cells into few rectangles that tile them exactly.)

Every grid is ``(rows, cols)`` bool with row 0 the **bottom** row (world y up), so cell
``[r, c]`` covers ``[x0 + c·cell, x0 + (c+1)·cell] × [y0 + r·cell, y0 + (r+1)·cell]``.
Images and MovingAI maps list their top row first; the readers flip them. Unknown cells
count as occupied.

Files are read through :mod:`apf_physics.common.safefile` (regular files within a size limit), a
grid's size is checked from the file's header before its cells are decoded, and every
problem is a :class:`~apf_physics.errors.WorldError` that starts with the file and names the
key or line: ``<file>: <key>: <what is wrong>``.
"""

from __future__ import annotations

import array
import contextlib
import math
import numbers
import os
import re
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from apf_physics.errors import WorldError, closest_match, did_you_mean
from apf_physics.common.safefile import NamedFileError, named_file, read_regular_file
from apf_physics.common.safeyaml import described, read_yaml_file, shortened

MAX_MAP_CELLS = 16_000_000
"""Largest grid read [cells] (rows × cols; 4000 × 4000), checked from the header before decoding."""
MAX_MAP_FILE_BYTES = 256 * 2**20
"""Largest map image or MovingAI map file [bytes]."""
MAX_MAP_YAML_BYTES = 2**20
"""Largest ROS map YAML [bytes] (a real one is a few hundred)."""
MAX_PROBLEMS = 20
"""Problems listed from one file (as a world file's: the rest are counted)."""
MAX_SCEN_FILE_BYTES = 64 * 2**20
"""Largest MovingAI scenario file [bytes] (the largest benchmark files are a few MB)."""

IMAGE_SUFFIXES = (".pgm", ".png", ".bmp")
"""Suffixes of the images a map YAML names."""
MAX_ORIGIN = 1e9
"""Farthest a ROS map's origin may be from 0 [units] (a UTM easting or northing is within it)."""
ROS_MODES = ("trinary", "scale", "raw")
"""``mode`` values of a ROS map YAML. ``trinary`` and ``scale`` read the same here (unknown is occupied)."""
ROS_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode")
"""Keys a ROS map YAML may hold."""
RAW_OCCUPIED = 50
"""``mode: raw``: a grey value (after ``negate``) of at least this is occupied (0 free, 100 occupied, 255 unknown)."""
MOVINGAI_FREE = b".GS"
"""MovingAI terrain that is passable; every other character (``@ O T W`` …) is occupied."""


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """An occupancy grid read from a file.

    Attributes:
        occupied: ``(rows, cols)`` bool; row 0 is the bottom row of the map (world y up);
            unknown cells are True.
        cell: Side of a cell [world units per cell] (> 0).
        origin: World coordinates of the lower-left corner of cell ``[0, 0]``.
        source: The file it came from, for messages.
    """

    occupied: np.ndarray
    cell: float
    origin: tuple[float, float]
    source: str

    def __post_init__(self):
        occupied = np.asarray(self.occupied, dtype=bool)
        if occupied.ndim != 2:
            raise ValueError(f"occupied must be a 2-D array, got shape {occupied.shape}")
        if not (math.isfinite(self.cell) and self.cell > 0):
            raise ValueError(f"cell must be a positive finite number, got {self.cell!r}")
        object.__setattr__(self, "occupied", occupied)
        object.__setattr__(self, "cell", float(self.cell))
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))

    @property
    def size(self) -> tuple[float, float]:
        """``(width, height)`` of the map [world units]: ``(cols · cell, rows · cell)``."""
        rows, cols = self.occupied.shape
        return cols * self.cell, rows * self.cell


# -- messages ----------------------------------------------------------------------------

def _check_cells(source: str, rows: int, cols: int, what: str) -> None:
    """Refuse a grid that is empty or over :data:`MAX_MAP_CELLS` (read from the module at call time)."""
    if rows <= 0 or cols <= 0:
        raise WorldError(f"{source}: the {what} is empty ({cols} x {rows} cells)")
    if rows * cols > MAX_MAP_CELLS:
        raise WorldError(f"{source}: the {what} is {cols:,} x {rows:,} = {rows * cols:,} cells, "
                         f"over the limit of {MAX_MAP_CELLS:,}")


# -- images ------------------------------------------------------------------------------

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNM_TOKEN = re.compile(rb"(?:\s|#[^\r\n]*)*(\S+)")


def _pgm_header(data: bytes, source: str) -> tuple[int, int, int, int]:
    """``(width, height, maxval, offset of the first pixel)`` of a PGM (``P2`` or ``P5``)."""
    values, position = [], 2
    for name in ("width", "height", "maxval"):
        match = _PNM_TOKEN.match(data, position)
        token = match.group(1) if match else b""
        if not token:
            raise WorldError(f"{source}: not a valid PGM: its header has no {name}")
        if not _ascii_digits(token) or len(token) > 9:
            raise WorldError(f"{source}: not a valid PGM: its {name} is not a whole number of at most 9 digits")
        values.append(int(token))
        position = match.end()
    width, height, maxval = values
    if not 0 < maxval < 65536:
        raise WorldError(f"{source}: not a valid PGM: its maxval is {maxval}, expected 1 to 65535")
    return width, height, maxval, position + 1   # one whitespace character ends the header


def _ascii_digits(token: bytes) -> bool:
    """Whether ``token`` is one or more of the ASCII digits 0 to 9 (``bytes.isdigit`` is; ``str.isdigit``
    also takes ``²`` and ``①``, which ``int`` refuses)."""
    return bool(token) and token.isdigit() and token.isascii()


def _image_size(data: bytes, source: str) -> tuple[str, int, int]:
    """``(format, width, height)`` from the header: ``"P2"``, ``"P5"``, ``"PNG"`` or ``"BMP"``."""
    if data[:2] in (b"P2", b"P5") and data[2:3].isspace():
        width, height, _, _ = _pgm_header(data, source)
        return data[:2].decode(), width, height
    if data[:8] == _PNG_SIGNATURE and data[12:16] == b"IHDR" and len(data) >= 24:
        width, height = struct.unpack(">II", data[16:24])
        return "PNG", width, height
    if data[:2] == b"BM" and len(data) >= 26:
        (header,) = struct.unpack("<I", data[14:18])
        if header == 12:   # BITMAPCOREHEADER: 16-bit unsigned sizes
            width, height = struct.unpack("<HH", data[18:22])
        else:              # BITMAPINFOHEADER and later: 32-bit signed (a negative height is top-down)
            width, height = struct.unpack("<ii", data[18:26])
        return "BMP", abs(width), abs(height)
    raise WorldError(f"{source}: not an image (PGM, PNG or BMP) that can be read as a map: it does not start as "
                     "any of them does")


def _decode_pgm(data: bytes, source: str) -> tuple[np.ndarray, int]:
    """``(pixels (height, width) int, maxval)`` of a PGM: decoded here, since OpenCV scales
    ``P2`` pixels by ``maxval`` but not ``P5`` ones, and leaves 16-bit ones unscaled."""
    width, height, maxval, offset = _pgm_header(data, source)
    count = width * height
    if data[:2] == b"P5":
        dtype = np.dtype(">u2" if maxval > 255 else "u1")
        need = count * dtype.itemsize
        # A header ended by CR LF (a file written in text mode) leaves the LF before the pixels,
        # where the format has one whitespace character: when the pixels then fill the file
        # exactly, the LF is the header's.
        if data[offset - 1:offset + 1] == b"\r\n" and len(data) - offset == need + 1:
            offset += 1
        if len(data) - offset < need:
            raise WorldError(f"{source}: the PGM is cut short: {width} x {height} pixels need "
                             f"{need:,} bytes, it has {max(len(data) - offset, 0):,}")
        pixels = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
    else:
        pixels = _plain_pgm_values(data, offset - 1, count, source, f"{width} x {height} pixels")
    if pixels.max(initial=0) > maxval:
        raise WorldError(f"{source}: not a valid PGM: a pixel value is over its maxval {maxval}")
    return pixels.reshape(height, width), maxval


PLAIN_CHUNK = 1 << 20
"""Bytes of a plain (``P2``) PGM's pixel text decoded at a time (the temporaries stay within about
50 MB; larger chunks were slower, their temporaries beyond the caches)."""
MAX_PLAIN_DIGITS = 18
"""Most digits of one plain PGM value, leading zeros included."""
MAXVAL_DIGITS = 5
"""Digits of a PGM's largest value, 65,535."""


def _spaces(text: np.ndarray) -> np.ndarray:
    """Which bytes of ``text`` (uint8) are ASCII whitespace (space, tab, LF, VT, FF, CR)."""
    return (text == 32) | ((text >= 9) & (text <= 13))


def _plain_pgm_values(data: bytes, offset: int, count: int, source: str, what: str) -> np.ndarray:
    """The first ``count`` whitespace-separated values of a plain PGM's pixel text from ``offset``
    (``#`` comments skipped), as (count,) int64.

    Decoded a chunk of :data:`PLAIN_CHUNK` bytes at a time, arithmetically from the digits (no
    string per value, no string array as wide as the longest value), so memory stays bounded
    whatever the values hold. Values beyond the ``count``-th are not looked at.
    """
    if b"#" in data[offset:]:
        data = data[:offset] + re.sub(rb"#[^\r\n]*", b" ", data[offset:])
    raw = np.frombuffer(data, np.uint8)
    out = np.empty(count, np.int64)
    filled, position, end_of_text = 0, offset, len(raw)
    while filled < count and position < end_of_text:
        stop = min(end_of_text, position + max(PLAIN_CHUNK, 2 * MAX_PLAIN_DIGITS))
        if stop < end_of_text and not _spaces(raw[stop]):   # the chunk would cut a value: end before it
            spaces = np.flatnonzero(_spaces(raw[position:stop]))
            if not len(spaces):
                raise WorldError(f"{source}: not a valid PGM: a pixel value of more than {MAX_PLAIN_DIGITS} digits")
            stop = position + int(spaces[-1]) + 1
        chunk = raw[position:stop]
        word = ~_spaces(chunk)
        edges = np.diff(word.view(np.int8), prepend=np.int8(0), append=np.int8(0))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        take = min(len(starts), count - filled)
        if take:
            starts, ends = starts[:take], ends[:take]
            chunk, word = chunk[:ends[-1]], word[:ends[-1]]
            if np.any(word & ((chunk < 48) | (chunk > 57))):
                raise WorldError(f"{source}: not a valid PGM: a pixel value is not a whole number")
            lengths = ends - starts
            if lengths.max() > MAX_PLAIN_DIGITS:
                raise WorldError(f"{source}: not a valid PGM: a pixel value of more than {MAX_PLAIN_DIGITS} digits")
            # a value is at most 65,535 (a PGM's largest maxval): its last five digits, the others zeros
            long = np.flatnonzero(lengths > MAXVAL_DIGITS)
            if len(long):
                nonzero = np.concatenate([[0], np.cumsum(chunk > 48, dtype=np.int64)])   # digits 1-9 so far
                if np.any(nonzero[ends[long] - MAXVAL_DIGITS] > nonzero[starts[long]]):
                    raise WorldError(f"{source}: not a valid PGM: a pixel value is over 65535")
            values = chunk[ends - 1].astype(np.int64) - 48          # the units, then each place in turn
            for place in range(1, min(int(lengths.max()), MAXVAL_DIGITS)):
                has = np.flatnonzero(lengths > place)
                values[has] += (chunk[ends[has] - 1 - place].astype(np.int64) - 48) * 10**place
            out[filled:filled + take] = values
            filled += take
        position = stop
    if filled < count:
        raise WorldError(f"{source}: the PGM is cut short: {what}, it has {filled:,} values")
    return out


def _decode_with_opencv(data: bytes, source: str, width: int, height: int) -> tuple[np.ndarray, int]:
    """``(pixels (height, width) or (height, width, channels), maxval)`` of a PNG or BMP."""
    import cv2

    try:
        with _quiet_stderr():
            pixels = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        pixels = None
    if pixels is None or pixels.shape[:2] != (height, width):
        raise WorldError(f"{source}: not an image (PGM, PNG or BMP) that can be read: OpenCV could not decode it")
    if pixels.dtype == np.uint8:
        return pixels, 255
    if pixels.dtype == np.uint16:
        return pixels, 65535
    raise WorldError(f"{source}: the image has {pixels.dtype} pixels; a map needs 8- or 16-bit ones")


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """The process's standard error (file descriptor 2) sent to the null device for the block.

    libpng and OpenCV print their own lines (``libpng error: IHDR: CRC error``, OpenCV's
    warnings) straight to it when a file is broken; the reader says what is wrong, once. Only
    the C libraries write during the block (a decode), so nothing of the program's own is lost.
    """
    with contextlib.suppress(Exception):   # what the program wrote before goes out before the block
        sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:   # no standard error to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def read_image(path: str | Path, *, negate: int = 0, occupied_thresh: float = 0.65, free_thresh: float = 0.196,
               mode: str = "trinary", source_key: str = "image") -> np.ndarray:
    """The occupied cells of a map image (PGM ``P2``/``P5``, PNG or BMP), as ROS ``map_server`` reads it.

    A pixel's grey value ``x`` (0 to 255; a colour pixel's is the mean of its colour channels,
    alpha ignored; other bit depths are scaled to 0 to 255) is a probability of being occupied
    ``p = (255 - x) / 255``, or ``x / 255`` with ``negate``. ``p > occupied_thresh`` is
    occupied, ``p < free_thresh`` free and anything between unknown, which counts as
    occupied. ``mode`` ``"trinary"`` and ``"scale"`` read the same; ``"raw"`` takes ``x``
    (after ``negate``, as ``map_server`` does) as the cell's value: at least
    :data:`RAW_OCCUPIED` is occupied.

    The image's size is read from its header and refused over :data:`MAX_MAP_CELLS` before
    the pixels are decoded.

    Args:
        source_key: The key that named the image (for callers' messages; unused here).

    Returns:
        ``(rows, cols)`` bool, row 0 the bottom row: the image flipped, since its first line is the top.
    """
    source = str(path)
    if mode not in ROS_MODES:
        raise ValueError(f"mode must be one of {ROS_MODES}, got {mode!r}")
    data = read_regular_file(path, "map image", WorldError, limit=MAX_MAP_FILE_BYTES)
    kind, width, height = _image_size(data, source)
    _check_cells(source, height, width, "map image")
    if kind in ("P2", "P5"):
        pixels, maxval = _decode_pgm(data, source)
    else:
        pixels, maxval = _decode_with_opencv(data, source, width, height)
    if pixels.ndim == 3:   # BGR, BGRA, or grey and alpha: drop the alpha channel
        channels = pixels.shape[2]
        pixels = pixels[..., :3] if channels == 4 else pixels[..., :1] if channels == 2 else pixels
        total = pixels.sum(axis=2, dtype=np.int64)
        scale = pixels.shape[2] * maxval
    else:
        total, scale = pixels, maxval
    # Classify every possible channel sum once, then look the pixels up.
    grey = np.arange(scale + 1) * (255.0 / scale)
    if negate:
        grey = 255.0 - grey
    if mode == "raw":
        table = grey >= RAW_OCCUPIED
    else:
        p = (255.0 - grey) / 255.0
        table = ~(p < free_thresh)   # occupied (p > occupied_thresh) or unknown: both occupied
    return np.ascontiguousarray(table[np.flipud(total)])


def write_pgm(path: str | Path, occupied_bottom_up: np.ndarray) -> None:
    """Write a binary (``P5``) PGM map: occupied 0 (black), free 254, row 0 (the bottom) as the last line.

    What :func:`read_image` reads back to the same grid (with the default thresholds).
    """
    occupied = np.asarray(occupied_bottom_up, dtype=bool)
    if occupied.ndim != 2:
        raise ValueError(f"occupied must be a 2-D array, got shape {occupied.shape}")
    rows, cols = occupied.shape
    pixels = np.where(np.flipud(occupied), 0, 254).astype(np.uint8)
    with open(path, "wb") as file:
        file.write(f"P5\n# apf_physics occupancy map\n{cols} {rows}\n255\n".encode("ascii"))
        file.write(pixels.tobytes())


# -- ROS map_server YAML -----------------------------------------------------------------

_DECIMAL = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _ros_number(value: Any) -> float | None:
    """``value`` as a finite float, or None if it is not a finite number (bools are not numbers).

    A string that is a decimal number counts: YAML 1.1 reads ``5e-2`` (no dot) as a string,
    where map_server's yaml-cpp reads a number.
    """
    if isinstance(value, str) and len(value) <= 100 and _DECIMAL.fullmatch(value.strip()):
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def read_ros_map(yaml_path: str | Path, within: str | Path | None = None) -> OccupancyMap:
    """A ROS ``map_server`` map: its YAML and the image it names.

    Keys: ``image`` (a path relative to the YAML's folder), ``resolution`` [world units per
    cell], ``origin`` ``[x, y, yaw]`` (the lower-left corner of the map; ``yaw`` must be 0),
    and optionally ``negate`` (0 or 1, default 0), ``occupied_thresh`` (0.65),
    ``free_thresh`` (0.196) and ``mode`` (``trinary``, ``scale`` or ``raw``); see
    :func:`read_image`.

    The YAML is read as world files are (:func:`~apf_physics.common.safeyaml.read_yaml_file`: within
    limits, no key twice). It is a file that another file names, so messages say where and
    what is wrong without showing what it holds.

    Args:
        within: The image must be inside this folder (symbolic links followed); None: anywhere.

    Raises:
        WorldError: Every problem of the YAML, one line each: ``<file>: <key>: <what is wrong>``;
            or one line for the image (``<file>: image: <image file>: <what is wrong>``).
    """
    source = str(yaml_path)
    spec = read_yaml_file(yaml_path, "map", WorldError, limit=MAX_MAP_YAML_BYTES, quote=False)
    if not isinstance(spec, dict):
        raise WorldError(f"{source}: expected a mapping of map_server keys ({', '.join(ROS_KEYS)}), "
                         f"got {_type_name(spec)}")
    # (the image is beside the YAML itself, wherever a link to it is)
    return ros_map_from_dict(spec, source, Path(os.path.realpath(yaml_path)).parent, within=within, quote=False)


def _type_name(value: Any) -> str:
    """``a list``, ``a str``, ``nothing``: what a value is, without what it holds."""
    if value is None:
        return "nothing"
    name = type(value).__name__
    return f"{'an' if name[0] in 'aeiou' else 'a'} {name}"


def _unknown_ros_keys(spec: dict, quote: bool, bad: Callable[[str, str], None]) -> None:
    """A ROS map's unknown keys: each named with a "did you mean" (``quote``: a world file's own), or,
    for a map YAML a world names, counted, with the known keys they are close to."""
    unknown = [key for key in spec if key not in ROS_KEYS]
    if quote:
        for key in unknown:
            name = key if isinstance(key, str) and key.isprintable() and len(key) <= 40 else shortened(key, 40)
            bad(name, f"unknown key{did_you_mean(key, ROS_KEYS)}; a ROS map has {', '.join(ROS_KEYS)}")
    elif unknown:
        close = sorted({c for c in (closest_match(k, ROS_KEYS) for k in unknown) if c is not None})
        hint = f" (did you mean {', '.join(map(repr, close))}?)" if close else ""
        bad("keys", f"{len(unknown)} unknown key{'s' if len(unknown) > 1 else ''}{hint}; a ROS map has "
                    f"{', '.join(ROS_KEYS)}")


def _ros_origin(value: Any, kind: Callable[[Any], str],
                bad: Callable[[str, str], None]) -> tuple[float, float] | None:
    """A ROS map's ``origin: [x, y, yaw]`` (yaw 0, or left out), or None with its problems told to ``bad``."""
    if not isinstance(value, list) or len(value) not in (2, 3):
        bad("origin", f"expected [x, y, yaw], got {kind(value)}")
        return None
    found = [_ros_number(v) for v in value]
    for i, (raw, number) in enumerate(zip(value, found)):
        if number is None:
            bad(f"origin[{i}]", f"expected a finite number, got {kind(raw)}")
    for i, number in enumerate(found[:2]):
        if number is not None and abs(number) > MAX_ORIGIN:
            bad(f"origin[{i}]", f"at most {MAX_ORIGIN:g} from 0 (farther, the map's cells lose their precision)")
            found[i] = None
    if len(value) == 3 and found[2] is not None and found[2] != 0:
        bad("origin[2]", f"a rotated map (yaw {found[2]:g}) is not supported; rotate the image instead")
    return (found[0], found[1]) if all(n is not None for n in found[:2]) else None


def ros_map_from_dict(spec: dict, source: str, folder: str | Path, within: str | Path | None = None,
                      quote: bool = True) -> OccupancyMap:
    """A ROS map from the keys of its YAML (``image`` relative to ``folder``); see :func:`read_ros_map`.

    A world file's ``grid:`` may hold these keys inline; ``source`` names it in messages.

    Args:
        within: The image must be inside this folder (symbolic links followed); None: anywhere.
        quote: Messages may show the values (a world file's own); False: only their types (a map
            YAML that a world file names).
    """
    problems: list[str] = []
    kind = described if quote else _type_name

    def bad(key: str, problem: str) -> None:
        problems.append(f"{source}: {key}: {problem}")

    _unknown_ros_keys(spec, quote, bad)
    for key in ("image", "resolution", "origin"):
        if key not in spec:
            bad(key, "missing")

    image = None
    if "image" in spec:
        try:
            image = named_file(spec["image"], folder, within)
        except NamedFileError as exc:
            # a map YAML's own text is not shown: its image's name only when it names an image file
            name = spec["image"]
            shown = quote or not isinstance(name, str) or Path(name).suffix.lower() in IMAGE_SUFFIXES
            bad("image", str(exc) if shown else "names no readable file (a name that is not a .pgm, .png or .bmp "
                                               "file is not shown)")

    resolution = None
    if "resolution" in spec:
        resolution = _ros_number(spec["resolution"])
        if resolution is None or resolution <= 0:
            bad("resolution", f"expected a positive finite number [units per cell], got {kind(spec['resolution'])}")
            resolution = None

    origin = _ros_origin(spec["origin"], kind, bad) if "origin" in spec else None

    negate = spec.get("negate", 0)
    if isinstance(negate, bool):
        negate = int(negate)
    if negate not in (0, 1) or not isinstance(negate, int):
        bad("negate", f"expected 0 or 1, got {kind(spec['negate'])}")
        negate = 0

    thresholds = {}
    for key, default in (("occupied_thresh", 0.65), ("free_thresh", 0.196)):
        number = _ros_number(spec.get(key, default))
        if number is None or not 0 <= number <= 1:
            bad(key, f"expected a number from 0 to 1, got {kind(spec[key])}")
        else:
            thresholds[key] = number
    if len(thresholds) == 2 and not thresholds["free_thresh"] < thresholds["occupied_thresh"]:
        bad("free_thresh", f"must be below occupied_thresh ({thresholds['occupied_thresh']:g}), "
                           f"got {thresholds['free_thresh']:g}")

    mode = spec.get("mode", "trinary")
    if mode not in ROS_MODES:
        bad("mode", f"expected one of {', '.join(ROS_MODES)}, got {kind(mode)}{did_you_mean(mode, ROS_MODES)}")

    if problems:
        raise WorldError("\n".join(problems))
    assert image is not None and resolution is not None and origin is not None
    try:
        occupied = read_image(image, negate=negate, occupied_thresh=thresholds["occupied_thresh"],
                              free_thresh=thresholds["free_thresh"], mode=mode)
    except WorldError as exc:
        raise WorldError(f"{source}: image: {exc}") from None
    rows, cols = occupied.shape
    if not all(math.isfinite(v) for v in (origin[0] + cols * resolution, origin[1] + rows * resolution)):
        raise WorldError(f"{source}: resolution: {resolution:g} makes the map infinitely large")
    return OccupancyMap(occupied=occupied, cell=resolution, origin=origin, source=source)


# -- MovingAI benchmarks -----------------------------------------------------------------

_BLANK_LINES = re.compile(rb"(?:[ \t\r\f\v]*\n)*")
MAX_HEADER_LINE = 1000
"""Longest header line of a MovingAI map [characters] (``height 4000`` is 11)."""
_NOT_SPACE = re.compile(rb"\S")


def read_movingai_map(path: str | Path, cell: float = 1.0) -> OccupancyMap:
    """A MovingAI grid map (``.map``): ``type octile``, ``height H``, ``width W``, ``map``, then H rows of W characters.

    ``.``, ``G`` and ``S`` are free; everything else (``@``, ``O``, ``T``, ``W`` or any other
    character) is occupied. The first row is the top of the map, so it becomes row ``H - 1``.
    The map's lower-left corner is at the origin; a cell is ``cell`` world units wide.
    The ``type`` line is optional and its value not checked (every type is the same grid).
    Lines end with LF or CR LF. Messages give line numbers, never the file's text (a world
    file may name any file as its map).
    """
    source = str(path)
    if isinstance(cell, bool) or not isinstance(cell, numbers.Real) or not (math.isfinite(cell) and cell > 0):
        raise WorldError(f"{source}: the cell size must be a positive finite number, got {shortened(cell)}")
    data = read_regular_file(path, "MovingAI map", WorldError, limit=MAX_MAP_FILE_BYTES)

    header: dict[str, int] = {}
    position, number = 0, 1    # where the next line starts, and its number
    while True:
        skipped = _BLANK_LINES.match(data, position).end()
        number += data.count(b"\n", position, skipped)
        position = skipped
        if _NOT_SPACE.search(data, position) is None:
            raise WorldError(f"{source}: line {number}: no 'map' line (the header ends with 'map', then the rows)")
        end = data.find(b"\n", position)
        end = len(data) if end < 0 else end
        if end - position > MAX_HEADER_LINE:
            raise WorldError(f"{source}: line {number}: a header line of more than {MAX_HEADER_LINE:,} characters")
        words = data[position:end].split()
        position, number = end + 1, number + 1
        key = words[0].lower()
        if key == b"map" and len(words) == 1:
            break   # the rows follow this line
        if key not in (b"type", b"height", b"width") or len(words) != 2:
            raise WorldError(f"{source}: line {number - 1}: expected 'type octile', 'height H', 'width W' or 'map'")
        name = key.decode()
        if name in header:
            raise WorldError(f"{source}: line {number - 1}: a second '{name}' line")
        if name == "type":
            header[name] = 0
            continue
        if not _ascii_digits(words[1]) or len(words[1]) > 9 or int(words[1]) == 0:
            raise WorldError(f"{source}: line {number - 1}: {name}: expected a positive whole number of at most 9 digits")
        header[name] = int(words[1])
    start = number - 1   # the 'map' line
    missing = [name for name in ("height", "width") if name not in header]
    if missing:
        raise WorldError(f"{source}: line {start}: the header has no {' or '.join(missing)} line")
    height, width = header["height"], header["width"]
    _check_cells(source, height, width, "MovingAI map")

    grid = _movingai_rows(data, position, height, width)
    if grid is None:   # not rows of equal length: find the line that is wrong
        parts = data[position:].split(b"\n", height)
        rows = [row[:-1] if row.endswith(b"\r") else row for row in parts[:height]]
        for index, row in enumerate(rows):
            if len(row) != width:
                if not any(rest.strip() for rest in parts[index:]):
                    raise WorldError(f"{source}: line {start + 1 + index}: the map ends after {index} rows, "
                                     f"expected height {height}")
                raise WorldError(f"{source}: line {start + 1 + index}: a row of {len(row)} characters, "
                                 f"expected width {width}")
        if len(rows) < height:
            raise WorldError(f"{source}: line {start + len(rows)}: the map ends after {len(rows)} rows, "
                             f"expected height {height}")
        tail = parts[height] if len(parts) > height else b""
        extra = _NOT_SPACE.search(tail)
        if extra is not None:
            line = start + height + 1 + tail.count(b"\n", 0, extra.start())
            raise WorldError(f"{source}: line {line}: more rows than the height {height}")
        grid = np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(height, width)
    free = np.isin(grid, np.frombuffer(MOVINGAI_FREE, dtype=np.uint8))
    return OccupancyMap(occupied=np.ascontiguousarray(np.flipud(~free)), cell=float(cell), origin=(0.0, 0.0),
                        source=source)


def _movingai_rows(data: bytes, position: int, height: int, width: int) -> np.ndarray | None:
    """The ``(height, width)`` characters of a map whose rows all end alike (LF, or CR LF) and
    after which only whitespace follows; None when they do not (the caller finds the line)."""
    for ending in (b"\n", b"\r\n"):
        stride = width + len(ending)
        size = height * stride
        body = np.frombuffer(data, np.uint8, count=min(size, len(data) - position), offset=position)
        if len(body) < size - len(ending):   # the last row may lack its line end
            continue
        padded = body if len(body) == size else np.concatenate([body, np.frombuffer(ending, np.uint8)])
        rows = padded.reshape(height, stride)
        ends_alike = np.all(rows[:, width:] == np.frombuffer(ending, np.uint8)) and not np.any(rows[:, :width] == 10)
        if ending == b"\n":   # (a row ending in CR LF among LF ones is a row one shorter)
            ends_alike = ends_alike and not np.any(rows[:, width - 1] == ord("\r"))
        if ends_alike and not _NOT_SPACE.search(data, position + size):
            return rows[:, :width]
    return None


@dataclass(frozen=True)
class Scenario:
    """One line of a MovingAI scenario file (``.scen``): a start and a goal on a map.

    Attributes:
        bucket: The benchmark's bucket (scenarios of similar length share one).
        map_name: The map file as the scenario names it.
        width, height: The map's size [cells].
        start, goal: ``(x, y)`` MovingAI cell coordinates: ``x`` the column, ``y`` the row
            counted from the **top**.
        optimal: Length of an optimal octile path [cells].
        source, line: The file and line it was read from (for messages; not compared).
    """

    bucket: int
    map_name: str
    width: int
    height: int
    start: tuple[int, int]
    goal: tuple[int, int]
    optimal: float
    source: str = field(default="", compare=False)
    line: int = field(default=0, compare=False)


_SCEN_FIELDS = ("bucket", "map", "width", "height", "start_x", "start_y", "goal_x", "goal_y", "optimal_length")
MAX_SCENARIOS = 100_000
"""Most scenarios run from one file (the largest benchmark files hold a few thousand); a larger
file is read with ``limit`` (``eval --limit N``) or ``buckets``."""
_WHOLE_FIELD = re.compile("[0-9]{1,9}")
_NUMBER_FIELD = re.compile(r"[+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]{1,3})?")


class _BadLine(Exception):
    """A scenario line's problem (the message, without the file and line)."""


def _scen_values(fields_: list[str], expected: tuple[int, int] | None) -> tuple:
    """``(bucket, map, width, height, sx, sy, gx, gy, optimal)`` of a scenario line's fields, checked.

    Whole numbers are ASCII digits (``str.isdigit`` would take ``²`` and ``①``), at most 9 of
    them; the optimal length a decimal number, finite, no longer than any path on the map can
    be (one visiting every cell: ``(width · height − 1) · √2``); coordinates inside the map; and
    the map of ``expected`` ``(width, height)`` size when given.

    Raises:
        _BadLine: the first problem, without the field's text (messages do not show a file's contents).
    """
    if len(fields_) != len(_SCEN_FIELDS):
        raise _BadLine(f"expected {len(_SCEN_FIELDS)} fields ({' '.join(_SCEN_FIELDS)}), got {len(fields_)}")
    values: list[Any] = []
    for name, text in zip(_SCEN_FIELDS, fields_):
        if name == "map":
            values.append(text)
        elif name == "optimal_length":
            number = float(text) if _NUMBER_FIELD.fullmatch(text) else None
            if number is None or not math.isfinite(number):
                raise _BadLine(f"{name}: expected a non-negative decimal number")
            values.append(number)
        else:
            if not _WHOLE_FIELD.fullmatch(text):
                raise _BadLine(f"{name}: expected a whole number of at most 9 digits (0-9)")
            values.append(int(text))
    _check_scen(values, expected)
    return tuple(values)


def _check_scen(values: Sequence[Any], expected: tuple[int, int] | None) -> None:
    """The checks of :func:`_scen_values` that compare fields (sizes, coordinates, the optimal length)."""
    _, _, width, height, sx, sy, gx, gy, optimal = values
    if width == 0 or height == 0:
        raise _BadLine(f"the map is empty ({width} x {height} cells)")
    if expected is not None and (width, height) != expected:
        raise _BadLine(f"the scenario is for a {width} x {height} map, but the map is {expected[0]} x {expected[1]}")
    for name, value, limit in (("start_x", sx, width), ("start_y", sy, height), ("goal_x", gx, width),
                               ("goal_y", gy, height)):
        if value >= limit:
            raise _BadLine(f"{name}: {value} is outside the {width} x {height} map")
    longest = (width * height - 1) * math.sqrt(2.0)
    if optimal > longest:
        raise _BadLine(f"optimal_length: {optimal:.6g} is longer than any path on a {width} x {height} map "
                       f"(at most {longest:.6g})")


@dataclass(frozen=True)
class ScenarioFile:
    """What :func:`read_scenarios` read from a ``.scen`` file.

    Attributes:
        scenarios: The scenarios kept (the buckets asked for, at most ``limit`` of them), in file order.
        lines: Scenario lines in the file (all of them valid).
        selected: Of them, those in the buckets asked for (before ``limit``).
        other_maps: Lines whose map is not the ``map_name`` given (compared by file name).
        first_other: The line number of the first of them (0: none).
    """

    scenarios: list[Scenario]
    lines: int
    selected: int
    other_maps: int = 0
    first_other: int = 0


def read_scenarios(path: str | Path, buckets: tuple[int, int] | None = None, limit: int | None = None,
                   map_name: str | None = None, map_size: tuple[int, int] | None = None) -> ScenarioFile:
    """The scenarios of a MovingAI scenario file (``.scen``, ``version 1``), checked line by line.

    After the ``version 1`` line, one scenario a line, tab- (or space-) separated: bucket, map,
    width, height, start x, start y, goal x, goal y, optimal length. Blank lines are skipped;
    lines end with LF or CR LF.

    Every line is checked, and every bad line is reported: one :class:`WorldError` listing the
    first :data:`MAX_PROBLEMS` as ``<file>: line N: <what is wrong>``
    (never the line's text), then how many more. Only the scenarios asked for are built: the
    buckets are applied, and then ``limit``, while reading (a file of millions of lines costs
    its reading, a few seconds, not millions of scenarios).

    Args:
        buckets: Only scenarios of buckets in this inclusive range.
        limit: At most this many scenarios, taken evenly through those selected (every bucket's
            range of lengths stays represented: a file lists its scenarios by bucket).
        map_name: The map the scenarios are run on: lines naming another map (by file name, any
            folder) are counted (:attr:`ScenarioFile.other_maps`).
        map_size: ``(width, height)`` of that map: a line for another size is a problem.

    Raises:
        WorldError: The file is unreadable, holds no scenario lines, has bad lines, or more than
            :data:`MAX_SCENARIOS` are selected without ``limit``.
    """
    source = str(path)
    data = read_regular_file(path, "MovingAI scenario", WorldError, limit=MAX_SCEN_FILE_BYTES)
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise WorldError(f"{source}: line {line}: not UTF-8 text") from None
    raw = np.frombuffer(data, np.uint8)
    breaks = np.flatnonzero(raw == 10)
    starts = np.concatenate([[0], breaks + 1])     # line k (from 0) is data[starts[k]:ends[k]]
    ends = np.concatenate([breaks, [len(raw)]])
    del breaks
    first = 0
    while first < len(starts) and not data[starts[first]:ends[first]].strip():
        first += 1
    if first == len(starts):
        raise WorldError(f"{source}: line 1: empty; expected 'version 1'")
    if data[starts[first]:ends[first]].split() not in ([b"version", b"1"], [b"version", b"1.0"]):
        raise WorldError(f"{source}: line {first + 1}: expected 'version 1' (the first line of a MovingAI scenario file)")
    read = _ScenLines(source, data, map_size, buckets, _file_name(map_name) if map_name is not None else None)
    for at in range(first + 1, len(starts), SCEN_BLOCK):
        read.block(starts[at:at + SCEN_BLOCK], ends[at:at + SCEN_BLOCK], at + 1)
    problems, bad, chosen = read.problems, read.bad, np.sort(np.frombuffer(read.chosen, np.int64))
    total, other, first_other = read.total, read.other, read.first_other
    if bad:
        if bad > len(problems):
            problems.append(f"{source}: and {bad - len(problems):,} more bad line{'s' if bad - len(problems) > 1 else ''} "
                            f"({bad:,} in all; the first {MAX_PROBLEMS} are listed)")
        raise WorldError("\n".join(problems))
    selected = len(chosen)
    if limit is not None and selected > limit:
        chosen = chosen[np.linspace(0, selected - 1, limit).round().astype(np.intp)]
    elif selected > MAX_SCENARIOS:
        raise WorldError(f"{source}: {selected:,} scenarios{' in the buckets asked for' if buckets else ''}, over "
                         f"the {MAX_SCENARIOS:,} run at once: take some (eval --limit N, or --buckets A-B)")
    scenarios = []
    for number in chosen.tolist():
        bucket, name, width, height, sx, sy, gx, gy, optimal = _scen_values(
            _scen_fields(data[starts[number - 1]:ends[number - 1]].decode("utf-8")), map_size)
        scenarios.append(Scenario(bucket=bucket, map_name=name, width=width, height=height, start=(sx, sy),
                                  goal=(gx, gy), optimal=optimal, source=source, line=number))
    return ScenarioFile(scenarios, total, selected, other, first_other)


SCEN_BLOCK = 1 << 16
"""Scenario lines checked at a time: the well-formed ones column by column, the others one by one."""
_POWERS_OF_TEN = 10 ** np.arange(8, -1, -1, dtype=np.int32)
_DECIMAL_BYTES = np.zeros(256, bool)
_DECIMAL_BYTES[list(b"0123456789.eE+- ")] = True


def _scen_fields(line: str) -> list[str]:
    """A scenario line's fields: tab-separated (a map name may hold spaces), else by whitespace."""
    return [f.strip() for f in line.strip().split("\t")] if "\t" in line else line.split()


class _ScenLines:
    """The lines of a ``.scen`` file after its ``version`` line, checked block by block
    (:func:`read_scenarios`): their problems (the first :data:`MAX_PROBLEMS`) and how many, and the
    numbers of the lines selected (``buckets``), with the counts :class:`ScenarioFile` reports.

    A line of eight tabs (the benchmark's own form) is checked with the others of its block,
    column by column on the file's bytes; any other line (spaces, a field missing, a blank line)
    one by one (:func:`_scen_values`), as is every line found bad, for its message.
    """

    def __init__(self, source: str, data: bytes, expected: tuple[int, int] | None,
                 buckets: tuple[int, int] | None, wanted_map: str | None):
        self.source, self.data, self.expected, self.buckets = source, data, expected, buckets
        self.raw = np.frombuffer(data, np.uint8)
        self.wanted = None if wanted_map is None else np.frombuffer(wanted_map.encode("utf-8"), np.uint8)
        self.wanted_map = wanted_map
        self.problems: list[str] = []
        self.bad = self.total = self.other = self.first_other = 0
        self.chosen = array.array("q")
        self._alone: list[tuple[int, int, int]] = []

    def problem(self, number: int, what: object) -> None:
        self.bad += 1
        if len(self.problems) < MAX_PROBLEMS:
            self.problems.append(f"{self.source}: line {number}: {what}")

    def one(self, start: int, end: int, number: int) -> None:
        """Line ``number`` (``data[start:end]``) on its own."""
        line = self.data[start:end].decode("utf-8")
        if not line.strip():
            return
        try:
            values = _scen_values(_scen_fields(line), self.expected)
        except _BadLine as exc:
            self.problem(number, exc)
            return
        other = self.wanted_map is not None and _file_name(values[1]) != self.wanted_map
        self._count(np.array([values[0]]), np.array([other]), np.array([number]))

    def block(self, starts: np.ndarray, ends: np.ndarray, first: int) -> None:
        """Lines ``first``, ``first + 1``, ... (``data[starts[k]:ends[k]]``)."""
        raw = self.raw
        ends = ends - ((ends > starts) & (raw[np.maximum(ends - 1, 0)] == 13))   # (a CR before the LF)
        numbers = np.arange(first, first + len(starts))
        tabs = np.flatnonzero(raw[starts[0]:ends[-1]] == 9) + starts[0]
        line_of = np.searchsorted(starts, tabs, side="right") - 1
        inside = tabs < ends[line_of]
        tabs, line_of = tabs[inside], line_of[inside]
        count = np.bincount(line_of, minlength=len(starts))
        tabbed = count == 8
        if not tabbed.all():   # the others each on its own, in the order of the lines with those found bad below
            self._alone = [(int(numbers[k]), int(starts[k]), int(ends[k])) for k in np.flatnonzero(~tabbed).tolist()]
        else:
            self._alone = []
        if tabbed.any():
            self._columns(tabs[tabbed[line_of]].reshape(-1, 8), starts[tabbed], ends[tabbed], numbers[tabbed])
        for number, start, end in sorted(self._alone):
            self.one(start, end, number)

    def _columns(self, cut: np.ndarray, starts: np.ndarray, ends: np.ndarray, numbers: np.ndarray) -> None:
        """Lines of eight tabs (``cut`` (n, 8) their positions), column by column; those found bad are
        left to :meth:`one` (``_alone``), which says why."""
        lo = np.column_stack([starts, cut + 1])               # each line's nine fields: [lo, hi)
        hi = np.column_stack([cut, ends])
        whole = [0, 2, 3, 4, 5, 6, 7]
        (bucket, width, height, sx, sy, gx, gy), wrong = self._whole(lo[:, whole], hi[:, whole])
        optimal, bad = self._decimal(lo[:, 8], hi[:, 8])
        wrong |= bad
        with np.errstate(over="ignore", invalid="ignore"):
            wrong |= ((width == 0) | (height == 0) | (sx >= width) | (gx >= width) | (sy >= height) | (gy >= height)
                      | ~np.isfinite(optimal) | (optimal < 0) | (optimal > (width * height - 1) * math.sqrt(2.0)))
        if self.expected is not None:
            wrong |= (width != self.expected[0]) | (height != self.expected[1])
        for k in np.flatnonzero(wrong).tolist():   # each again on its own: its message (or a space the columns took amiss)
            self._alone.append((int(numbers[k]), int(lo[k, 0]), int(hi[k, 8])))
        keep = ~wrong
        self._count(bucket[keep], self._other_maps(lo[keep, 1], hi[keep, 1]), numbers[keep])

    def _whole(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(values (C, n), bad (n,))``: the whole numbers in ``data[lo:hi]`` ((n, C) fields, each 1 to 9
        ASCII digits), and the lines where one is not."""
        length = hi - lo
        bad = np.any((length < 1) | (length > 9), axis=1)
        place = np.arange(9)
        at = np.maximum(hi[..., None] - 9 + place, 0)                                # right-aligned: units last
        digits = self.raw[at] - np.uint8(48)                                         # (n, C, 9); not a digit: > 9
        digits[place < 9 - np.minimum(length, 9)[..., None]] = 0                     # before the number
        bad |= np.any(digits > 9, axis=(1, 2))
        values = digits.astype(np.int32) @ _POWERS_OF_TEN                           # at most 999,999,999
        return values.T.astype(np.int64), bad

    def _decimal(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The decimal numbers in ``data[lo:hi]`` (up to 24 characters), and which are not (or not plainly)."""
        length = hi - lo
        bad = (length < 1) | (length > 24)
        place = np.arange(24)
        at = np.maximum(hi[:, None] - 24 + place, 0)
        text = self.raw[at]
        text[place < 24 - np.minimum(length, 24)[:, None]] = 32                      # spaces before the number
        bad |= ~np.all(_DECIMAL_BYTES[text], axis=1)
        text[bad] = 48
        try:
            return np.ascontiguousarray(text).view("S24").ravel().astype(float), bad
        except ValueError:   # (one like 1.2.3: each on its own says which)
            return np.zeros(len(lo)), np.ones(len(lo), bool)

    def _other_maps(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Which of the map names ``data[lo:hi]`` name another map than the one wanted (by file name)."""
        if self.wanted is None:
            return np.zeros(len(lo), bool)
        raw = self.raw
        base = int(lo.min()) if len(lo) else 0
        span = raw[base:int(hi.max()) if len(hi) else 0]
        slash = np.flatnonzero((span == 47) | (span == 92)) + base
        last = np.searchsorted(slash, hi) - 1                          # the last slash before each name's end
        name_lo = np.where((last >= 0) & (slash[np.maximum(last, 0)] >= lo), slash[np.maximum(last, 0)] + 1, lo) \
            if len(slash) else lo
        n = len(self.wanted)
        other = (hi - name_lo) != n
        same_length = np.flatnonzero(~other)
        if len(same_length) and n:
            text = raw[name_lo[same_length, None] + np.arange(n)]
            other[same_length] = np.any(text != self.wanted, axis=1)
        return other

    def _count(self, bucket: np.ndarray, other: np.ndarray, numbers: np.ndarray) -> None:
        """Valid lines: counted, those naming another map counted, those in the buckets kept."""
        self.total += len(numbers)
        if other.any():
            self.other += int(other.sum())
            first = int(numbers[np.argmax(other)])
            self.first_other = min(self.first_other, first) if self.first_other else first
        if self.buckets is not None:
            numbers = numbers[(bucket >= self.buckets[0]) & (bucket <= self.buckets[1])]
        self.chosen.extend(numbers.tolist())


def _file_name(name: str) -> str:
    """The file name of a map as a scenario names it (``maps/dao/arena.map`` → ``arena.map``; either slash)."""
    return name.replace("\\", "/").rsplit("/", 1)[-1]


def read_movingai_scen(path: str | Path) -> list[Scenario]:
    """Every scenario of a MovingAI scenario file (``.scen``): :func:`read_scenarios`' scenarios."""
    return read_scenarios(path).scenarios


def scen_text(scenarios: list[Scenario]) -> str:
    """A MovingAI scenario file's text (``version 1``, then one tab-separated line per scenario):
    what :func:`read_movingai_scen` reads back."""
    lines = ["version 1"]
    for s in scenarios:
        lines.append("\t".join([str(s.bucket), s.map_name, str(s.width), str(s.height), str(s.start[0]),
                                str(s.start[1]), str(s.goal[0]), str(s.goal[1]), repr(float(s.optimal))]))
    return "\n".join(lines) + "\n"


def scenario_points(scen: Scenario, grid: OccupancyMap) -> tuple[np.ndarray, np.ndarray]:
    """World coordinates of a scenario's start and goal on ``grid``: the centres of their cells.

    ``x = origin_x + (col + 0.5) · cell``, ``y = origin_y + (rows - 1 - row + 0.5) · cell``
    (MovingAI counts rows from the top).

    Raises:
        WorldError: The scenario is for a map of another size.
    """
    rows, cols = grid.occupied.shape
    if (scen.width, scen.height) != (cols, rows):
        where = f"{scen.source or 'scenario'}: line {scen.line}" if scen.line else (scen.source or "scenario")
        raise WorldError(f"{where}: the scenario is for a {scen.width} x {scen.height} map, "
                         f"but {grid.source} is {cols} x {rows}")
    x0, y0 = grid.origin

    def point(cell: tuple[int, int]) -> np.ndarray:
        col, row = cell
        return np.array([x0 + (col + 0.5) * grid.cell, y0 + (rows - 1 - row + 0.5) * grid.cell])

    return point(scen.start), point(scen.goal)
