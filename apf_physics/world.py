"""Worlds: the rectangular map, its obstacles, targets and starts, and the field's parameters.

A world is read from a YAML file (JSON is accepted, being YAML) and validated against the
world-file contract documented in the README. Every problem is reported as one
:class:`~apf_physics.errors.WorldError` naming the file, the key and what is wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping, Sequence, Union

import numpy as np
import yaml

from apf_physics import field as apf
from apf_physics import geometry
from apf_physics.errors import UserError, WorldError

FIELD_PRESETS: dict[str, dict[str, float]] = {
    # SPEC §1, thesis Tables 2–4. u_max is the cap used in place of infinity (thesis Fig. 11).
    "thesis-demo": {"katt": 1, "krep": 20, "kstr": 8, "p0": 3, "ps": 8, "u_max": 100},
    "thesis-fixed": {"katt": 2, "krep": 20, "kstr": 8, "p0": 0.5, "ps": 8, "u_max": 100},
    "thesis-general": {"katt": 1, "krep": 20, "kstr": 8, "p0": 3, "ps": 8, "u_max": 100},
}


@dataclass(frozen=True)
class FieldParams:
    """Parameters of the artificial potential field (SPEC §1)."""

    katt: float   # attraction gain
    krep: float   # repulsion gain
    kstr: float   # black-hole strength
    p0: float     # repulsion range [world units]
    ps: float     # black-hole range [world units]
    u_max: float  # cap of each repulsive term, also its value inside an obstacle

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, eq=False)
class PolygonObstacle:
    """A simple polygon, stored counter-clockwise; concave allowed."""

    vertices: np.ndarray  # (M, 2)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return geometry.polygon_signed_distance(points, self.vertices)

    def to_dict(self) -> dict[str, Any]:
        return {"polygon": self.vertices.tolist()}


@dataclass(frozen=True, eq=False)
class CircleObstacle:
    """A disc; radius 0 is the thesis's point obstacle."""

    center: np.ndarray  # (2,)
    radius: float

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.center - self.radius, self.center + self.radius

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return geometry.circle_signed_distance(points, self.center, self.radius)

    def to_dict(self) -> dict[str, Any]:
        return {"circle": {"center": self.center.tolist(), "radius": self.radius}}


Obstacle = Union[PolygonObstacle, CircleObstacle]


@dataclass(frozen=True)
class FormationSpec:
    """A leader and followers in a chain (SPEC §3).

    Attributes:
        followers: Number of followers.
        comm_range: Communication range: each follower must stay this close to the robot it follows [units].
        spacing: Preferred distance between consecutive robots [units].
        shape: ``"line"`` (each follows the previous robot), ``"wedge"``, or ``"offsets"``.
        offsets: For ``shape: offsets``: per follower ``[back, left]`` relative to the leader's heading.
    """

    followers: int = 2
    comm_range: float = 3.0
    spacing: float = 1.0
    shape: str = "line"
    offsets: tuple[tuple[float, float], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"followers": self.followers, "comm_range": self.comm_range,
                                "spacing": self.spacing, "shape": self.shape}
        if self.offsets:
            data["offsets"] = [list(o) for o in self.offsets]
        return data


@dataclass(frozen=True, eq=False)
class World:
    """A validated world. Build it with :func:`load_world` or :func:`world_from_dict`.

    Attributes:
        name: Short name, used in tables and file names.
        size: ``(width, height)``; the origin is the lower-left corner, y up.
        robot_radius: Radius of each robot's disc.
        goal_tolerance: A target is reached when the robot's centre is this close to it.
        field: The potential field's parameters.
        obstacles: Static obstacles.
        targets: ``(T, 2)`` target positions (at least one).
        starts: ``(S, 2)`` evaluation start positions (may be empty).
        formation: The formation, if the world file defines one.
        source: The file the world came from, for messages.
    """

    name: str
    size: tuple[float, float]
    robot_radius: float
    goal_tolerance: float
    field: FieldParams
    obstacles: tuple[Obstacle, ...]
    targets: np.ndarray
    starts: np.ndarray
    formation: FormationSpec | None = None
    source: str | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    # -- the field ---------------------------------------------------------------------
    def potential(self, points: np.ndarray) -> np.ndarray:
        """Total potential U at ``(N, 2)`` points (SPEC §1)."""
        return apf.potential(points, self.targets, self.obstacles, self.field)

    def gradient(self, points: np.ndarray) -> np.ndarray:
        """``∇U`` at ``(N, 2)`` points."""
        return apf.gradient(points, self.targets, self.obstacles, self.field)

    def raster(self, resolution: int = 4) -> apf.Raster:
        """U at the nodes of a grid over the map, ``resolution`` nodes per unit; built once and cached."""
        key = ("potential", int(resolution))
        if key not in self._cache:
            grid = apf.Grid.covering((0.0, 0.0), self.size, resolution)
            values = self.potential(grid.node_points()).reshape(grid.shape)
            self._cache[key] = apf.Raster(grid, values)
        return self._cache[key]

    @property
    def u_wall(self) -> float:
        """The value impassable points (inside obstacles, outside the map) read in observations.

        The highest potential anywhere on the map (at the raster's resolution 4), and at
        least ``u_max`` above the lowest, so that blocked points always read as a maximum.
        """
        if "u_wall" not in self._cache:
            values = self.raster(4).values
            self._cache["u_wall"] = float(max(values.max(), values.min() + self.field.u_max))
        return self._cache["u_wall"]

    # -- geometry ----------------------------------------------------------------------
    def obstacle_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance to the nearest obstacle's boundary (negative inside); +inf without obstacles."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        best = np.full(len(points), np.inf)
        for obstacle in self.obstacles:
            d, _ = obstacle.signed_distance(points)
            best = np.minimum(best, d)
        return best

    def edge_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance to the map's edge (negative outside)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        w, h = self.size
        return np.minimum.reduce([points[:, 0], w - points[:, 0], points[:, 1], h - points[:, 1]])

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point to the nearest obstacle or the map's edge (negative when blocked)."""
        return np.minimum(self.obstacle_distance(points), self.edge_distance(points))

    def is_free(self, points: np.ndarray, margin: float | None = None) -> np.ndarray:
        """True where a robot centred at the point keeps ``margin`` (default: its radius) from everything."""
        margin = self.robot_radius if margin is None else margin
        return self.clearance(points) >= margin

    def free_cells(self, margin: float | None = None, resolution: int = 4) -> np.ndarray:
        """Centres of the grid cells (side ``1/resolution``) in which every point is free.

        A cell qualifies when its centre's clearance exceeds ``margin`` plus half the cell's
        diagonal (clearance changes no faster than distance). Built once and cached.
        """
        margin = self.robot_radius if margin is None else margin
        key = ("free_cells", float(margin), int(resolution))
        if key not in self._cache:
            h = 1.0 / resolution
            xs = np.arange(h / 2, self.size[0], h)
            ys = np.arange(h / 2, self.size[1], h)
            centres = np.column_stack([a.ravel() for a in np.meshgrid(xs, ys)])
            self._cache[key] = centres[self.clearance(centres) > margin + h / np.sqrt(2)]
        return self._cache[key]

    def random_free_positions(self, rng: np.random.Generator, count: int, margin: float | None = None) -> np.ndarray:
        """``count`` positions where a robot fits, drawn uniformly over the free cells of :meth:`free_cells`."""
        cells = self.free_cells(margin)
        if not len(cells):
            raise WorldError(f"{self.source or self.name}: no free position for a robot of radius {self.robot_radius}")
        half = 0.5 / 4
        return cells[rng.integers(len(cells), size=count)] + rng.uniform(-half, half, size=(count, 2))

    # -- serialisation -----------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The world as the world-file contract's mapping (round-trips through :func:`world_from_dict`)."""
        data: dict[str, Any] = {
            "name": self.name,
            "size": list(self.size),
            "robot_radius": self.robot_radius,
            "goal_tolerance": self.goal_tolerance,
            "field": self.field.as_dict(),
            "obstacles": [o.to_dict() for o in self.obstacles],
            "targets": self.targets.tolist(),
            "starts": self.starts.tolist(),
        }
        if self.formation is not None:
            data["formation"] = self.formation.to_dict()
        return data


# ---------------------------------------------------------------------------------------
# Loading and validation
# ---------------------------------------------------------------------------------------

_TOP_KEYS = {"name", "size", "robot_radius", "goal_tolerance", "field", "obstacles", "targets", "starts", "formation"}
_REQUIRED = ("size", "field", "targets")


class _Checker:
    """Builds one clear message per problem: ``<file>: <key>: <what is wrong>``."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, problem: str) -> WorldError:
        return WorldError(f"{self.source}: {key}: {problem}" if key else f"{self.source}: {problem}")

    def number(self, value: Any, key: str, *, positive: bool = False, nonnegative: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"expected a number, got {type(value).__name__} {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise self.fail(key, f"must be finite, got {value}")
        if positive and value <= 0:
            raise self.fail(key, f"must be positive, got {value:g}")
        if nonnegative and value < 0:
            raise self.fail(key, f"must not be negative, got {value:g}")
        return value

    def point(self, value: Any, key: str) -> np.ndarray:
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise self.fail(key, f"expected a point [x, y], got {value!r}")
        return np.array([self.number(v, f"{key}[{i}]") for i, v in enumerate(value)])

    def points(self, value: Any, key: str, *, at_least: int = 0) -> np.ndarray:
        if not isinstance(value, (list, tuple)):
            raise self.fail(key, f"expected a list of points [[x, y], ...], got {type(value).__name__}")
        if len(value) < at_least:
            raise self.fail(key, f"needs at least {at_least} point{'s' if at_least > 1 else ''}, got {len(value)}")
        pts = [self.point(p, f"{key}[{i}]") for i, p in enumerate(value)]
        return np.array(pts, dtype=float).reshape(-1, 2)

    def mapping(self, value: Any, key: str, allowed: set[str], required: Sequence[str] = ()) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a mapping, got {type(value).__name__} {value!r}")
        unknown = sorted(set(map(str, value)) - allowed)
        if unknown:
            raise self.fail(f"{key}.{unknown[0]}" if key else unknown[0],
                            f"unknown key (allowed: {', '.join(sorted(allowed))})")
        for name in required:
            if name not in value:
                raise self.fail(f"{key}.{name}" if key else name, "missing")
        return value


def _parse_field(check: _Checker, value: Any) -> FieldParams:
    if isinstance(value, str):
        if value not in FIELD_PRESETS:
            raise check.fail("field", f"unknown preset {value!r} (known: {', '.join(FIELD_PRESETS)})")
        return FieldParams(**{k: float(v) for k, v in FIELD_PRESETS[value].items()})
    names = [f.name for f in fields(FieldParams)]
    raw = dict(check.mapping(value, "field", set(names) | {"preset"}))
    base: dict[str, float] = {}
    if "preset" in raw:
        preset = raw.pop("preset")
        if preset not in FIELD_PRESETS:
            raise check.fail("field.preset", f"unknown preset {preset!r} (known: {', '.join(FIELD_PRESETS)})")
        base = dict(FIELD_PRESETS[preset])
    base.update(raw)
    for name in names:
        if name not in base:
            raise check.fail(f"field.{name}", "missing")
    values = {}
    for name in names:
        positive = name in ("p0", "ps", "u_max")
        values[name] = check.number(base[name], f"field.{name}", positive=positive, nonnegative=not positive)
    return FieldParams(**values)


def _parse_obstacle(check: _Checker, value: Any, key: str, size: tuple[float, float]) -> Obstacle:
    body = check.mapping(value, key, {"polygon", "circle"})
    if len(body) != 1:
        raise check.fail(key, "each obstacle is exactly one of 'polygon: [[x, y], ...]' or 'circle: {center, radius}'")
    w, h = size
    if "polygon" in body:
        k = f"{key}.polygon"
        vertices = check.points(body["polygon"], k, at_least=3)
        if not geometry.polygon_is_simple(vertices):
            raise check.fail(k, "polygon crosses itself or repeats a vertex (it must be a simple polygon)")
        if abs(geometry.polygon_area(vertices)) < 1e-12:
            raise check.fail(k, "polygon has zero area (its vertices are collinear)")
        if vertices.min() < 0 or np.any(vertices[:, 0] > w) or np.any(vertices[:, 1] > h):
            raise check.fail(k, f"polygon reaches outside the map [0, {w:g}] x [0, {h:g}]")
        if geometry.polygon_area(vertices) < 0:
            vertices = vertices[::-1].copy()
        return PolygonObstacle(vertices)
    k = f"{key}.circle"
    circle = check.mapping(body["circle"], k, {"center", "radius"}, required=("center", "radius"))
    center = check.point(circle["center"], f"{k}.center")
    radius = check.number(circle["radius"], f"{k}.radius", nonnegative=True)
    if center[0] - radius < 0 or center[1] - radius < 0 or center[0] + radius > w or center[1] + radius > h:
        raise check.fail(k, f"circle reaches outside the map [0, {w:g}] x [0, {h:g}]")
    return CircleObstacle(center, radius)


def _parse_formation(check: _Checker, value: Any) -> FormationSpec:
    body = check.mapping(value, "formation", {"followers", "comm_range", "spacing", "shape", "offsets"})
    default = FormationSpec()
    followers = body.get("followers", default.followers)
    if isinstance(followers, bool) or not isinstance(followers, int) or followers < 0:
        raise check.fail("formation.followers", f"expected a whole number >= 0, got {followers!r}")
    comm_range = check.number(body.get("comm_range", default.comm_range), "formation.comm_range", positive=True)
    spacing = check.number(body.get("spacing", default.spacing), "formation.spacing", positive=True)
    if spacing > comm_range:
        raise check.fail("formation.spacing", f"spacing {spacing:g} exceeds comm_range {comm_range:g}")
    shape = body.get("shape", default.shape)
    if shape not in ("line", "wedge", "offsets"):
        raise check.fail("formation.shape", f"expected 'line', 'wedge' or 'offsets', got {shape!r}")
    offsets: tuple[tuple[float, float], ...] = ()
    if shape == "offsets":
        if "offsets" not in body:
            raise check.fail("formation.offsets", "missing (required when shape is 'offsets')")
        pts = check.points(body["offsets"], "formation.offsets", at_least=1)
        if len(pts) != followers:
            raise check.fail("formation.offsets", f"{len(pts)} offsets for {followers} followers")
        offsets = tuple((float(a), float(b)) for a, b in pts)
    elif "offsets" in body:
        raise check.fail("formation.offsets", "only allowed when shape is 'offsets'")
    return FormationSpec(followers, comm_range, spacing, shape, offsets)


def world_from_dict(data: Any, source: str = "<dict>") -> World:
    """Validate a world-file mapping and build the :class:`World`.

    Raises:
        WorldError: naming ``source``, the key and what is wrong.
    """
    check = _Checker(source)
    if not isinstance(data, Mapping):
        raise check.fail("", f"a world file must be a mapping of keys, got {type(data).__name__}")
    check.mapping(data, "", _TOP_KEYS, required=_REQUIRED)

    size_raw = data["size"]
    if not isinstance(size_raw, (list, tuple)) or len(size_raw) != 2:
        raise check.fail("size", f"expected [width, height], got {size_raw!r}")
    size = (check.number(size_raw[0], "size[0]", positive=True), check.number(size_raw[1], "size[1]", positive=True))

    name = data.get("name", Path(source).stem if source != "<dict>" else "world")
    if not isinstance(name, str) or not name:
        raise check.fail("name", f"expected a non-empty string, got {name!r}")
    robot_radius = check.number(data.get("robot_radius", 0.25), "robot_radius", positive=True)
    goal_tolerance = check.number(data.get("goal_tolerance", 0.75), "goal_tolerance", positive=True)
    params = _parse_field(check, data["field"])

    raw_obstacles = data.get("obstacles", [])
    if raw_obstacles is None:
        raw_obstacles = []
    if not isinstance(raw_obstacles, list):
        raise check.fail("obstacles", f"expected a list, got {type(raw_obstacles).__name__}")
    obstacles = tuple(_parse_obstacle(check, o, f"obstacles[{i}]", size) for i, o in enumerate(raw_obstacles))

    targets = check.points(data["targets"], "targets", at_least=1)
    starts = check.points(data.get("starts", []) or [], "starts")
    formation = _parse_formation(check, data["formation"]) if data.get("formation") is not None else None

    world = World(name, size, robot_radius, goal_tolerance, params, obstacles, targets, starts, formation, source)

    for key, pts, margin in (("targets", targets, 0.0), ("starts", starts, robot_radius)):
        if not len(pts):
            continue
        edge = world.edge_distance(pts)
        inside = world.obstacle_distance(pts)
        for i in range(len(pts)):
            where = f"{key}[{i}]"
            if edge[i] < margin:
                if edge[i] < 0:
                    raise check.fail(where, f"{pts[i].tolist()} is outside the map [0, {size[0]:g}] x [0, {size[1]:g}]")
                raise check.fail(where, f"{pts[i].tolist()} is closer than the robot radius {robot_radius:g} to the map's edge")
            if inside[i] <= 0:
                raise check.fail(where, f"{pts[i].tolist()} is inside an obstacle")
            if inside[i] < margin:
                raise check.fail(where, f"{pts[i].tolist()} is closer than the robot radius {robot_radius:g} to an obstacle")
    return world


def read_yaml_file(path: str | Path, kind: str, error: type[UserError] = UserError) -> Any:
    """Read a YAML file, turning every failure into one ``error`` naming the file.

    Args:
        path: The file.
        kind: What the file is, for messages (``"world"``, ``"curriculum"``).
        error: The exception class to raise.
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{source}: no such {kind} file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{source}: cannot read the {kind} file ({exc})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise error(f"{source}: not valid YAML{where}: {getattr(exc, 'problem', exc)}") from None


def load_world(path: str | Path) -> World:
    """Read and validate a world file (YAML, or JSON being YAML).

    Raises:
        WorldError: the file is missing, unreadable, not YAML, or breaks the contract.
    """
    return world_from_dict(read_yaml_file(path, "world", WorldError), str(path))


class _WorldDumper(yaml.SafeDumper):
    """Writes points and small mappings inline (``[x, y]``), everything else as blocks."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(v, (int, float)) for v in data) or all(
        isinstance(v, list) and all(isinstance(x, (int, float)) for x in v) for v in data) and len(data) <= 8
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


def _represent_dict(dumper: yaml.SafeDumper, data: dict) -> yaml.Node:
    flow = all(isinstance(v, (int, float, str)) for v in data.values())
    return dumper.represent_mapping("tag:yaml.org,2002:map", data.items(), flow_style=flow)


def _tidy(value: Any) -> Any:
    """Integral floats as ints, so world files read as people write them."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, float):
        return round(value, 6)
    if isinstance(value, list):
        return [_tidy(v) for v in value]
    if isinstance(value, dict):
        return {k: _tidy(v) for k, v in value.items()}
    return value


_WorldDumper.add_representer(list, _represent_list)
_WorldDumper.add_representer(dict, _represent_dict)


def dump_world_yaml(world: World) -> str:
    """The world as YAML text in the world-file contract."""
    return yaml.dump(_tidy(world.to_dict()), Dumper=_WorldDumper, sort_keys=False, width=120)


def save_world(world: World, path: str | Path) -> None:
    """Write a world file that :func:`load_world` reads back to the same world."""
    path = Path(path)
    try:
        path.write_text(dump_world_yaml(world), encoding="utf-8")
    except OSError as exc:
        raise UserError(f"{path}: cannot write the world file ({exc.strerror})") from None


def load_worlds(paths: Sequence[str | Path]) -> list[World]:
    """Load several world files; a directory stands for every ``*.yaml`` in it, sorted."""
    out: list[World] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            files = sorted(p.glob("*.yaml")) + sorted(p.glob("*.yml"))
            if not files:
                raise WorldError(f"{p}: directory holds no .yaml world files")
            out.extend(load_world(f) for f in files)
        else:
            out.append(load_world(p))
    return out
