"""The world-file schema: what a world file's mapping may hold, each value checked, every problem collected.

:func:`parse_world` checks a mapping read from a world file (docs/world-files.md) key by
key: unknown keys (with a did-you-mean), missing ones, types, ranges and the limits below,
each checked before the work it protects. It returns the values in the file's own units
(:class:`FileWorld`); :func:`apf_physics.world.io.worldfile.world_from_dict` converts them and builds the
world. A :class:`Checker` records every problem, one line each (``<file>: <key>: <what is
wrong>``, values shortened): the first :data:`MAX_PROBLEMS`, then how many more (counted up to
:data:`MAX_COUNTED`, where the check stops); a value with a problem raises
:class:`Invalid`, which skips only what depends on it.
"""

from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, TypeVar

import numpy as np

from apf_physics.common import geometry
from apf_physics.world.io import mapfiles, sdfworld
from apf_physics.errors import WorldError, closest_match
from apf_physics.world.field import FIELD_PRESETS, FieldParams
from apf_physics.world.kinematics import KINEMATICS, LIMIT_BOUNDS, LIMIT_KEYS, UnicycleLimits
from apf_physics.world.obstacles import CircleObstacle, Motion, Obstacle, PolygonObstacle
from apf_physics.common.safefile import NamedFileError, named_file
from apf_physics.common.safeyaml import described, key_text, shortened
from apf_physics.world.core import Fleet, FormationSpec, FormationTask, Frame

T = TypeVar("T")

# -- limits (docs/world-files.md): each protects something built later --------------------
MIN_SIDE = 1.0
"""Shortest side of the map [units] (the rasters need at least a few nodes across)."""
MAX_SIDE = 10_000.0
"""Longest side of the map [units]; the memory budget below usually binds first."""
MAX_OBSTACLES = 10_000
"""Most obstacles (loading checks each; the field and the physics visit each)."""
MAX_POLYGON_VERTICES = 1_000
"""Most vertices of one polygon (the physics splits it into triangles in about O(n²))."""
MAX_VERTICES = 100_000
"""Most polygon vertices in all."""
MAX_TARGETS = 100
"""Most targets (every value of U is a sum over them)."""
MAX_STARTS = 10_000
"""Most starts (each is one robot in an evaluation)."""
MAX_FOLLOWERS = 32
"""Most followers in a formation."""
MAX_ROUTE_POINTS = 100
"""Most points of a moving obstacle's route."""
MIN_ROBOT_RADIUS = 0.01
"""Smallest robot radius [units]: keeps the physics at most 256 substeps per control step."""
MIN_GOAL_TOLERANCE = 0.25
"""Smallest goal tolerance [units]: one A* grid spacing, so that grid nodes reach every target."""
MAX_POTENTIAL = 1e12
"""Largest magnitude of U and of its slope anywhere the package evaluates them."""
MAX_NAME_CHARS = 200
"""Longest world name [characters]."""
MAX_PROBLEMS = mapfiles.MAX_PROBLEMS
"""Problems listed from one file (20); the rest are counted."""
MAX_COUNTED = 1000
"""Problems counted in one file before the check stops (a file of a million bad entries is
not read to its end)."""

_TOP_KEYS = {"name", "units", "size", "origin", "grid", "sdf", "robot", "robot_radius", "goal_tolerance", "field",
             "obstacles", "targets", "starts", "formation", "formations", "robots"}
_SDF_KEYS = {"file", "skip", "heights"}
MAX_UNIT_CHARS = 16
"""Longest name of the file's unit (``units:``) [characters]."""
_GRID_KEYS = {"image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode", "map", "movingai", "cell"}


# -- messages ----------------------------------------------------------------------------
def _did_you_mean(word: Any, choices: Sequence[str]) -> str:
    """``"did you mean 'x'? "`` for the choice most like ``word`` (:func:`~apf_physics.errors.closest_match`),
    else ``""``."""
    close = closest_match(word, choices)
    return f"did you mean {close!r}? " if close is not None else ""


def obstacle_place(index: int, name: str | None) -> str:
    """How messages name obstacle ``index`` of the file: ``obstacles[2]``, or ``obstacles[2] 'pillar'``
    when it has a name."""
    return f"obstacles[{index}]" + (f" {name!r}" if name is not None else "")


def join_key(key: str, part: str) -> str:
    """``key.part``; after a named obstacle (:func:`obstacle_place`) ``key: part``."""
    return f"{key}: {part}" if key.endswith("'") else f"{key}.{part}"


class Invalid(Exception):
    """A value failed its check; the problem is recorded and what depends on the value is skipped."""


class TooMany(Exception):
    """:data:`MAX_COUNTED` problems found: stop checking."""


class Checker:
    """Records one line per problem: ``<file>: <key>: <what is wrong>``."""

    def __init__(self, source: str):
        self.source = source
        self.problems: list[str] = []
        """The first :data:`MAX_PROBLEMS` problems, one line each."""
        self.found = 0
        """How many problems were found (listed or only counted)."""
        self.stopped = False
        self.keys: set[str] = set()
        """The top-level keys that have a problem (``starts`` for ``starts[2][0]``)."""
        self.partial: dict[str, tuple[list[Any], list[int]]] = {}
        """For a list with a problem in some entries (``starts``, ``targets``, ``obstacles``): the
        entries that parsed and their indices in the file, so that their placement can still be
        checked and reported with the schema's problems."""

    def bad(self, key: str, problem: str) -> Invalid:
        """Record a problem and return the exception that skips what depends on the value."""
        self.found += 1
        if len(self.problems) < MAX_PROBLEMS:
            self.problems.append(f"{self.source}: {key}: {problem}" if key else f"{self.source}: {problem}")
        self.keys.add(re.split(r"[.\[]", key, maxsplit=1)[0])
        if self.found >= MAX_COUNTED:
            self.stopped = True
            raise TooMany
        return Invalid()

    def attempt(self, parse: Callable[..., T], *args: Any, **kwargs: Any) -> T | None:
        """``parse(*args, **kwargs)``, or None when it found a problem (recorded)."""
        try:
            return parse(*args, **kwargs)
        except Invalid:
            return None

    def error(self) -> WorldError:
        lines = list(self.problems)
        more = self.found - len(self.problems)
        if self.stopped:
            lines.append(f"{self.source}: and {more:,} more problems (the check stopped after {MAX_COUNTED:,})")
        elif more:
            lines.append(f"{self.source}: and {more:,} more problem{'s' if more > 1 else ''} "
                         f"({self.found:,} in all; the first {MAX_PROBLEMS} are listed)")
        return WorldError("\n".join(lines))

    def number(self, value: Any, key: str, *, positive: bool = False, nonnegative: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise self.bad(key, f"expected a number, got {described(value)}")
        try:
            number = float(value)
        except OverflowError:
            raise self.bad(key, f"too large for a number: {shortened(value)}") from None
        if not math.isfinite(number):
            raise self.bad(key, f"must be finite, got {number}")
        if positive and number <= 0:
            raise self.bad(key, f"must be positive, got {number:g}")
        if nonnegative and number < 0:
            raise self.bad(key, f"must not be negative, got {number:g}")
        return number

    def point(self, value: Any, key: str) -> tuple[float, float]:
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise self.bad(key, f"expected a point [x, y], got {described(value)}")
        x = self.attempt(self.number, value[0], f"{key}[0]")
        y = self.attempt(self.number, value[1], f"{key}[1]")
        if x is None or y is None:
            raise Invalid
        return x, y

    def points(self, value: Any, key: str, *, at_least: int = 0, at_most: int, what: str = "points") -> np.ndarray:
        """A list of points, its length checked before any point is."""
        if not isinstance(value, (list, tuple)):
            raise self.bad(key, f"expected a list of points [[x, y], ...], got {described(value)}")
        if len(value) < at_least:
            raise self.bad(key, f"needs at least {at_least} point{'s' if at_least > 1 else ''}, got {len(value)}")
        if len(value) > at_most:
            raise self.bad(key, f"at most {at_most:,} {what}, got {len(value):,}")
        pts = [self.attempt(self.point, p, f"{key}[{i}]") for i, p in enumerate(value)]
        if any(p is None for p in pts):
            self.partial[key] = ([p for p in pts if p is not None], [i for i, p in enumerate(pts) if p is not None])
            raise Invalid
        return np.array(pts, dtype=float).reshape(-1, 2)

    def entries(self, value: Any, key: str, *, expected: str, what: str, at_most: int, at_least: int = 1) -> list:
        """``value`` if it is a list of ``at_least`` to ``at_most`` entries (``what``), its length
        checked before any entry is; ``expected`` says what a wrong value should have been."""
        if not isinstance(value, list) or len(value) < at_least:
            raise self.bad(key, f"expected {expected}, got {described(value)}")
        if len(value) > at_most:
            raise self.bad(key, f"at most {at_most:,} {what}, got {len(value):,}")
        return value

    def mapping(self, value: Any, key: str, allowed: set[str], required: Sequence[str] = ()) -> Mapping[str, Any]:
        """``value`` if it is a mapping; its unknown and missing keys are recorded (and skipped by the caller)."""
        if not isinstance(value, Mapping):
            raise self.bad(key, f"expected a mapping, got {described(value)}")
        for name in value:
            if not (isinstance(name, str) and name in allowed):
                where = join_key(key, key_text(name)) if key else key_text(name)
                hint = _did_you_mean(name, sorted(allowed))
                self.bad(where, f"unknown key ({hint or ''}allowed: {', '.join(sorted(allowed))})")
        for name in required:
            if name not in value:
                self.bad(join_key(key, name) if key else name, "missing")
        return value


# -- the parts of a world ------------------------------------------------------------------
def _parse_size(check: Checker, value: Any) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise check.bad("size", f"expected [width, height], got {described(value)}")
    sides = [check.attempt(check.number, v, f"size[{i}]", positive=True) for i, v in enumerate(value)]
    for i, side in enumerate(sides):
        if side is not None and not MIN_SIDE <= side <= MAX_SIDE:
            check.bad(f"size[{i}]", f"must be between {MIN_SIDE:g} and {MAX_SIDE:,.0f} units, got {side:g}")
            sides[i] = None
    if sides[0] is None or sides[1] is None:
        raise Invalid
    return sides[0], sides[1]


def _parse_name(check: Checker, value: Any, key: str = "name") -> str:
    if not isinstance(value, str) or not value:
        raise check.bad(key, f"expected a non-empty string, got {described(value)}")
    if len(value) > MAX_NAME_CHARS:
        raise check.bad(key, f"at most {MAX_NAME_CHARS} characters, got {len(value):,}")
    if not value.isprintable():
        raise check.bad(key, f"must be printable on one line, got {shortened(value)}")
    return value


def _parse_units(check: Checker, value: Any) -> str:
    """The name of the file's unit of length (shown after lengths and on axes)."""
    if not isinstance(value, str) or not value or len(value) > MAX_UNIT_CHARS or not value.isprintable() \
            or value != value.strip():
        raise check.bad("units", f"expected the name of a unit of length, such as m or cm (at most {MAX_UNIT_CHARS} "
                                 f"printable characters), got {described(value)}")
    return value


def _parse_field(check: Checker, value: Any, frame: Frame = Frame()) -> FieldParams:
    """The field in steps: a preset's values are in steps; numbers written in the file are in its units."""
    known = f"(known: {', '.join(FIELD_PRESETS)})"
    if isinstance(value, str):
        if value not in FIELD_PRESETS:
            raise check.bad("field", f"unknown preset {shortened(value)} ({_did_you_mean(value, list(FIELD_PRESETS))}"
                                     f"known: {', '.join(FIELD_PRESETS)})")
        return FieldParams.preset(value)
    names = [f.name for f in fields(FieldParams)]
    problems = len(check.problems)
    raw = check.mapping(value, "field", set(names) | {"preset"})
    base: dict[str, Any] = {}
    if "preset" in raw:
        preset = raw["preset"]
        if not isinstance(preset, str) or preset not in FIELD_PRESETS:
            raise check.bad("field.preset", f"unknown preset {shortened(preset)} {known}")
        base = frame.field_to_file(FieldParams.preset(preset))
    base.update({k: v for k, v in raw.items() if k in names})
    values = {}
    for name in names:
        if name not in base:
            check.bad(f"field.{name}", "missing")
            continue
        positive = name in ("p0", "ps", "u_max")
        values[name] = check.attempt(check.number, base[name], f"field.{name}", positive=positive,
                                     nonnegative=not positive)
    if len(check.problems) > problems:
        raise Invalid
    if frame.unit == 1.0:
        return FieldParams(**values)
    with np.errstate(all="ignore"):
        return FieldParams(**{k: float(v) for k, v in frame.field_from_file(values).items()})


def _outside(box: tuple[np.ndarray, np.ndarray] | None, lower: np.ndarray, upper: np.ndarray) -> str | None:
    """What to say if ``[lower, upper]`` leaves the map ``box`` (its corners in file coordinates),
    else None (also when the map is unknown)."""
    if box is None:
        return None
    lo, hi = box
    if lower[0] < lo[0] or lower[1] < lo[1] or upper[0] > hi[0] or upper[1] > hi[1]:
        return f"reaches outside the map [{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}]"
    return None


def _parse_motion(check: Checker, value: Any, key: str) -> Motion:
    problems = len(check.problems)
    body = check.mapping(value, key, {"path", "speed", "loop", "phase"}, required=("path", "speed"))
    path = (check.attempt(check.points, body["path"], f"{key}.path", at_least=1, at_most=MAX_ROUTE_POINTS)
            if "path" in body else None)
    speed = check.attempt(check.number, body["speed"], f"{key}.speed", positive=True) if "speed" in body else None
    if speed is not None and speed > 1:
        check.bad(f"{key}.speed", f"at most 1 unit per control step, got {speed:g}")
    loop = body.get("loop", False)
    if not isinstance(loop, bool):
        check.bad(f"{key}.loop", f"expected true or false, got {described(loop)}")
    phase = check.attempt(check.number, body.get("phase", 0.0), f"{key}.phase", nonnegative=True)
    if len(check.problems) > problems:
        raise Invalid
    return Motion(path, speed, loop, phase)


def _parse_obstacle(check: Checker, value: Any, index: int, box: tuple[np.ndarray, np.ndarray] | None) -> Obstacle:
    """Obstacle ``index`` of the file; every problem names it by its name when it has one (:func:`obstacle_place`)."""
    problems = len(check.problems)
    given = value.get("name") if isinstance(value, Mapping) else None
    known = given if isinstance(given, str) and given and len(given) <= MAX_NAME_CHARS and given.isprintable() else None
    key = obstacle_place(index, known)
    body = check.mapping(value, key, {"polygon", "circle", "motion", "name"})
    name = check.attempt(_parse_name, check, body["name"], join_key(key, "name")) if "name" in body else None
    shapes = [k for k in ("polygon", "circle") if k in body]
    if len(shapes) != 1:
        if len(check.problems) == problems:
            check.bad(key, "each obstacle is exactly one of 'polygon: [[x, y], ...]' or 'circle: {center, radius}' "
                           "(and an optional 'motion')")
        raise Invalid
    motion = check.attempt(_parse_motion, check, body["motion"], join_key(key, "motion")) if "motion" in body else None
    # the box it sweeps along its route (the route starts where it is written)
    reach = motion.reach if motion is not None else (np.zeros(2), np.zeros(2))
    if "polygon" in body:
        k = join_key(key, "polygon")
        vertices = check.points(body["polygon"], k, at_least=3, at_most=MAX_POLYGON_VERTICES, what="vertices")
        if not geometry.polygon_is_simple(vertices):
            raise check.bad(k, "polygon crosses itself or repeats a vertex (it must be a simple polygon)")
        area = geometry.polygon_area(vertices)
        if abs(area) < 1e-12:
            raise check.bad(k, "polygon has zero area (its vertices are collinear)")
        outside = _outside(box, vertices.min(axis=0) + reach[0], vertices.max(axis=0) + reach[1])
        if outside:
            raise check.bad(k, f"polygon {outside}" + (" on its route" if motion is not None else ""))
        if len(check.problems) > problems:
            raise Invalid
        return PolygonObstacle(vertices if area > 0 else vertices[::-1].copy(), motion, name)
    k = join_key(key, "circle")
    circle = check.mapping(body["circle"], k, {"center", "radius"}, required=("center", "radius"))
    center = check.attempt(check.point, circle["center"], f"{k}.center") if "center" in circle else None
    radius = check.attempt(check.number, circle["radius"], f"{k}.radius", nonnegative=True) if "radius" in circle else None
    if center is None or radius is None or len(check.problems) > problems:
        raise Invalid
    c = np.array(center)
    outside = _outside(box, c - radius + reach[0], c + radius + reach[1])
    if outside:
        raise check.bad(k, f"circle {outside}" + (" on its route" if motion is not None else ""))
    return CircleObstacle(c, radius, motion, name)


def _parse_obstacles(check: Checker, value: Any, box: tuple[np.ndarray, np.ndarray] | None) -> tuple[Obstacle, ...]:
    if value is None:
        return ()
    check.entries(value, "obstacles", expected="a list", what="obstacles", at_most=MAX_OBSTACLES, at_least=0)
    vertices = sum(len(o["polygon"]) for o in value
                   if isinstance(o, Mapping) and isinstance(o.get("polygon"), (list, tuple)))
    if vertices > MAX_VERTICES:
        raise check.bad("obstacles", f"at most {MAX_VERTICES:,} polygon vertices in all, got {vertices:,}")
    parsed = [check.attempt(_parse_obstacle, check, o, i, box) for i, o in enumerate(value)]
    first: dict[str, int] = {}
    for i, o in enumerate(value):   # a name picks out one obstacle in messages: no two alike
        name = o.get("name") if isinstance(o, Mapping) else None
        if isinstance(name, str) and name in first:
            parsed[i] = None
            check.bad(f"obstacles[{i}].name", f"{shortened(name)} is already the name of obstacles[{first[name]}]")
        elif isinstance(name, str):
            first[name] = i
    if any(o is None for o in parsed):
        check.partial["obstacles"] = ([o for o in parsed if o is not None],
                                      [i for i, o in enumerate(parsed) if o is not None])
        raise Invalid
    return tuple(parsed)


MAX_FORMATIONS = 64
"""Most formations in one world."""
MAX_ROBOTS = 10_000
"""Most robots of a world's ``robots:`` (a fleet; each is one robot of one evaluation)."""


def _parse_robots(check: Checker, value: Any) -> Fleet:
    """A world file's ``robots:``: a list of ``{start: [x, y], target: [x, y]}``, in the file's units."""
    check.entries(value, "robots", expected="a non-empty list of robots ({start: [x, y], target: [x, y]})",
                  what="robots", at_most=MAX_ROBOTS)
    starts, targets = [], []
    for i, entry in enumerate(value):
        key = f"robots[{i}]"
        body = check.attempt(check.mapping, entry, key, {"start", "target"}, required=("start", "target"))
        if body is None or "start" not in body or "target" not in body:
            continue
        start = check.attempt(check.point, body["start"], f"{key}.start")
        target = check.attempt(check.point, body["target"], f"{key}.target")
        if start is not None and target is not None:
            starts.append(start)
            targets.append(target)
    if len(starts) < len(value):
        raise Invalid
    return Fleet(np.array(starts, float), np.array(targets, float))


def _parse_formations(check: Checker, value: Any) -> tuple[FormationTask, ...]:
    check.entries(value, "formations", expected="a non-empty list of formations", what="formations",
                  at_most=MAX_FORMATIONS)
    tasks = []
    for i, entry in enumerate(value):
        key = f"formations[{i}]"
        body = check.attempt(check.mapping, entry, key, _FORMATION_KEYS | {"start", "target"},
                             required=("start", "target"))
        if body is None or "start" not in body or "target" not in body:   # (a missing one is reported)
            continue
        start = check.attempt(check.point, body["start"], f"{key}.start")
        target = check.attempt(check.point, body["target"], f"{key}.target")
        spec = check.attempt(_parse_formation, check, {k: v for k, v in body.items() if k not in ("start", "target")},
                             key)
        if start is not None and target is not None and spec is not None:
            tasks.append(FormationTask(np.asarray(start, float), np.asarray(target, float), spec))
    if len(tasks) < len(value):
        raise Invalid
    return tuple(tasks)


_FORMATION_KEYS = {"followers", "comm_range", "spacing", "shape", "offsets"}


def _parse_formation(check: Checker, value: Any, key: str = "formation") -> FormationSpec:
    problems = len(check.problems)
    body = check.mapping(value, key, _FORMATION_KEYS)
    default = FormationSpec()
    followers = body.get("followers", default.followers)
    if isinstance(followers, bool) or not isinstance(followers, int) or not 0 <= followers <= MAX_FOLLOWERS:
        check.bad(f"{key}.followers", f"expected a whole number from 0 to {MAX_FOLLOWERS}, got {described(followers)}")
        followers = None
    comm_range = check.attempt(check.number, body.get("comm_range", default.comm_range), f"{key}.comm_range",
                               positive=True)
    spacing = check.attempt(check.number, body.get("spacing", default.spacing), f"{key}.spacing", positive=True)
    if spacing is not None and comm_range is not None and spacing > comm_range:
        check.bad(f"{key}.spacing", f"spacing {spacing:g} exceeds comm_range {comm_range:g}")
    shape = body.get("shape", default.shape)
    if shape not in ("line", "wedge", "offsets"):
        check.bad(f"{key}.shape", f"expected 'line', 'wedge' or 'offsets', got {described(shape)}")
    offsets: tuple[tuple[float, float], ...] = ()
    if shape == "offsets":
        if "offsets" not in body:
            check.bad(f"{key}.offsets", "missing (required when shape is 'offsets')")
        else:
            pts = check.attempt(check.points, body["offsets"], f"{key}.offsets", at_least=1, at_most=MAX_FOLLOWERS)
            if pts is not None and followers is not None and len(pts) != followers:
                check.bad(f"{key}.offsets", f"{len(pts)} offsets for {followers} followers")
            elif pts is not None:
                offsets = tuple((float(a), float(b)) for a, b in pts)
    elif "offsets" in body:
        check.bad(f"{key}.offsets", "only allowed when shape is 'offsets'")
    if len(check.problems) > problems:
        raise Invalid
    return FormationSpec(followers, comm_range, spacing, shape, offsets)


def _parse_robot(check: Checker, data: Mapping[str, Any]) -> tuple[float | None, float | None, UnicycleLimits | None]:
    """``(radius, step, unicycle)`` in file units, from ``robot: {radius, step, kinematics, ...}``
    (or the older ``robot_radius``).

    Unset, the radius is a quarter of the step and the step is one file unit. ``kinematics:
    unicycle`` makes the robots unicycles, with the limits of
    :class:`~apf_physics.world.kinematics.UnicycleLimits` that the mapping gives (speeds and
    accelerations in file units per step, turn rates in radians per step); ``holonomic`` (the
    default) takes no limits.
    """
    keys = {"radius", "step", "kinematics", *LIMIT_KEYS}
    robot = check.attempt(check.mapping, data["robot"], "robot", keys) if "robot" in data else {}
    if robot is None:
        return None, None, None
    if "radius" in robot and "robot_radius" in data:
        check.bad("robot_radius", "given twice: write robot: {radius: ...} alone")
    step = check.attempt(check.number, robot.get("step", 1.0), "robot.step", positive=True)
    if "radius" in robot:
        radius = check.attempt(check.number, robot["radius"], "robot.radius", positive=True)
    elif "robot_radius" in data:
        radius = check.attempt(check.number, data["robot_radius"], "robot_radius", positive=True)
    else:
        radius = None if step is None else 0.25 * step
    kind = robot.get("kinematics", "holonomic")
    if kind not in KINEMATICS:
        check.bad("robot.kinematics", f"expected one of {', '.join(KINEMATICS)}, got {shortened(kind)}")
        return radius, step, None
    given = [k for k in LIMIT_KEYS if k in robot]
    if kind == "holonomic":
        for k in given:
            check.bad(f"robot.{k}", "only for a unicycle robot: add kinematics: unicycle")
        return radius, step, None
    limits = {}
    for k in given:
        value = check.attempt(check.number, robot[k], f"robot.{k}", nonnegative=k == "max_reverse",
                              positive=k != "max_reverse")
        if value is not None:
            limits[k] = value
    if len(limits) < len(given):
        return radius, step, None
    unit = step or 1.0
    defaults = UnicycleLimits().scaled(1.0 / unit)   # the default limits are in steps
    unicycle = replace(defaults, **limits)
    for name, value, bound in unicycle.out_of_bounds(unit):
        steps = f"{LIMIT_BOUNDS[name]:g} steps of {unit:g}" if unit != 1.0 else f"{LIMIT_BOUNDS[name]:g} steps"
        why = {"max_speed": f"{steps} per control step", "max_reverse": f"{steps} per control step",
               "max_accel": f"{steps} per control step, from one step to the next",
               "max_turn_rate": "a whole turn per control step [rad]",
               "max_turn_accel": "from a whole turn one way to a whole turn the other in one step [rad]"}[name]
        check.bad(f"robot.{name}", f"at most {bound:.6g} ({why}), got {value:g}")
    return radius, step, unicycle


def _parse_grid(check: Checker, value: Any, source: str, confine: bool = False) -> mapfiles.OccupancyMap:
    """The ``grid:`` layer: a ROS map (its YAML with ``map:``, or its keys inline) or a MovingAI map.

    Every file name goes through :func:`~apf_physics.common.safefile.named_file` (relative to the world
    file's folder; with ``confine``, it must stay inside that folder, the image a map YAML names too).
    """
    body = check.mapping(value, "grid", _GRID_KEYS)
    folder = Path(source).parent if source != "<dict>" else Path.cwd()
    within = folder if confine else None

    def path_of(key: str) -> Path:
        try:
            return named_file(body[key], folder, within)
        except NamedFileError as exc:
            raise check.bad(f"grid.{key}", str(exc)) from None

    try:
        if "movingai" in body:
            extra = set(body) - {"movingai", "cell"}
            if extra:
                raise check.bad("grid", f"a MovingAI grid takes movingai and cell, not {', '.join(sorted(extra))}")
            cell = check.number(body.get("cell", 1.0), "grid.cell", positive=True)
            return mapfiles.read_movingai_map(path_of("movingai"), cell)
        if "map" in body:
            if set(body) != {"map"}:
                raise check.bad("grid", "'map: FILE.yaml' names a ROS map YAML, which holds the other keys")
            return mapfiles.read_ros_map(path_of("map"), within=within)
        if "image" not in body:
            raise check.bad("grid", "give 'movingai: FILE.map', 'map: FILE.yaml' (a ROS map) or the ROS map keys "
                                    "inline (image, resolution, origin, ...)")
        return mapfiles.ros_map_from_dict({k: v for k, v in body.items()}, str(source), folder, within=within)
    except WorldError as exc:   # the map file's own problems, each naming that file
        for line in str(exc).splitlines():
            check.bad("grid", line.removeprefix(f"{source}: "))
        raise Invalid from None


def _parse_sdf(check: Checker, value: Any, source: str, box: tuple[np.ndarray, np.ndarray] | None,
               room: int, confine: bool = False) -> tuple[Obstacle, ...]:
    """The ``sdf:`` key: the static box, cylinder and sphere collisions of a Gazebo SDF world
    (:mod:`apf_physics.sdfworld`) as obstacles, named ``model::link::collision``. Those wholly
    outside the map are left out (the map is a window on the Gazebo world); one that crosses the
    map's edge is a problem. ``room``: how many obstacles the world may still take; ``confine``: the
    file must be inside the world file's folder (:func:`~apf_physics.common.safefile.named_file`)."""
    body = check.mapping(value, "sdf", _SDF_KEYS, required=("file",))
    if "file" not in body:
        raise Invalid
    name = body["file"]
    if not isinstance(name, str) or not name:
        raise check.bad("sdf.file", f"expected a file name, got {described(name)}")
    skip = body.get("skip", [])
    if not isinstance(skip, list) or not all(isinstance(p, str) and p for p in skip):
        raise check.bad("sdf.skip", f"expected a list of model names (glob patterns allowed), got {described(skip)}")
    heights = body.get("heights", list(sdfworld.DEFAULT_HEIGHTS))
    if not isinstance(heights, (list, tuple)) or len(heights) != 2:
        raise check.bad("sdf.heights", f"expected [low, high], got {described(heights)}")
    low = check.number(heights[0], "sdf.heights[0]")
    high = check.number(heights[1], "sdf.heights[1]")
    if not low < high:
        raise check.bad("sdf.heights", f"low {low:g} must be below high {high:g}")
    if set(body) - _SDF_KEYS:
        raise Invalid
    folder = Path(source).parent if source != "<dict>" else Path.cwd()
    try:
        path = named_file(name, folder, folder if confine else None)
    except NamedFileError as exc:
        raise check.bad("sdf.file", str(exc)) from None
    try:
        footprints = sdfworld.read_sdf_obstacles(path, skip, (low, high))
    except WorldError as exc:   # the SDF file's own problems, each naming that file
        for line in str(exc).splitlines():
            check.bad("sdf", line)
        raise Invalid from None
    obstacles: list[Obstacle] = []
    for shape in footprints:
        if shape.vertices is not None:
            obstacle: Obstacle = PolygonObstacle(shape.vertices, name=shape.name)
            lower, upper = shape.vertices.min(axis=0), shape.vertices.max(axis=0)
        else:
            center = np.array(shape.center, float)
            obstacle = CircleObstacle(center, float(shape.radius), name=shape.name)
            lower, upper = center - shape.radius, center + shape.radius
        if box is not None and ((upper < box[0]).any() or (lower > box[1]).any()):
            continue                                      # wholly outside the map: not in this world
        outside = _outside(box, lower, upper)
        if outside:
            check.bad("sdf", f"{shape.name!r} {outside}: enlarge the map (size, origin) or add the model to sdf.skip")
            continue
        obstacles.append(obstacle)
    if len(obstacles) > room:
        raise check.bad("sdf", f"{len(obstacles):,} obstacles from the SDF world leave the world over "
                               f"{MAX_OBSTACLES:,} obstacles")
    return tuple(obstacles)


@dataclass(frozen=True)
class FileWorld:
    """A world file's values as checked, in the file's units and coordinates; each None where it
    is missing or has a problem (recorded).

    Attributes:
        name: The world's name (by default the file's stem).
        size: Width and height of the map (the grid's, when there is one).
        grid: The ``grid:`` layer, if any.
        frame: The file's coordinates of the world's origin (the grid's) and file units per step
            (``robot.step``).
        robot_radius: The robot's radius.
        goal_tolerance: How near a target counts as reaching it.
        params: The field, already in steps.
        obstacles: The obstacles written (not the grid).
        targets: (T, 2) targets (a formations-only file: the formations' targets).
        starts: (S, 2) starts (a formations-only file: the formations' starts).
        formation: The ``formation:`` of the world's robots, if any.
        formations: The ``formations:`` (empty when there are none).
        unicycle: The robot's limits if it is a unicycle (file units), else None.
        sdf: The obstacles read from the ``sdf:`` world (after :attr:`obstacles` in the world).
        robots: The ``robots:`` (file units), else None.
    """

    name: str | None
    size: tuple[float, float] | None
    grid: mapfiles.OccupancyMap | None
    frame: Frame
    robot_radius: float | None
    goal_tolerance: float | None
    params: FieldParams | None
    obstacles: tuple[Obstacle, ...] | None
    targets: np.ndarray | None
    starts: np.ndarray | None
    formation: FormationSpec | None
    formations: tuple[FormationTask, ...] | None
    unicycle: UnicycleLimits | None = None
    sdf: tuple[Obstacle, ...] | None = ()
    robots: Fleet | None = None


def parse_world(check: Checker, data: Any, source: str, confine: bool = False) -> FileWorld | None:
    """Check the world-file mapping ``data`` (read from ``source``) key by key.

    ``confine``: the files the world names (its grid's) must be inside the folder of ``source``.

    Returns:
        Its values in the file's units (:class:`FileWorld`, each None where it has a problem,
        recorded in ``check``), or None when ``data`` is not a mapping.

    Raises:
        TooMany: :data:`MAX_COUNTED` problems are found.
    """
    if not isinstance(data, Mapping):
        check.bad("", f"a world file must be a mapping of keys, got {described(data)}")
        return None
    several = data.get("formations") is not None
    fleet = data.get("robots") is not None
    has_grid = data.get("grid") is not None
    required = [k for k in (("field",) if several or fleet else ("field", "targets"))] + ([] if has_grid else ["size"])
    check.mapping(data, "", _TOP_KEYS, required=required)
    if several and data.get("formation") is not None:
        check.bad("formation", "'formation' and 'formations' together: give one formation, or a list of them")
    for other in ("formation", "starts"):
        if fleet and data.get(other):
            check.bad("robots", f"'robots' and '{other}' together: a fleet's robots start where 'robots' puts them")
    if has_grid and "size" in data:
        check.bad("size", "a world with a grid takes its size from the grid: leave size out")
    if has_grid and "origin" in data:
        check.bad("origin", "a world with a grid takes its origin from the grid: leave origin out")
    grid = check.attempt(_parse_grid, check, data["grid"], source, confine) if has_grid else None
    size = grid.size if grid is not None else (check.attempt(_parse_size, check, data["size"]) if "size" in data else None)
    origin = check.attempt(check.point, data["origin"], "origin") if "origin" in data and not has_grid else (0.0, 0.0)
    offset = np.asarray(grid.origin if grid is not None else (origin or (0.0, 0.0)), float)
    box = (offset, offset + np.asarray(size, float)) if size is not None and origin is not None else None
    default_name = Path(source).stem if source != "<dict>" else "world"
    name = check.attempt(_parse_name, check, data.get("name", default_name))
    robot_radius, step, unicycle = _parse_robot(check, data)
    units = check.attempt(_parse_units, check, data["units"]) if "units" in data else None
    if units is None and has_grid and isinstance(data["grid"], Mapping) and "movingai" not in data["grid"]:
        units = "m"   # a ROS map's resolution and origin are in metres
    frame = Frame((float(offset[0]), float(offset[1])), float(step if step is not None else 1.0), units or "")
    if grid is not None and step is not None and not all(MIN_SIDE <= side / step <= MAX_SIDE for side in grid.size):
        rows, cols = grid.occupied.shape
        check.bad("grid", f"the map is {size[0] / step:.6g} x {size[1] / step:.6g} steps of {step:g} ({cols:,} x {rows:,} "
                          f"cells of {grid.cell:g}); each side must be between {MIN_SIDE:g} and {MAX_SIDE:,.0f} steps")
        size = None
    goal_tolerance = check.attempt(check.number, data.get("goal_tolerance", 0.75 * frame.unit), "goal_tolerance",
                                   positive=True)
    params = check.attempt(_parse_field, check, data["field"], frame) if "field" in data else None
    obstacles = check.attempt(_parse_obstacles, check, data.get("obstacles"), box)
    room = MAX_OBSTACLES - (len(data["obstacles"]) if isinstance(data.get("obstacles"), list) else 0)
    sdf = check.attempt(_parse_sdf, check, data["sdf"], source, box, room, confine) if data.get("sdf") is not None else ()
    targets = (check.attempt(check.points, data["targets"], "targets", at_least=1, at_most=MAX_TARGETS, what="targets")
               if "targets" in data else None)
    starts = check.attempt(check.points, data.get("starts") or [], "starts", at_most=MAX_STARTS, what="starts")
    formation = (check.attempt(_parse_formation, check, data["formation"])
                 if data.get("formation") is not None and not several else None)
    formations = check.attempt(_parse_formations, check, data["formations"]) if several else ()
    robots = check.attempt(_parse_robots, check, data["robots"]) if fleet else None
    if robots is not None and "targets" not in data:
        targets = robots.targets   # a fleet's targets are its robots'
    if several and formations:   # the formations' own starts and targets, unless also given at the top
        if "targets" not in data:
            targets = np.array([task.target for task in formations])
        if not data.get("starts"):
            starts = np.array([task.start for task in formations])
    return FileWorld(name, size, grid, frame, robot_radius, goal_tolerance, params, obstacles, targets, starts,
                     formation, formations, unicycle, sdf, robots)
