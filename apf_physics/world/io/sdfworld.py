"""Static obstacles from a Gazebo SDF world: the footprints of its box, cylinder and sphere collisions.

A world file's ``sdf: {file: NAME.world}`` (README "World files") takes its obstacles from a
Gazebo world. :func:`read_sdf_obstacles` reads the file and returns, for every ``<collision>``
of every static model (nested models included) whose shape reaches into a band of heights
above the ground, its footprint on the ground plane:

- a sphere, or a cylinder standing upright: a circle;
- a box, or a cylinder that is tilted: the convex polygon its outline casts on the ground (a
  tilted cylinder's outline is taken from 32 points per end, pushed out to contain the circle).

Poses compose as SDF says (model ∘ link ∘ collision, roll-pitch-yaw ``Rz·Ry·Rx``; ``degrees``
and ``quat_xyzw`` poses read too); a saved world's ``<state>`` gives the pose of each
top-level model it lists, as Gazebo restores it. Planes (the ground) are not obstacles; models
that are not static (robots, things that move) are left out; ``<include>`` of
``model://ground_plane`` and ``model://sun`` is ignored. Anything else the file holds that
cannot be read as a footprint (a mesh, another ``<include>``, a pose relative to another
frame) is a problem, named by its model; such models can be left out by name (``skip``).

The file is read as hostile input: a regular file of at most :data:`MAX_SDF_BYTES`
(:mod:`apf_physics.common.safefile`), UTF-8 only, no document type declaration (so no entities: no
"billion laughs", no external entities), at most :data:`MAX_ELEMENTS` elements nested at most
:data:`MAX_DEPTH` deep, counted while it is parsed. Every problem is a
:class:`~apf_physics.errors.WorldError` naming the file: ``<file>: <where>: <what is wrong>``.
"""

from __future__ import annotations

import fnmatch
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from apf_physics.errors import WorldError
from apf_physics.common.safefile import read_regular_file

MAX_SDF_BYTES = 32 * 2**20
"""Largest SDF world file [bytes] (a BARN world is 0.45 MB)."""
MAX_ELEMENTS = 2_000_000
"""Most XML elements in one file (a BARN world has about 25,000)."""
MAX_DEPTH = 64
"""Deepest nesting of XML elements (models nest models; a real world is under 15 deep)."""
MAX_SHAPES = 10_000
"""Most footprints one file may give (the world file's limit on obstacles)."""
DEFAULT_HEIGHTS = (0.05, 2.0)
"""Band of heights [m] a collision must reach into to be an obstacle: above a floor slab, below a ceiling."""
IGNORED_INCLUDES = ("model://ground_plane", "model://sun")
"""Included models that are never obstacles."""
TILTED_SAMPLES = 32
"""Points per end of a tilted cylinder's outline."""
_UPRIGHT = 1e-6
"""A cylinder whose axis leans less than this [rad-ish: 1 − cos] is upright (a circle)."""


@dataclass(frozen=True)
class Footprint:
    """One collision's outline on the ground plane, in the SDF world's coordinates.

    Attributes:
        name: ``model::link::collision`` (nested models joined the same way).
        center: A circle's centre (None for a polygon).
        radius: A circle's radius (None for a polygon).
        vertices: A polygon's (K, 2) vertices, counter-clockwise (None for a circle).
    """

    name: str
    center: tuple[float, float] | None = None
    radius: float | None = None
    vertices: np.ndarray | None = None


class _Problems:
    """Problems found in one file, each ``<file>: <where>: <what>``; raised together."""

    LISTED = 20

    def __init__(self, source: str):
        self.source, self.lines, self.count = source, [], 0

    def add(self, where: str, what: str) -> None:
        self.count += 1
        if len(self.lines) < self.LISTED:
            self.lines.append(f"{self.source}: {where}: {what}" if where else f"{self.source}: {what}")

    def raise_any(self) -> None:
        if self.count:
            more = self.count - len(self.lines)
            tail = [f"{self.source}: and {more:,} more problem{'s' if more > 1 else ''}"] if more else []
            raise WorldError("\n".join(self.lines + tail))


# -- reading the XML within limits --------------------------------------------------------------
_DECLARATION = re.compile(r"^\s*<\?xml[^>]*?encoding\s*=\s*[\"']([^\"']+)[\"']")


def parse_xml(data: bytes, source: str) -> ET.Element:
    """The root element of an SDF file's bytes, read within the limits (module docstring).

    Raises:
        WorldError: naming ``source``: not UTF-8, a document type declaration or an entity, too
            many or too deeply nested elements, or not well-formed XML (with its line).
    """
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise WorldError(f"{source}: the SDF file is UTF-16; save it as UTF-8")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise WorldError(f"{source}: the SDF file is not UTF-8 text (byte {exc.start})") from None
    declared = _DECLARATION.match(text)
    if declared and declared.group(1).strip().lower().replace("_", "-") not in ("utf-8", "utf8", "us-ascii", "ascii"):
        raise WorldError(f"{source}: the SDF file declares encoding {declared.group(1)!r}; only UTF-8 is read")
    for marker in ("<!DOCTYPE", "<!ENTITY"):
        if marker in text:
            line = text.count("\n", 0, text.index(marker)) + 1
            raise WorldError(f"{source}: line {line}: {marker[2:]} declarations are refused (an SDF world needs none, "
                             "and entities can expand without bound)")
    parser = ET.XMLPullParser(events=("start", "end"))
    depth = elements = 0
    root = None
    try:
        for start in range(0, len(text), 1 << 16):
            parser.feed(text[start:start + (1 << 16)])
            for event, element in parser.read_events():
                if event == "end":
                    depth -= 1
                    continue
                root = element if root is None else root
                depth += 1
                elements += 1
                if depth > MAX_DEPTH:
                    raise WorldError(f"{source}: elements nested more than {MAX_DEPTH} deep (at <{element.tag}>)")
                if elements > MAX_ELEMENTS:
                    raise WorldError(f"{source}: more than {MAX_ELEMENTS:,} XML elements")
        parser.close()
    except ET.ParseError as exc:
        raise WorldError(f"{source}: not well-formed XML: {exc}") from None
    if root is None:
        raise WorldError(f"{source}: no XML elements")
    return root


# -- poses --------------------------------------------------------------------------------------
def _rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """SDF's roll-pitch-yaw: ``Rz(yaw)·Ry(pitch)·Rx(roll)``."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _quaternion(x: float, y: float, z: float, w: float) -> np.ndarray:
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0:
        raise ValueError("a quaternion of length 0")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _numbers(text: str | None, count: Sequence[int], what: str) -> list[float]:
    values = (text or "").split()
    if len(values) not in count:
        raise ValueError(f"{what}: expected {' or '.join(map(str, count))} numbers, got {len(values)}")
    try:
        out = [float(v) for v in values]
    except ValueError:
        raise ValueError(f"{what}: not a number in {' '.join(values)[:60]!r}") from None
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what}: numbers must be finite")
    return out


def _pose(element: ET.Element | None, *frames: str) -> np.ndarray:
    """The 4×4 transform of an element's ``<pose>`` (identity without one), relative to its parent.

    Raises:
        ValueError: A pose that is not 6 numbers (or 7 with ``quat_xyzw``), or that is given
            relative to another frame than the parent (``relative_to``, or SDF 1.4-1.6 ``frame``).
    """
    pose = np.eye(4)
    node = None if element is None else element.find("pose")
    if node is None:
        return pose
    frame = node.get("relative_to", node.get("frame", ""))
    if frame not in ("", *frames):
        raise ValueError(f"pose relative to {frame!r}: only poses relative to the parent are read")
    if node.get("rotation_format", "euler_rpy") == "quat_xyzw":
        x, y, z, *q = _numbers(node.text, (7,), "pose")
        pose[:3, :3] = _quaternion(*q)
    else:
        if node.get("rotation_format", "euler_rpy") != "euler_rpy":
            raise ValueError(f"pose rotation_format {node.get('rotation_format')!r} (known: euler_rpy, quat_xyzw)")
        x, y, z, roll, pitch, yaw = _numbers(node.text, (6,), "pose")
        if node.get("degrees", "false").strip().lower() in ("true", "1"):
            roll, pitch, yaw = (math.radians(a) for a in (roll, pitch, yaw))
        pose[:3, :3] = _rotation(roll, pitch, yaw)
    pose[:3, 3] = (x, y, z)
    return pose


# -- footprints -----------------------------------------------------------------------------------
def convex_hull(points: np.ndarray) -> np.ndarray:
    """(K, 2) the convex hull of ``points``, counter-clockwise (Andrew's monotone chain)."""
    pts = np.unique(np.round(np.asarray(points, float), 12), axis=0)
    if len(pts) < 3:
        return pts

    def half(seq: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 1e-15:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _footprint(geometry: ET.Element, pose: np.ndarray, scale: np.ndarray, name: str,
               heights: tuple[float, float]) -> Footprint | None | str:
    """The footprint of one ``<geometry>`` at ``pose``, None when it is not an obstacle (a plane, or
    outside the band of heights), or a string saying why it cannot be read."""
    shapes = [child for child in geometry if isinstance(child.tag, str)]
    if len(shapes) != 1:
        return f"expected one shape in <geometry>, got {len(shapes)}"
    shape = shapes[0]
    kind = shape.tag
    rotation, centre = pose[:3, :3], pose[:3, 3]
    if kind == "plane":
        return None
    try:
        if kind == "box":
            size = np.array(_numbers(shape.findtext("size"), (3,), "box size")) * scale
            if not (size > 0).all():
                return "box size must be positive"
            corners = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)]) * size
            points = corners @ rotation.T + centre
            low, high = points[:, 2].min(), points[:, 2].max()
            if high < heights[0] or low > heights[1]:
                return None
            return Footprint(name, vertices=convex_hull(points[:, :2]))
        if kind in ("cylinder", "sphere"):
            (radius,) = _numbers(shape.findtext("radius"), (1,), f"{kind} radius")
            if not radius > 0:
                return f"{kind} radius must be positive"
            if kind == "sphere":
                if not np.allclose(scale, scale[0]):
                    return "a sphere scaled unevenly (an ellipsoid) is not read"
                radius *= scale[0]
                if centre[2] + radius < heights[0] or centre[2] - radius > heights[1]:
                    return None
                return Footprint(name, center=(float(centre[0]), float(centre[1])), radius=float(radius))
            (length,) = _numbers(shape.findtext("length"), (1,), "cylinder length")
            if not length > 0:
                return "cylinder length must be positive"
            if not math.isclose(scale[0], scale[1]):
                return "a cylinder scaled unevenly across its axis is not read"
            radius, length = radius * scale[0], length * scale[2]
            axis = rotation[:, 2]
            ends = centre + np.outer((-0.5, 0.5), axis) * length
            spread = radius * math.sqrt(max(0.0, 1.0 - axis[2] ** 2))   # how far the rims reach up and down
            if ends[:, 2].max() + spread < heights[0] or ends[:, 2].min() - spread > heights[1]:
                return None
            if 1.0 - abs(axis[2]) < _UPRIGHT:
                return Footprint(name, center=(float(centre[0]), float(centre[1])), radius=float(radius))
            angles = np.linspace(0.0, 2 * math.pi, TILTED_SAMPLES, endpoint=False)
            rim = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
            rim *= radius / math.cos(math.pi / TILTED_SAMPLES)    # the polygon contains the circle
            points = np.vstack([rim @ rotation.T + end for end in ends])
            return Footprint(name, vertices=convex_hull(points[:, :2]))
    except ValueError as exc:
        return str(exc)
    return f"<{kind}> geometry is not read (boxes, cylinders and spheres are; skip the model, or draw it as obstacles)"


def _scale(text: str | None) -> np.ndarray:
    if text is None:
        return np.ones(3)
    values = np.array(_numbers(text, (3,), "scale"))
    if not (values > 0).all():
        raise ValueError("scale must be positive")
    return values


def _is_static(model: ET.Element, inherited: bool) -> bool:
    text = model.findtext("static")
    return inherited or (text is not None and text.strip().lower() in ("1", "true"))


def _models(parent: ET.Element, transform: np.ndarray, prefix: str, static: bool, states: dict,
            problems: _Problems, skip: Sequence[str]) -> Iterator[tuple[str, ET.Element, np.ndarray, bool, np.ndarray]]:
    """Every model under ``parent`` (nested ones too): ``(name, element, world transform, static, scale)``."""
    for model in parent.findall("model"):
        name = prefix + model.get("name", "?")
        if any(fnmatch.fnmatchcase(name, pattern) or fnmatch.fnmatchcase(model.get("name", ""), pattern)
               for pattern in skip):
            continue
        try:
            if not prefix and name in states:       # a saved world's state: where the model is now
                local, scale = states[name]
            else:
                local = _pose(model, parent.get("name", ""), "world" if not prefix else "__model__")
                scale = np.ones(3)
        except ValueError as exc:
            problems.add(f"model {name!r}", str(exc))
            continue
        here = transform @ local
        is_static = _is_static(model, static)
        yield name, model, here, is_static, scale
        yield from _models(model, here, name + "::", is_static, states, problems, skip)
        for include in model.findall("include"):
            _include(include, name, problems, skip)


def _include(include: ET.Element, where: str, problems: _Problems, skip: Sequence[str]) -> None:
    uri = (include.findtext("uri") or "").strip()
    name = (include.findtext("name") or uri.rsplit("/", 1)[-1]).strip()
    if uri in IGNORED_INCLUDES or any(fnmatch.fnmatchcase(name, p) for p in skip):
        return
    problems.add(f"{where}include {uri!r}".strip(),
                 f"included models are not read (no Gazebo model path here): add {name!r} to sdf.skip, or write "
                 "the model into the world")


def _states(world: ET.Element, problems: _Problems) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Top-level model poses (and scales) from the world's ``<state>`` elements (the last one wins)."""
    out = {}
    for state in world.findall("state"):
        for model in state.findall("model"):
            name = model.get("name", "?")
            try:
                out[name] = (_pose(model, "world"), _scale(model.findtext("scale")))
            except ValueError as exc:
                problems.add(f"state model {name!r}", str(exc))
    return out


def sdf_footprints(root: ET.Element, source: str, skip: Sequence[str] = (),
                   heights: tuple[float, float] = DEFAULT_HEIGHTS) -> list[Footprint]:
    """The footprints of the static collisions of an SDF document (see the module docstring).

    Args:
        root: The ``<sdf>`` element (or a ``<world>``).
        source: The file, for messages.
        skip: Model names (glob patterns, ``*`` and ``?``) to leave out, nested names included
            (``outer::inner``).
        heights: ``(low, high)``: a collision is an obstacle if it reaches into this band.

    Raises:
        WorldError: Every problem found, one line each, naming the model.
    """
    problems = _Problems(source)
    worlds = [root] if root.tag == "world" else root.findall("world")
    if root.tag not in ("sdf", "world"):
        raise WorldError(f"{source}: not an SDF world (its root element is <{root.tag}>, not <sdf>)")
    if len(worlds) != 1:
        raise WorldError(f"{source}: expected one <world> in the SDF file, got {len(worlds)}")
    world = worlds[0]
    states = _states(world, problems)
    out: list[Footprint] = []
    for include in world.findall("include"):
        _include(include, "", problems, skip)
    for name, model, transform, static, scale in _models(world, np.eye(4), "", False, states, problems, skip):
        if not static:
            continue
        for link in model.findall("link"):
            link_name = f"{name}::{link.get('name', '?')}"
            try:
                at_link = transform @ _pose(link, model.get("name", ""), "__model__")
            except ValueError as exc:
                problems.add(f"link {link_name!r}", str(exc))
                continue
            for collision in link.findall("collision"):
                where = f"{link_name}::{collision.get('name', '?')}"
                geometry = collision.find("geometry")
                if geometry is None:
                    problems.add(f"collision {where!r}", "no <geometry>")
                    continue
                try:
                    pose = at_link @ _pose(collision, link.get("name", ""))
                except ValueError as exc:
                    problems.add(f"collision {where!r}", str(exc))
                    continue
                shape = _footprint(geometry, pose, scale, where, heights)
                if isinstance(shape, str):
                    problems.add(f"collision {where!r}", shape)
                elif shape is not None:
                    out.append(shape)
                    if len(out) > MAX_SHAPES:
                        raise WorldError(f"{source}: more than {MAX_SHAPES:,} obstacles (the world file's limit)")
    problems.raise_any()
    return out


def read_sdf_obstacles(path: str | Path, skip: Sequence[str] = (),
                       heights: tuple[float, float] = DEFAULT_HEIGHTS) -> list[Footprint]:
    """The footprints of the static collisions of the SDF world file ``path`` (:func:`sdf_footprints`).

    Raises:
        WorldError: The file is missing, not a regular file, too large, not a readable SDF
            world, or holds collisions that cannot be read (every one named).
    """
    data = read_regular_file(path, "SDF world", WorldError, MAX_SDF_BYTES)
    return sdf_footprints(parse_xml(data, str(path)), str(path), skip, heights)
