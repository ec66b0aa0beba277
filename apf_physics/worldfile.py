"""World files: reading, validating and writing the YAML world-file contract (README "World files").

:func:`load_world` reads a file (YAML, or JSON being YAML) and :func:`world_from_dict`
validates a mapping and builds the :class:`~apf_physics.world.World`. Every problem is
reported as one :class:`~apf_physics.errors.WorldError` naming the file, the key and what is
wrong. :func:`save_world` writes a file that reads back to the same world.
"""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from apf_physics import geometry
from apf_physics.bundled import resolve_world
from apf_physics.errors import UserError, WorldError
from apf_physics.field import FIELD_PRESETS, FieldParams
from apf_physics.obstacles import CircleObstacle, Obstacle, PolygonObstacle
from apf_physics.world import FormationSpec, World

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
    path = resolve_world(path)
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
        p = resolve_world(p)
        if p.is_dir():
            files = sorted(p.glob("*.yaml")) + sorted(p.glob("*.yml"))
            if not files:
                raise WorldError(f"{p}: directory holds no .yaml world files")
            out.extend(load_world(f) for f in files)
        else:
            out.append(load_world(p))
    return out
