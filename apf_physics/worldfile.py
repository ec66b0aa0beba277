"""World files: reading, validating and writing the YAML world-file contract (README "World files").

:func:`load_world` reads a file (YAML, or JSON being YAML) and :func:`world_from_dict`
validates a mapping and builds the :class:`~apf_physics.world.World`. Every problem found is
reported, one line each, in one :class:`~apf_physics.errors.WorldError`: ``<file>: <key>:
<what is wrong>``, with values shortened. :func:`save_world` writes a file that reads back
to the same world.

Hostile or broken input gets a clear refusal, never a traceback, a hang or a raw memory
error: only regular files of at most :data:`MAX_FILE_BYTES` are read; the YAML parser's
events are checked for depth, length and node count (aliases expanded) before any Python
object is built; and the limits below are checked before the work they protect (the
rasters the physics and the planners build, the physics' substeps, the field's values).
"""

from __future__ import annotations

import difflib
import math
import numbers
import os
import re
import reprlib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence, TypeVar

import numpy as np
import yaml

from apf_physics import geometry
from apf_physics.bundled import resolve_world
from apf_physics.errors import UserError, WorldError
from apf_physics.field import FIELD_PRESETS, FieldParams
from apf_physics.safefile import MAX_FILE_BYTES, open_regular_file, read_regular_file  # noqa: F401 (public here too)
from apf_physics import mapfiles
from apf_physics.obstacles import CircleObstacle, GridObstacle, Motion, Obstacle, PolygonObstacle
from apf_physics.world import FormationSpec, FormationTask, Frame, World

T = TypeVar("T")

# -- limits (README "World files") -------------------------------------------------------
# Reading: what any YAML file (world or curriculum) may hold.
MAX_DEPTH = 32
"""Deepest nesting of lists and mappings (a world file needs 5)."""
MAX_NODES = 500_000
"""Most values in one file (numbers, strings, lists, mappings), every alias counted as what it expands to."""
MAX_SCALAR_CHARS = 4096
"""Longest single value [characters]: a path fits; an integer stays below Python's 4,300-digit parsing limit."""

# The world: each limit protects something built later.
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
MAX_PROBLEMS = 20
"""Problems reported from one file before the check stops."""

MEMORY_BUDGET = 2 * 2**30
"""Default peak memory the rasters of one world may take [bytes]; the environment variable
``APF_PHYSICS_MEMORY_BUDGET`` (bytes, or a number with K, M, G or T) overrides it."""
MEMORY_BUDGET_VARIABLE = "APF_PHYSICS_MEMORY_BUDGET"
RASTER_MARGIN = 16.0
"""How far beyond the map rasters reach [units] (observation windows of up to 29 × 29)."""
RASTER_BYTES_PER_UNIT2 = 4_000
"""Peak bytes per square unit of rasters (map plus margin) an evaluation builds, computed in
chunks: measured 2,400–2,600 beyond the process's own (a 300 × 300 world of boxes with the
window and map networks and A*; a 512 × 512 MovingAI map with the map network and A*), rounded
up. The physics' clearance raster at 8 nodes per unit dominates; then the A* grid and the
potential and observation rasters at 4."""
RASTER_BYTES_PER_TARGET = 1_500
"""Further peak bytes per square unit per target: U is computed from a column per target
(measured 370 at the default 4 nodes per unit; 1,500 covers a model's observer at 8)."""

_TOP_KEYS = {"name", "size", "grid", "robot", "robot_radius", "goal_tolerance", "field", "obstacles", "targets", "starts",
             "formation", "formations"}
_GRID_KEYS = {"image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode", "map", "movingai", "cell"}
_REQUIRED = ("size", "field", "targets")


# -- messages ----------------------------------------------------------------------------
class _ShortRepr(reprlib.Repr):
    """``repr`` cut to a few elements and levels; huge integers by their digit count (their
    ``repr`` would raise beyond 4,300 digits)."""

    def __init__(self):
        super().__init__()
        self.maxlevel, self.maxlist, self.maxtuple, self.maxdict, self.maxset = 3, 4, 4, 4, 4
        self.maxstring, self.maxlong, self.maxother = 40, 24, 40

    def repr_int(self, x: int, level: int) -> str:
        if x.bit_length() > 256:
            return f"<an integer of about {int(x.bit_length() * math.log10(2)) + 1} digits>"
        return super().repr_int(x, level)


_REPR = _ShortRepr()


def _short(value: Any, limit: int = 60) -> str:
    """``value`` for a message: one line of at most ``limit`` characters, whatever it is."""
    try:
        text = _REPR.repr(value)
    except Exception:  # a value whose repr fails: say what it is
        text = f"<{type(value).__name__}>"
    text = text.replace("\n", " ")
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _kind(value: Any) -> str:
    """``list [1, 2, ...]``: the type and the shortened value (``null`` for an empty YAML value)."""
    return "null" if value is None else f"{type(value).__name__} {_short(value)}"


def _key_text(key: Any) -> str:
    """A mapping key as messages show it: plain if it is a short printable string."""
    if isinstance(key, str) and key.isprintable() and 0 < len(key) <= 40:
        return key
    return _short(key, 40)


def _did_you_mean(word: Any, choices: Sequence[str]) -> str:
    if not isinstance(word, str) or len(word) > 100:
        return ""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f"did you mean {close[0]!r}? " if close else ""


class _Invalid(Exception):
    """A value failed its check; the problem is recorded and what depends on the value is skipped."""


class _TooMany(Exception):
    """:data:`MAX_PROBLEMS` problems recorded: stop checking."""


class _Checker:
    """Records one line per problem: ``<file>: <key>: <what is wrong>``."""

    def __init__(self, source: str):
        self.source = source
        self.problems: list[str] = []
        self.stopped = False

    def bad(self, key: str, problem: str) -> _Invalid:
        """Record a problem and return the exception that skips what depends on the value."""
        self.problems.append(f"{self.source}: {key}: {problem}" if key else f"{self.source}: {problem}")
        if len(self.problems) >= MAX_PROBLEMS:
            self.stopped = True
            raise _TooMany
        return _Invalid()

    def attempt(self, parse: Callable[..., T], *args: Any, **kwargs: Any) -> T | None:
        """``parse(*args, **kwargs)``, or None when it found a problem (recorded)."""
        try:
            return parse(*args, **kwargs)
        except _Invalid:
            return None

    def error(self) -> WorldError:
        lines = list(self.problems)
        if self.stopped:
            lines.append(f"{self.source}: stopped after {MAX_PROBLEMS} problems")
        return WorldError("\n".join(lines))

    def number(self, value: Any, key: str, *, positive: bool = False, nonnegative: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise self.bad(key, f"expected a number, got {_kind(value)}")
        try:
            number = float(value)
        except OverflowError:
            raise self.bad(key, f"too large for a number: {_short(value)}") from None
        if not math.isfinite(number):
            raise self.bad(key, f"must be finite, got {number}")
        if positive and number <= 0:
            raise self.bad(key, f"must be positive, got {number:g}")
        if nonnegative and number < 0:
            raise self.bad(key, f"must not be negative, got {number:g}")
        return number

    def point(self, value: Any, key: str) -> tuple[float, float]:
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise self.bad(key, f"expected a point [x, y], got {_kind(value)}")
        x = self.attempt(self.number, value[0], f"{key}[0]")
        y = self.attempt(self.number, value[1], f"{key}[1]")
        if x is None or y is None:
            raise _Invalid
        return x, y

    def points(self, value: Any, key: str, *, at_least: int = 0, at_most: int, what: str = "points") -> np.ndarray:
        """A list of points, its length checked before any point is."""
        if not isinstance(value, (list, tuple)):
            raise self.bad(key, f"expected a list of points [[x, y], ...], got {_kind(value)}")
        if len(value) < at_least:
            raise self.bad(key, f"needs at least {at_least} point{'s' if at_least > 1 else ''}, got {len(value)}")
        if len(value) > at_most:
            raise self.bad(key, f"at most {at_most:,} {what}, got {len(value):,}")
        pts = [self.attempt(self.point, p, f"{key}[{i}]") for i, p in enumerate(value)]
        if any(p is None for p in pts):
            raise _Invalid
        return np.array(pts, dtype=float).reshape(-1, 2)

    def mapping(self, value: Any, key: str, allowed: set[str], required: Sequence[str] = ()) -> Mapping[str, Any]:
        """``value`` if it is a mapping; its unknown and missing keys are recorded (and skipped by the caller)."""
        if not isinstance(value, Mapping):
            raise self.bad(key, f"expected a mapping, got {_kind(value)}")
        for name in value:
            if not (isinstance(name, str) and name in allowed):
                where = f"{key}.{_key_text(name)}" if key else _key_text(name)
                hint = _did_you_mean(name, sorted(allowed))
                self.bad(where, f"unknown key ({hint or ''}allowed: {', '.join(sorted(allowed))})")
        for name in required:
            if name not in value:
                self.bad(f"{key}.{name}" if key else name, "missing")
        return value


# -- the parts of a world ------------------------------------------------------------------
def _parse_size(check: _Checker, value: Any) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise check.bad("size", f"expected [width, height], got {_kind(value)}")
    sides = [check.attempt(check.number, v, f"size[{i}]", positive=True) for i, v in enumerate(value)]
    for i, side in enumerate(sides):
        if side is not None and not MIN_SIDE <= side <= MAX_SIDE:
            check.bad(f"size[{i}]", f"must be between {MIN_SIDE:g} and {MAX_SIDE:,.0f} units, got {side:g}")
            sides[i] = None
    if sides[0] is None or sides[1] is None:
        raise _Invalid
    return sides[0], sides[1]


def _parse_name(check: _Checker, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise check.bad("name", f"expected a non-empty string, got {_kind(value)}")
    if len(value) > MAX_NAME_CHARS:
        raise check.bad("name", f"at most {MAX_NAME_CHARS} characters, got {len(value):,}")
    if not value.isprintable():
        raise check.bad("name", f"must be printable on one line, got {_short(value)}")
    return value


def _parse_field(check: _Checker, value: Any, frame: Frame = Frame()) -> FieldParams:
    """The field in steps: a preset's values are in steps; numbers written in the file are in its units."""
    known = f"(known: {', '.join(FIELD_PRESETS)})"
    if isinstance(value, str):
        if value not in FIELD_PRESETS:
            raise check.bad("field", f"unknown preset {_short(value)} ({_did_you_mean(value, list(FIELD_PRESETS))}"
                                     f"known: {', '.join(FIELD_PRESETS)})")
        return FieldParams.preset(value)
    names = [f.name for f in fields(FieldParams)]
    problems = len(check.problems)
    raw = check.mapping(value, "field", set(names) | {"preset"})
    base: dict[str, Any] = {}
    if "preset" in raw:
        preset = raw["preset"]
        if not isinstance(preset, str) or preset not in FIELD_PRESETS:
            raise check.bad("field.preset", f"unknown preset {_short(preset)} {known}")
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
        raise _Invalid
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


def _parse_motion(check: _Checker, value: Any, key: str) -> Motion:
    problems = len(check.problems)
    body = check.mapping(value, key, {"path", "speed", "loop", "phase"}, required=("path", "speed"))
    path = (check.attempt(check.points, body["path"], f"{key}.path", at_least=1, at_most=MAX_ROUTE_POINTS)
            if "path" in body else None)
    speed = check.attempt(check.number, body["speed"], f"{key}.speed", positive=True) if "speed" in body else None
    if speed is not None and speed > 1:
        check.bad(f"{key}.speed", f"at most 1 unit per control step, got {speed:g}")
    loop = body.get("loop", False)
    if not isinstance(loop, bool):
        check.bad(f"{key}.loop", f"expected true or false, got {_kind(loop)}")
    phase = check.attempt(check.number, body.get("phase", 0.0), f"{key}.phase", nonnegative=True)
    if len(check.problems) > problems:
        raise _Invalid
    return Motion(path, speed, loop, phase)


def _parse_obstacle(check: _Checker, value: Any, key: str, box: tuple[np.ndarray, np.ndarray] | None) -> Obstacle:
    problems = len(check.problems)
    body = check.mapping(value, key, {"polygon", "circle", "motion"})
    shapes = [k for k in ("polygon", "circle") if k in body]
    if len(shapes) != 1:
        if len(check.problems) == problems:
            check.bad(key, "each obstacle is exactly one of 'polygon: [[x, y], ...]' or 'circle: {center, radius}' "
                           "(and an optional 'motion')")
        raise _Invalid
    motion = check.attempt(_parse_motion, check, body["motion"], f"{key}.motion") if "motion" in body else None
    # the box it sweeps along its route (the route starts where it is written)
    reach = motion.reach if motion is not None else (np.zeros(2), np.zeros(2))
    if "polygon" in body:
        k = f"{key}.polygon"
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
            raise _Invalid
        return PolygonObstacle(vertices if area > 0 else vertices[::-1].copy(), motion)
    k = f"{key}.circle"
    circle = check.mapping(body["circle"], k, {"center", "radius"}, required=("center", "radius"))
    center = check.attempt(check.point, circle["center"], f"{k}.center") if "center" in circle else None
    radius = check.attempt(check.number, circle["radius"], f"{k}.radius", nonnegative=True) if "radius" in circle else None
    if center is None or radius is None or len(check.problems) > problems:
        raise _Invalid
    c = np.array(center)
    outside = _outside(box, c - radius + reach[0], c + radius + reach[1])
    if outside:
        raise check.bad(k, f"circle {outside}" + (" on its route" if motion is not None else ""))
    return CircleObstacle(c, radius, motion)


def _parse_obstacles(check: _Checker, value: Any, box: tuple[np.ndarray, np.ndarray] | None) -> tuple[Obstacle, ...]:
    if value is None:
        return ()
    if not isinstance(value, list):
        raise check.bad("obstacles", f"expected a list, got {_kind(value)}")
    if len(value) > MAX_OBSTACLES:
        raise check.bad("obstacles", f"at most {MAX_OBSTACLES:,} obstacles, got {len(value):,}")
    vertices = sum(len(o["polygon"]) for o in value
                   if isinstance(o, Mapping) and isinstance(o.get("polygon"), (list, tuple)))
    if vertices > MAX_VERTICES:
        raise check.bad("obstacles", f"at most {MAX_VERTICES:,} polygon vertices in all, got {vertices:,}")
    parsed = [check.attempt(_parse_obstacle, check, o, f"obstacles[{i}]", box) for i, o in enumerate(value)]
    if any(o is None for o in parsed):
        raise _Invalid
    return tuple(parsed)


MAX_FORMATIONS = 64
"""Most formations in one world."""


def _parse_formations(check: _Checker, value: Any) -> tuple[FormationTask, ...]:
    if not isinstance(value, list) or not value:
        check.bad("formations", f"expected a non-empty list of formations, got {_kind(value)}")
        raise _Invalid
    if len(value) > MAX_FORMATIONS:
        check.bad("formations", f"at most {MAX_FORMATIONS} formations, got {len(value):,}")
        raise _Invalid
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
        raise _Invalid
    return tuple(tasks)


_FORMATION_KEYS = {"followers", "comm_range", "spacing", "shape", "offsets"}


def _parse_formation(check: _Checker, value: Any, key: str = "formation") -> FormationSpec:
    problems = len(check.problems)
    body = check.mapping(value, key, _FORMATION_KEYS)
    default = FormationSpec()
    followers = body.get("followers", default.followers)
    if isinstance(followers, bool) or not isinstance(followers, int) or not 0 <= followers <= MAX_FOLLOWERS:
        check.bad(f"{key}.followers", f"expected a whole number from 0 to {MAX_FOLLOWERS}, got {_kind(followers)}")
        followers = None
    comm_range = check.attempt(check.number, body.get("comm_range", default.comm_range), f"{key}.comm_range",
                               positive=True)
    spacing = check.attempt(check.number, body.get("spacing", default.spacing), f"{key}.spacing", positive=True)
    if spacing is not None and comm_range is not None and spacing > comm_range:
        check.bad(f"{key}.spacing", f"spacing {spacing:g} exceeds comm_range {comm_range:g}")
    shape = body.get("shape", default.shape)
    if shape not in ("line", "wedge", "offsets"):
        check.bad(f"{key}.shape", f"expected 'line', 'wedge' or 'offsets', got {_kind(shape)}")
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
        raise _Invalid
    return FormationSpec(followers, comm_range, spacing, shape, offsets)


# -- limits that depend on several values ----------------------------------------------------
def memory_budget() -> int:
    """The peak memory the rasters of one world may take [bytes]: :data:`MEMORY_BUDGET`, or
    ``APF_PHYSICS_MEMORY_BUDGET`` (bytes, or a number with K, M, G or T, binary units).

    Raises:
        UserError: the variable is set to something else.
    """
    text = os.environ.get(MEMORY_BUDGET_VARIABLE, "").strip()
    if not text:
        return MEMORY_BUDGET
    scale = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}.get(text[-1:].upper(), 1)
    number = text[:-1] if scale > 1 else text
    try:
        value = float(number) * scale
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise UserError(f"{MEMORY_BUDGET_VARIABLE}: expected a size such as 8G or 500M, got {_short(text)}")
    return int(value)


def raster_memory(size: Sequence[float], targets: int) -> float:
    """Estimated peak memory [bytes] of the rasters an evaluation of a world builds.

    The physics' clearance raster (8 nodes per unit, float64), the potential and observation
    rasters and the A* grid (4 nodes per unit) over the map and :data:`RASTER_MARGIN` beyond
    it: :data:`RASTER_BYTES_PER_UNIT2` plus :data:`RASTER_BYTES_PER_TARGET` per target, per
    square unit (measured peaks, rounded up).
    """
    area = (float(size[0]) + 2 * RASTER_MARGIN) * (float(size[1]) + 2 * RASTER_MARGIN)
    return area * (RASTER_BYTES_PER_UNIT2 + RASTER_BYTES_PER_TARGET * int(targets))


def raster_memory_problem(size: Sequence[float], targets: int) -> str | None:
    """What to say when the rasters of a map of ``size`` with ``targets`` targets exceed :func:`memory_budget`, else None."""
    need, budget = raster_memory(size, targets), memory_budget()
    if need <= budget:
        return None
    return (f"a {size[0]:g} x {size[1]:g} map with {targets} target(s) needs about {_gib(need)} of rasters "
            f"(the physics' clearance at 8 nodes per unit, the planners' at 4), over the budget of {_gib(budget)}; "
            f"use a smaller map, or set {MEMORY_BUDGET_VARIABLE} (e.g. {math.ceil(need / 2**30)}G) on a machine "
            f"with that much memory")


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def _field_bounds(params: FieldParams, size: tuple[float, float], targets: int,
                  obstacles: int) -> dict[str, tuple[float, float]]:
    """Upper bounds of |U| and |∇U| from each term of the field anywhere the rasters reach.

    ``U_att ≤ katt/2 · T · D²`` and ``|∇U_att| ≤ katt · T · D`` with ``D`` the diagonal of the
    map and margin; ``|U_bh| ≤ kstr/2 · T · ps²``, ``|∇U_bh| ≤ kstr · T · ps``; each repulsive
    term is capped at ``u_max`` and grows only where ``(1/d − 1/p0)² < 2 u_max / krep``, so
    its slope ``krep (1/d − 1/p0) / d²`` stays below ``krep · s · (1/p0 + s)²`` with ``s = √(2 u_max / krep)``.
    """
    with np.errstate(all="ignore"):
        f = {k: np.float64(v) for k, v in params.as_dict().items()}
        reach = np.float64(math.hypot(size[0] + 2 * RASTER_MARGIN, size[1] + 2 * RASTER_MARGIN))
        s = np.sqrt(2 * f["u_max"] / f["krep"]) if f["krep"] > 0 else np.float64(0.0)
        rep_slope = obstacles * f["krep"] * s * (1 / f["p0"] + s) ** 2 if f["krep"] > 0 else np.float64(0.0)
        return {
            "katt": (f["katt"] / 2 * targets * reach**2, f["katt"] * targets * reach),
            "kstr and ps": (f["kstr"] / 2 * targets * f["ps"] ** 2, f["kstr"] * targets * f["ps"]),
            "krep, p0 and u_max": (obstacles * f["u_max"], rep_slope),
        }


def _check_together(check: _Checker, size, robot_radius, goal_tolerance, params, obstacles, targets) -> None:
    """The limits that depend on several values (each checked when its values are valid)."""
    if size is not None:
        if robot_radius is not None and robot_radius >= min(size) / 2:
            check.bad("robot_radius", f"{robot_radius:g} does not fit in the {size[0]:g} x {size[1]:g} map "
                                      "(it must be less than half its shorter side)")
        half_diagonal = math.hypot(*size) / 2
        if goal_tolerance is not None and goal_tolerance >= half_diagonal:
            check.bad("goal_tolerance", f"{goal_tolerance:g} is not less than half the map's diagonal "
                                        f"({half_diagonal:.4g}): nearly every point would count as reached")
    if size is not None and targets is not None:
        problem = raster_memory_problem(size, len(targets))
        if problem:
            check.bad("size", problem)
    if size is not None and targets is not None and params is not None and obstacles is not None:
        bounds = _field_bounds(params, size, len(targets), len(obstacles))
        for index, what in ((0, "|U|"), (1, "the slope of U")):
            worst = max(bounds, key=lambda k: np.nan_to_num(bounds[k][index], nan=np.inf))
            value = bounds[worst][index]
            if not np.isfinite(value) or value > MAX_POTENTIAL:
                shown = f"about {value:.1e}" if np.isfinite(value) else "infinity"
                check.bad("field", f"{what} would reach {shown} on this map (from {worst}); "
                                   f"it must stay below {MAX_POTENTIAL:.0e}")
                break
    if robot_radius is not None and robot_radius < MIN_ROBOT_RADIUS:
        check.bad("robot_radius", f"must be at least {MIN_ROBOT_RADIUS:g} (smaller robots need more than 256 physics "
                                  f"substeps per step), got {robot_radius:g}")
    if goal_tolerance is not None and goal_tolerance < MIN_GOAL_TOLERANCE:
        check.bad("goal_tolerance", f"must be at least {MIN_GOAL_TOLERANCE:g} (the A* grid's spacing), "
                                    f"got {goal_tolerance:g}")


def _check_placement(check: _Checker, world: World) -> None:
    """Targets and starts inside the map and outside the obstacles; starts not yet at a target."""
    size, radius = world.size, world.robot_radius
    for key, pts, margin in (("targets", world.targets, 0.0), ("starts", world.starts, radius)):
        if not len(pts):
            continue
        edge = world.edge_distance(pts)
        inside = np.full(len(pts), np.inf)
        in_map = np.flatnonzero(edge >= margin)
        inside[in_map] = world.obstacle_distance(pts[in_map])
        # (a formation's start is checked against its own target: _check_formations)
        reached = (world.distance_to_target(pts) <= world.goal_tolerance if key == "starts" and not world.formations
                   else np.zeros(len(pts), bool))
        for i in np.flatnonzero((edge < margin) | (inside < margin) | (inside <= 0) | reached).tolist():
            where, at = f"{key}[{i}]", [round(v, 9) for v in world.frame.to_file(pts[i]).tolist()]
            if edge[i] < 0:
                lo, hi = world.frame.to_file([0.0, 0.0]), world.frame.to_file(size)
                check.bad(where, f"{at} is outside the map [{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}]")
            elif edge[i] < margin:
                check.bad(where, f"{at} is closer than the robot radius {radius * world.frame.unit:g} to the map's edge")
            elif inside[i] <= 0:
                check.bad(where, f"{at} is inside an obstacle")
            elif inside[i] < margin:
                check.bad(where, f"{at} is closer than the robot radius {radius * world.frame.unit:g} to an obstacle")
            else:
                check.bad(where, f"{at} is already within goal_tolerance {world.goal_tolerance * world.frame.unit:g} "
                                 "of a target")


def _check_formations(check: _Checker, world: World) -> None:
    """Several formations: their targets and starts placed like the world's, leaders apart."""
    if not world.formations:
        return
    r = world.robot_radius
    for i, task in enumerate(world.formations):
        for what, point, margin in (("target", task.target, 0.0), ("start", task.start, r)):
            clear = float(world.clearance(point[None])[0])
            if clear < margin or clear <= 0:
                check.bad(f"formations[{i}].{what}", f"{point.tolist()} is "
                          + ("not clear of the obstacles and the map's edge by the robot radius" if what == "start"
                             else "inside an obstacle or outside the map"))
        if np.hypot(*(task.start - task.target)) <= world.goal_tolerance:
            check.bad(f"formations[{i}].start", f"already within goal_tolerance {world.goal_tolerance:g} of its target")
        for j in range(i):
            if np.hypot(*(task.start - world.formations[j].start)) < 2 * r:
                check.bad(f"formations[{i}].start", f"overlaps the leader of formations[{j}]")


def _check_routes(check: _Checker, world: World) -> None:
    """Moving obstacles: a route of some length, and no target anywhere they sweep."""
    for i in world.moving:
        obstacle = world.obstacles[i]
        motion = obstacle.motion
        if motion.length <= 1e-9:
            check.bad(f"obstacles[{i}].motion.path", "the route has no length (every offset is [0, 0])")
            continue
        # where the obstacle is along its route, at most 0.05 apart (it moves in straight legs)
        travel = np.linspace(0.0, motion.period, max(2, int(np.ceil(motion.period / 0.05)) + 1))
        offsets = Motion(motion.path, 1.0, motion.loop).offset(travel)
        for k, target in enumerate(world.targets):
            d, _ = obstacle.signed_distance(target[None] - offsets)
            if d.min() <= 0:
                check.bad(f"obstacles[{i}].motion", f"the obstacle sweeps over targets[{k}] {target.tolist()}")


def _parse_robot(check: _Checker, data: Mapping[str, Any]) -> tuple[float | None, float | None]:
    """``(radius, step)`` in file units, from ``robot: {radius, step}`` (or the older ``robot_radius``).

    Unset, the radius is a quarter of the step and the step is one file unit.
    """
    robot = check.attempt(check.mapping, data["robot"], "robot", {"radius", "step"}) if "robot" in data else {}
    if robot is None:
        return None, None
    if "radius" in robot and "robot_radius" in data:
        check.bad("robot_radius", "given twice: write robot: {radius: ...} alone")
    step = check.attempt(check.number, robot.get("step", 1.0), "robot.step", positive=True)
    if "radius" in robot:
        radius = check.attempt(check.number, robot["radius"], "robot.radius", positive=True)
    elif "robot_radius" in data:
        radius = check.attempt(check.number, data["robot_radius"], "robot_radius", positive=True)
    else:
        radius = None if step is None else 0.25 * step
    return radius, step


def _parse_grid(check: _Checker, value: Any, source: str) -> mapfiles.OccupancyMap:
    """The ``grid:`` layer: a ROS map (its YAML with ``map:``, or its keys inline) or a MovingAI map."""
    body = check.mapping(value, "grid", _GRID_KEYS)
    folder = Path(source).parent if source != "<dict>" else Path.cwd()

    def path_of(key: str) -> Path:
        name = body[key]
        if not isinstance(name, str) or not name:
            raise check.bad(f"grid.{key}", f"expected a file name, got {_kind(name)}")
        return (folder / name).resolve()

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
            return mapfiles.read_ros_map(path_of("map"))
        if "image" not in body:
            raise check.bad("grid", "give 'movingai: FILE.map', 'map: FILE.yaml' (a ROS map) or the ROS map keys "
                                    "inline (image, resolution, origin, ...)")
        return mapfiles.ros_map_from_dict({k: v for k, v in body.items()}, str(source), folder)
    except WorldError as exc:   # the map file's own problems, each naming that file
        for line in str(exc).splitlines():
            check.bad("grid", line.removeprefix(f"{source}: "))
        raise _Invalid from None


def _build(check: _Checker, data: Any, source: str) -> World | None:
    if not isinstance(data, Mapping):
        check.bad("", f"a world file must be a mapping of keys, got {_kind(data)}")
        return None
    several = data.get("formations") is not None
    has_grid = data.get("grid") is not None
    required = [k for k in (("field",) if several else ("field", "targets"))] + ([] if has_grid else ["size"])
    check.mapping(data, "", _TOP_KEYS, required=required)
    if several and data.get("formation") is not None:
        check.bad("formation", "'formation' and 'formations' together: give one formation, or a list of them")
    if has_grid and "size" in data:
        check.bad("size", "a world with a grid takes its size from the grid: leave size out")
    grid = check.attempt(_parse_grid, check, data["grid"], source) if has_grid else None
    size = grid.size if grid is not None else (check.attempt(_parse_size, check, data["size"]) if "size" in data else None)
    offset = np.asarray(grid.origin if grid is not None else (0.0, 0.0), float)
    box = (offset, offset + np.asarray(size, float)) if size is not None else None
    default_name = Path(source).stem if source != "<dict>" else "world"
    name = check.attempt(_parse_name, check, data.get("name", default_name))
    robot_radius, step = _parse_robot(check, data)
    frame = Frame((float(offset[0]), float(offset[1])), float(step if step is not None else 1.0))
    goal_tolerance = check.attempt(check.number, data.get("goal_tolerance", 0.75 * frame.unit), "goal_tolerance",
                                   positive=True)
    params = check.attempt(_parse_field, check, data["field"], frame) if "field" in data else None
    obstacles = check.attempt(_parse_obstacles, check, data.get("obstacles"), box)
    targets = (check.attempt(check.points, data["targets"], "targets", at_least=1, at_most=MAX_TARGETS, what="targets")
               if "targets" in data else None)
    starts = check.attempt(check.points, data.get("starts") or [], "starts", at_most=MAX_STARTS, what="starts")
    formation = (check.attempt(_parse_formation, check, data["formation"])
                 if data.get("formation") is not None and not several else None)
    formations = check.attempt(_parse_formations, check, data["formations"]) if several else ()
    if several and formations:   # the formations' own starts and targets, unless also given at the top
        if "targets" not in data:
            targets = np.array([task.target for task in formations])
        if not data.get("starts"):
            starts = np.array([task.start for task in formations])
    # everything in steps, from the map's lower-left corner (README, "Real maps": units)
    u = frame.unit
    to_world = (lambda pts: (np.asarray(pts, float) - offset) / u)
    size = None if size is None else (size[0] / u, size[1] / u)
    robot_radius = None if robot_radius is None else robot_radius / u
    goal_tolerance = None if goal_tolerance is None else goal_tolerance / u
    targets = None if targets is None else to_world(targets)
    starts = None if starts is None else to_world(starts).reshape(-1, 2)
    if obstacles is not None:
        obstacles = tuple(_obstacle_to_world(o, offset, u) for o in obstacles)
        if grid is not None:
            obstacles += (GridObstacle(grid.occupied, grid.cell / u, (0.0, 0.0), spec=_grid_spec(data["grid"], source)),)
    formation = None if formation is None else _formation_to_world(formation, u)
    formations = tuple(FormationTask(to_world(t.start), to_world(t.target), _formation_to_world(t.spec, u))
                       for t in formations or ())
    _check_together(check, size, robot_radius, goal_tolerance, params, obstacles, targets)
    if check.problems:
        return None
    world = World(name, size, robot_radius, goal_tolerance, params, obstacles, targets, starts, formation, source,
                  formations, frame=frame)
    _check_placement(check, world)
    _check_routes(check, world)
    _check_formations(check, world)
    return world


def _grid_spec(value: Mapping[str, Any], source: str) -> dict[str, Any]:
    """The ``grid:`` mapping with its file names made absolute (so a world saved elsewhere still finds them)."""
    folder = Path(source).parent if source != "<dict>" else Path.cwd()
    return {k: (str((folder / v).resolve()) if k in ("image", "map", "movingai") else v) for k, v in value.items()}


def _obstacle_to_world(obstacle: Obstacle, offset: np.ndarray, unit: float) -> Obstacle:
    if unit == 1.0 and not offset.any():
        return obstacle
    motion = obstacle.motion
    if motion is not None:
        motion = Motion(np.asarray(motion.path, float) / unit, motion.speed / unit, motion.loop, motion.phase / unit)
    if isinstance(obstacle, CircleObstacle):
        return CircleObstacle((obstacle.center - offset) / unit, obstacle.radius / unit, motion)
    return PolygonObstacle((obstacle.vertices - offset) / unit, motion)


def _formation_to_world(spec: FormationSpec, unit: float) -> FormationSpec:
    if unit == 1.0:
        return spec
    return replace(spec, comm_range=spec.comm_range / unit, spacing=spec.spacing / unit,
                   offsets=tuple((a / unit, b / unit) for a, b in spec.offsets))


def world_from_dict(data: Any, source: str = "<dict>") -> World:
    """Validate a world-file mapping and build the :class:`World`.

    Raises:
        WorldError: one line per problem (at most :data:`MAX_PROBLEMS`), each naming
            ``source``, the key and what is wrong.
    """
    check = _Checker(source)
    try:
        world = _build(check, data, source)
    except _TooMany:
        world = None
    if check.problems or world is None:
        raise check.error()
    return world


# -- reading files ---------------------------------------------------------------------------
_PARSER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)   # libyaml's parser when PyYAML has it


class _Resolver(yaml.resolver.Resolver):
    """YAML 1.1's implicit types, plus the floats of YAML 1.2 and JSON (``1e-9``, ``2.5E3``), which
    YAML 1.1 would read as strings."""


_Resolver.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789"))
_RESOLVER = _Resolver()
_CONSTRUCTOR = yaml.constructor.SafeConstructor()
_SEQUENCE_TAGS = (None, "!", "tag:yaml.org,2002:seq")
_SCALAR_TAGS = {f"tag:yaml.org,2002:{name}" for name in ("null", "bool", "int", "float", "str", "binary", "timestamp")}
_MERGE = object()  # the key ``<<``: merge the mappings that are its value
_MAPPING_TAGS = (None, "!", "tag:yaml.org,2002:map")


class _YamlLimit(Exception):
    """The text breaks a limit; the message says where and which."""


@dataclass
class _Open:
    """A list or mapping the parser has opened and not yet closed."""

    value: list | dict
    anchor: str | None
    size: int = 1                      # values in it so far, itself included, aliases expanded
    key: Any = None                    # in a mapping: the key waiting for its value
    has_key: bool = False
    merges: list | None = None         # mappings merged in with ``<<``


def _scalar(event: yaml.ScalarEvent) -> Any:
    """The Python value of a scalar, by the safe loader's rules for its tag."""
    tag = event.tag if event.tag not in (None, "!") else _RESOLVER.resolve(yaml.ScalarNode, event.value, event.implicit)
    if tag == "tag:yaml.org,2002:merge":
        return _MERGE
    construct = _CONSTRUCTOR.yaml_constructors.get(tag) if tag in _SCALAR_TAGS else None
    if construct is None:
        raise _YamlLimit(f"line {event.start_mark.line + 1}: unsupported tag {_short(tag)}")
    return construct(_CONSTRUCTOR, yaml.ScalarNode(tag, event.value, event.start_mark, event.end_mark, event.style))


def _load_yaml(text: str) -> Any:
    """The document in ``text``, built from the parser's events with the limits checked as they come.

    What ``yaml.safe_load`` returns (one document; anchors and aliases share one object;
    ``<<`` merges), but nothing is built beyond the limits: nesting deeper than
    :data:`MAX_DEPTH`, a value longer than :data:`MAX_SCALAR_CHARS`, more than
    :data:`MAX_NODES` values with every alias counted as what it expands to (an alias bomb is
    refused after the few events that define it), an alias inside what it names, and a key
    repeated in one mapping (YAML would keep only the last: what was written first would be lost).

    Raises:
        _YamlLimit: a limit is broken or a value cannot be built.
        yaml.YAMLError: ``text`` is not YAML.
    """
    nodes, documents = 0, 0
    stack: list[_Open] = []
    anchors: dict[str, tuple[Any, int]] = {}   # anchor -> (value, values it expands to)
    unfinished: set[str] = set()              # anchors of collections still open
    document: Any = None
    for event in yaml.parse(text, Loader=_PARSER):
        where = f"line {event.start_mark.line + 1}"
        if isinstance(event, yaml.DocumentStartEvent):
            documents += 1
            if documents > 1:
                raise _YamlLimit(f"{where}: a second document; the file must hold one")
            continue
        if isinstance(event, yaml.CollectionStartEvent):
            if len(stack) >= MAX_DEPTH:
                raise _YamlLimit(f"{where}: nested deeper than {MAX_DEPTH} levels")
            mapping = isinstance(event, yaml.MappingStartEvent)
            if event.tag not in (_MAPPING_TAGS if mapping else _SEQUENCE_TAGS):
                raise _YamlLimit(f"{where}: unsupported tag {_short(event.tag)}")
            stack.append(_Open({} if mapping else [], event.anchor))
            if event.anchor:
                unfinished.add(event.anchor)
            continue
        if isinstance(event, yaml.CollectionEndEvent):
            frame = stack.pop()
            value, size, count = frame.value, frame.size, 1   # its contents are counted already
            if frame.merges:  # explicit keys win, then the first merged mapping, then the next
                merged: dict = {}
                for source in reversed(frame.merges):
                    merged.update(source)
                merged.update(value)
                value.clear()
                value.update(merged)
            if frame.anchor:
                anchors[frame.anchor] = (value, size)
                unfinished.discard(frame.anchor)
        elif isinstance(event, yaml.ScalarEvent):
            if len(event.value) > MAX_SCALAR_CHARS:
                raise _YamlLimit(f"{where}: a value of {len(event.value):,} characters (at most {MAX_SCALAR_CHARS:,})")
            value = _scalar(event)
            size = count = 1
            if event.anchor:
                anchors[event.anchor] = (value, 1)
        elif isinstance(event, yaml.AliasEvent):
            name = _key_text(event.anchor)
            if event.anchor in unfinished:
                raise _YamlLimit(f"{where}: alias *{name} is inside the collection it names")
            if event.anchor not in anchors:
                raise _YamlLimit(f"{where}: alias *{name} has no anchor &{name} before it")
            value, size = anchors[event.anchor]
            count = size
        else:  # stream and document ends
            continue
        nodes += count
        if nodes > MAX_NODES:
            raise _YamlLimit(f"{where}: more than {MAX_NODES:,} values (aliases counted as what they expand to)")
        if value is _MERGE and not (stack and isinstance(stack[-1].value, dict) and not stack[-1].has_key):
            raise _YamlLimit(f"{where}: '<<' is only a mapping's key")
        if not stack:
            document = value
            continue
        parent = stack[-1]
        parent.size += size
        if isinstance(parent.value, list):
            parent.value.append(value)
        elif not parent.has_key:
            if value is _MERGE:
                if parent.merges is not None:
                    raise _YamlLimit(f"{where}: key '<<' appears twice in one mapping")
                parent.merges = []
            else:
                try:
                    hash(value)
                except TypeError:
                    raise _YamlLimit(f"{where}: a {type(value).__name__} as a mapping key") from None
                if value in parent.value:
                    raise _YamlLimit(f"{where}: key {_short(value)} appears twice in one mapping")
            parent.key, parent.has_key = value, True
        else:
            if parent.key is _MERGE:
                sources = [value] if isinstance(value, dict) else value
                if not isinstance(sources, list) or not all(isinstance(m, dict) for m in sources):
                    raise _YamlLimit(f"{where}: '<<' merges a mapping or a list of mappings")
                parent.merges.extend(sources)
            else:
                parent.value[parent.key] = value
            parent.has_key = False
    return document


def read_yaml_file(path: str | Path, kind: str, error: type[UserError] = UserError) -> Any:
    """Read a YAML file within the limits, turning every failure into one ``error`` naming the file.

    Args:
        path: The file: a regular file of at most :data:`MAX_FILE_BYTES`.
        kind: What the file is, for messages (``"world"``, ``"curriculum"``).
        error: The exception class to raise.
    """
    source = str(path)
    data = read_regular_file(path, kind, error)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{source}: cannot read the {kind} file (not UTF-8 text: byte {exc.start:,} "
                    f"is {data[exc.start]:#04x})") from None
    try:
        return _load_yaml(text)
    except _YamlLimit as exc:
        raise error(f"{source}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise error(f"{source}: not valid YAML{where}: {_short(getattr(exc, 'problem', None) or exc, 200)}") from None
    except (ValueError, OverflowError, TypeError) as exc:  # a value YAML's constructors reject (a date like 2024-13-45)
        raise error(f"{source}: not valid YAML: {_short(str(exc), 200)}") from None


def load_world(path: str | Path) -> World:
    """Read and validate a world file (YAML, or JSON being YAML).

    Raises:
        WorldError: the file is missing, not a regular file, too large, not YAML, or breaks
            the contract (every problem, one line each).
    """
    path = resolve_world(path)
    if Path(path).suffix.lower() == ".map":
        raise WorldError(f"{path}: a MovingAI map alone has no target: evaluate its scenarios with "
                         f"`apf-physics eval {path} --scen {path}.scen`, or write a world file with "
                         f"'grid: {{movingai: {Path(path).name}}}' and targets")
    data = read_yaml_file(path, "world", WorldError)
    if isinstance(data, Mapping) and "image" in data and "resolution" in data:
        raise WorldError(f"{path}: a ROS map alone has no target: write a world file with "
                         f"'grid: {{map: {Path(path).name}}}', robot: {{radius, step}}, a field and targets")
    return world_from_dict(data, str(path))


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
