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

import math
import numbers
import os
import re
import reprlib
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from apf_physics.errors import WorldError, did_you_mean
from apf_physics.common.safefile import read_regular_file

MAX_MAP_CELLS = 16_000_000
"""Largest grid read [cells] (rows × cols; 4000 × 4000), checked from the header before decoding."""
MAX_MAP_FILE_BYTES = 256 * 2**20
"""Largest map image or MovingAI map file [bytes]."""
MAX_MAP_YAML_BYTES = 2**20
"""Largest ROS map YAML [bytes] (a real one is a few hundred)."""
MAX_SCEN_FILE_BYTES = 64 * 2**20
"""Largest MovingAI scenario file [bytes] (the largest benchmark files are a few MB)."""

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

_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxstring, _REPR.maxlong, _REPR.maxother = 2, 4, 4, 40, 24, 40


def _short(value: Any, limit: int = 60) -> str:
    """``value`` for a message: one line of at most ``limit`` characters, whatever it is."""
    try:
        text = _REPR.repr(value)
    except Exception:  # a huge integer, or a repr that fails: say what it is
        text = f"<{type(value).__name__}>"
    text = text.replace("\n", " ")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _kind(value: Any) -> str:
    """``list [1, 2, ...]``: the type and the shortened value (``null`` for an empty YAML value)."""
    return "null" if value is None else f"{type(value).__name__} {_short(value)}"


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
        if not token.isdigit() or len(token) > 9:
            found = _short(token.decode("latin-1")) if token else "missing"
            raise WorldError(f"{source}: not a valid PGM: its {name} is {found}")
        values.append(int(token))
        position = match.end()
    width, height, maxval = values
    if not 0 < maxval < 65536:
        raise WorldError(f"{source}: not a valid PGM: its maxval is {maxval}, expected 1 to 65535")
    return width, height, maxval, position + 1   # one whitespace character ends the header


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
    raise WorldError(f"{source}: not an image (PGM, PNG or BMP) that can be read as a map: "
                     f"it starts with {_short(data[:8])}")


def _decode_pgm(data: bytes, source: str) -> tuple[np.ndarray, int]:
    """``(pixels (height, width) int, maxval)`` of a PGM: decoded here, since OpenCV scales
    ``P2`` pixels by ``maxval`` but not ``P5`` ones, and leaves 16-bit ones unscaled."""
    width, height, maxval, offset = _pgm_header(data, source)
    count = width * height
    if data[:2] == b"P5":
        dtype = np.dtype(">u2" if maxval > 255 else "u1")
        if len(data) - offset < count * dtype.itemsize:
            raise WorldError(f"{source}: the PGM is cut short: {width} x {height} pixels need "
                             f"{count * dtype.itemsize:,} bytes, it has {max(len(data) - offset, 0):,}")
        pixels = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
    else:
        text = re.sub(rb"#[^\r\n]*", b" ", data[offset - 1:])
        tokens = text.split()
        if len(tokens) < count:
            raise WorldError(f"{source}: the PGM is cut short: {width} x {height} pixels, it has {len(tokens):,} values")
        try:
            pixels = np.array(tokens[:count]).astype(np.int64)
        except (ValueError, OverflowError):
            raise WorldError(f"{source}: not a valid PGM: a pixel value is not a whole number") from None
    if pixels.min() < 0 or pixels.max() > maxval:
        raise WorldError(f"{source}: not a valid PGM: a pixel value is over its maxval {maxval}")
    return pixels.reshape(height, width), maxval


def _decode_with_opencv(data: bytes, source: str, width: int, height: int) -> tuple[np.ndarray, int]:
    """``(pixels (height, width) or (height, width, channels), maxval)`` of a PNG or BMP."""
    import cv2

    try:
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


def read_ros_map(yaml_path: str | Path) -> OccupancyMap:
    """A ROS ``map_server`` map: its YAML and the image it names.

    Keys: ``image`` (a path relative to the YAML's folder), ``resolution`` [world units per
    cell], ``origin`` ``[x, y, yaw]`` (the lower-left corner of the map; ``yaw`` must be 0),
    and optionally ``negate`` (0 or 1, default 0), ``occupied_thresh`` (0.65),
    ``free_thresh`` (0.196) and ``mode`` (``trinary``, ``scale`` or ``raw``); see
    :func:`read_image`.

    Raises:
        WorldError: Every problem of the YAML, one line each: ``<file>: <key>: <what is wrong>``;
            or one line for the image (``<file>: image: <image file>: <what is wrong>``).
    """
    source = str(yaml_path)
    data = read_regular_file(yaml_path, "map", WorldError, limit=MAX_MAP_YAML_BYTES)
    try:
        spec = yaml.safe_load(data)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}: " if mark is not None else ""
        raise WorldError(f"{source}: {where}not valid YAML: {exc.problem}") from None
    except (yaml.YAMLError, ValueError, OverflowError, RecursionError) as exc:
        reason = " ".join(str(exc).split())
        raise WorldError(f"{source}: not valid YAML: {reason if len(reason) <= 100 else reason[:97] + '...'}") from None
    if not isinstance(spec, dict):
        raise WorldError(f"{source}: expected a mapping of map_server keys ({', '.join(ROS_KEYS)}), got {_kind(spec)}")
    return ros_map_from_dict(spec, source, Path(yaml_path).parent)


def ros_map_from_dict(spec: dict, source: str, folder: str | Path) -> OccupancyMap:
    """A ROS map from the keys of its YAML (``image`` relative to ``folder``); see :func:`read_ros_map`.

    A world file's ``grid:`` may hold these keys inline; ``source`` names it in messages.
    """
    problems: list[str] = []

    def bad(key: str, problem: str) -> None:
        problems.append(f"{source}: {key}: {problem}")

    for key in spec:
        if key not in ROS_KEYS:
            name = key if isinstance(key, str) and key.isprintable() and len(key) <= 40 else _short(key, 40)
            bad(name, f"unknown key{did_you_mean(key, ROS_KEYS)}; a ROS map has {', '.join(ROS_KEYS)}")
    for key in ("image", "resolution", "origin"):
        if key not in spec:
            bad(key, "missing")

    image = None
    if "image" in spec:
        value = spec["image"]
        if not isinstance(value, str) or not value.strip():
            bad("image", f"expected the image's path, got {_kind(value)}")
        else:
            image = Path(folder) / value
            if not os.path.exists(image):
                bad("image", f"no such file {image}")
                image = None

    resolution = None
    if "resolution" in spec:
        resolution = _ros_number(spec["resolution"])
        if resolution is None or resolution <= 0:
            bad("resolution", f"expected a positive finite number [units per cell], got {_kind(spec['resolution'])}")
            resolution = None

    origin = None
    if "origin" in spec:
        value = spec["origin"]
        if not isinstance(value, list) or len(value) not in (2, 3):
            bad("origin", f"expected [x, y, yaw], got {_kind(value)}")
        else:
            numbers_ = [_ros_number(v) for v in value]
            for i, (raw, number) in enumerate(zip(value, numbers_)):
                if number is None:
                    bad(f"origin[{i}]", f"expected a finite number, got {_kind(raw)}")
            if len(value) == 3 and numbers_[2] is not None and numbers_[2] != 0:
                bad("origin[2]", f"a rotated map (yaw {numbers_[2]:g}) is not supported; rotate the image instead")
            if all(n is not None for n in numbers_[:2]):
                origin = (numbers_[0], numbers_[1])

    negate = spec.get("negate", 0)
    if isinstance(negate, bool):
        negate = int(negate)
    if negate not in (0, 1) or not isinstance(negate, int):
        bad("negate", f"expected 0 or 1, got {_kind(spec['negate'])}")
        negate = 0

    thresholds = {}
    for key, default in (("occupied_thresh", 0.65), ("free_thresh", 0.196)):
        number = _ros_number(spec.get(key, default))
        if number is None or not 0 <= number <= 1:
            bad(key, f"expected a number from 0 to 1, got {_kind(spec[key])}")
        else:
            thresholds[key] = number
    if len(thresholds) == 2 and not thresholds["free_thresh"] < thresholds["occupied_thresh"]:
        bad("free_thresh", f"must be below occupied_thresh ({thresholds['occupied_thresh']:g}), "
                           f"got {thresholds['free_thresh']:g}")

    mode = spec.get("mode", "trinary")
    if mode not in ROS_MODES:
        bad("mode", f"expected one of {', '.join(ROS_MODES)}, got {_kind(mode)}{did_you_mean(mode, ROS_MODES)}")

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

def _lines(data: bytes) -> list[bytes]:
    """The file's lines, without line ends (``\\n`` or ``\\r\\n``)."""
    return [line[:-1] if line.endswith(b"\r") else line for line in data.split(b"\n")]


def _text(line: bytes, limit: int = 60) -> str:
    return _short(line.decode("utf-8", errors="replace"), limit)


def read_movingai_map(path: str | Path, cell: float = 1.0) -> OccupancyMap:
    """A MovingAI grid map (``.map``): ``type octile``, ``height H``, ``width W``, ``map``, then H rows of W characters.

    ``.``, ``G`` and ``S`` are free; everything else (``@``, ``O``, ``T``, ``W`` or any other
    character) is occupied. The first row is the top of the map, so it becomes row ``H - 1``.
    The map's lower-left corner is at the origin; a cell is ``cell`` world units wide.
    The ``type`` line is optional and its value not checked (every type is the same grid).
    """
    source = str(path)
    if isinstance(cell, bool) or not isinstance(cell, numbers.Real) or not (math.isfinite(cell) and cell > 0):
        raise WorldError(f"{source}: the cell size must be a positive finite number, got {_short(cell)}")
    lines = _lines(read_regular_file(path, "MovingAI map", WorldError, limit=MAX_MAP_FILE_BYTES))

    header: dict[str, int] = {}
    start = None
    for number, line in enumerate(lines, 1):
        words = line.split()
        if not words:
            continue
        key = words[0].lower()
        if key == b"map" and len(words) == 1:
            start = number   # the rows follow this line
            break
        if key not in (b"type", b"height", b"width") or len(words) != 2:
            raise WorldError(f"{source}: line {number}: expected 'type octile', 'height H', 'width W' or 'map', "
                             f"got {_text(line)}")
        name = key.decode()
        if name in header:
            raise WorldError(f"{source}: line {number}: a second '{name}' line")
        if name == "type":
            header[name] = 0
            continue
        if not words[1].isdigit() or len(words[1]) > 9 or int(words[1]) == 0:
            raise WorldError(f"{source}: line {number}: {name}: expected a positive whole number, got {_text(words[1])}")
        header[name] = int(words[1])
    if start is None:
        raise WorldError(f"{source}: line {len(lines)}: no 'map' line (the header ends with 'map', then the rows)")
    missing = [name for name in ("height", "width") if name not in header]
    if missing:
        raise WorldError(f"{source}: line {start}: the header has no {' or '.join(missing)} line")
    height, width = header["height"], header["width"]
    _check_cells(source, height, width, "MovingAI map")

    rows = lines[start:start + height]
    for index, row in enumerate(rows):
        number = start + 1 + index
        if len(row) != width:
            if not any(rest.strip() for rest in lines[number - 1:]):
                raise WorldError(f"{source}: line {number}: the map ends after {index} rows, expected height {height}")
            raise WorldError(f"{source}: line {number}: a row of {len(row)} characters, expected width {width}")
    if len(rows) < height:
        raise WorldError(f"{source}: line {len(lines)}: the map ends after {len(rows)} rows, expected height {height}")
    for extra, line in enumerate(lines[start + height:], start + height + 1):
        if line.strip():
            raise WorldError(f"{source}: line {extra}: more rows than the height {height}: {_text(line)}")

    grid = np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(height, width)
    free = np.isin(grid, np.frombuffer(MOVINGAI_FREE, dtype=np.uint8))
    return OccupancyMap(occupied=np.ascontiguousarray(np.flipud(~free)), cell=float(cell), origin=(0.0, 0.0),
                        source=source)


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


def _scen_line(fields_: list[str], source: str, number: int) -> Scenario:
    where = f"{source}: line {number}"
    if len(fields_) != len(_SCEN_FIELDS):
        raise WorldError(f"{where}: expected {len(_SCEN_FIELDS)} fields ({' '.join(_SCEN_FIELDS)}), got {len(fields_)}")
    values: dict[str, Any] = {}
    for name, text in zip(_SCEN_FIELDS, fields_):
        if name == "map":
            values[name] = text
        elif name == "optimal_length":
            try:
                values[name] = float(text)
            except ValueError:
                values[name] = None
            if values[name] is None or not math.isfinite(values[name]) or values[name] < 0:
                raise WorldError(f"{where}: {name}: expected a non-negative number, got {_short(text)}")
        else:
            if not text.isdigit() or len(text) > 9:
                raise WorldError(f"{where}: {name}: expected a whole number, got {_short(text)}")
            values[name] = int(text)
    width, height = values["width"], values["height"]
    if width == 0 or height == 0:
        raise WorldError(f"{where}: the map is empty ({width} x {height} cells)")
    for name, limit in (("start_x", width), ("goal_x", width), ("start_y", height), ("goal_y", height)):
        if values[name] >= limit:
            raise WorldError(f"{where}: {name}: {values[name]} is outside the {width} x {height} map")
    return Scenario(bucket=values["bucket"], map_name=values["map"], width=width, height=height,
                    start=(values["start_x"], values["start_y"]), goal=(values["goal_x"], values["goal_y"]),
                    optimal=values["optimal_length"], source=source, line=number)


def read_movingai_scen(path: str | Path) -> list[Scenario]:
    """The scenarios of a MovingAI scenario file (``.scen``, ``version 1``).

    After the ``version 1`` line, one scenario a line, tab- (or space-) separated: bucket, map,
    width, height, start x, start y, goal x, goal y, optimal length. Blank lines are skipped.
    """
    source = str(path)
    data = read_regular_file(path, "MovingAI scenario", WorldError, limit=MAX_SCEN_FILE_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise WorldError(f"{source}: line {line}: not UTF-8 text") from None
    scenarios, version = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        if not version:
            if line.split() not in (["version", "1"], ["version", "1.0"]):
                raise WorldError(f"{source}: line {number}: expected 'version 1', got {_short(line)}")
            version = True
            continue
        fields_ = [f.strip() for f in line.strip().split("\t")] if "\t" in line else line.split()
        scenarios.append(_scen_line(fields_, source, number))
    if not version:
        raise WorldError(f"{source}: line 1: empty; expected 'version 1'")
    return scenarios


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
