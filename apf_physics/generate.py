"""Random worlds where gradient descent tends to get trapped, for training and held-out tests.

Every family places its obstacles between the starts and the target, which is where APF
local minima arise (thesis Fig. 1): the target is drawn first, then an axis ``u`` pointing
from the target toward where the starts will be; the obstacles sit across that axis a few
units from the target, and the starts behind them (seen from the target), spread around the
axis.

Families (:data:`FAMILIES`):

- ``point``: one point obstacle (a circle of radius 0), the thesis's basic learning.
- ``line``: one line-shaped obstacle (a thin rectangle) across the axis.
- ``two_points``: two point obstacles either side of the axis, a gap of 1.5–4 units between.
- ``concave``: a U-shaped cup whose opening faces the starts.
- ``bent_line``: two line-shaped obstacles, one bent (a V or L whose inside faces the starts).
- ``clutter``: 5–10 mixed obstacles (discs, points, lines, boxes) scattered around the axis.
- ``moving``: one of the families above plus 3–8 moving obstacles (discs and boxes) whose
  routes cross the axis between the starts and the target, at 0.15–0.6 units per step:
  back and forth across it, or round a loop through three points.
- ``crossing``: 2–4 formations of 3 robots (a line or a wedge) whose routes cross near the
  middle of the map, each from its start to a target across it, among 2–4 obstacles kept
  off the crossing (the world file's ``formations:``).

Structure families (:data:`STRUCTURE_FAMILIES`, issue 12): larger structures than the ones
above, for testing whether a planner generalises. They use a robot of radius 0.3
(:data:`STRUCTURE_ROBOT_RADIUS`); every start is out of the target's sight (the straight
segment to it comes within the robot's radius of an obstacle: the start is behind a
structure as seen from the target, where gradient descent is trapped about nine times in
ten) and its A* path is shorter than :data:`PATH_SHARE` of the default step limit
(:func:`step_limit`, 4 x (width + height): shorter than 240 on a 50 x 50 map, 480 on a
100 x 100 one).

- ``rooms``: a building of 2 up to 4 x 4 rooms (6 x 6 on a 100 x 100 map), 7–16 units
  across, with jittered walls and 1.6–3.2 wide doors at random places in them (a random
  spanning tree of doors, extra doors that make loops, now and then a wall left out);
  either filling the map (the map's edge its outside wall) or a smaller building, turned
  at times, with 1–3 outside doors. The target in a room (now and then outside, by a
  wall), the starts in the other rooms or outside.
- ``maze``: a grid maze drawn by a depth-first walk (long corridors) or by Kruskal's
  algorithm (many short dead ends), 5–30 % of its remaining inner walls removed to make
  loops; cells of 3–6 units (3.5–8 on a 100 x 100 map; larger where there would be more
  than 10 a side, 12 on a 100 x 100 map); filling the map or a smaller block, turned at
  times, with 1–3 gates. The target and most starts in cells.
- ``nested_cups``: two or three nested cups around the target, openings alternating
  (opposite sides, now and then a quarter turn): U-shaped or with a partial opening,
  rectangular or round, 1.8–4 units apart (up to 5.7 on a 100 x 100 map), at any
  orientation. Starts outside the nest or between its cups.
- ``narrow_gap``: one straight wall from edge to edge across the map between the target and
  the starts, 0.3–1 thick, at any angle, with a single gap 1.3–1.8 wide somewhere along it.
- ``dense_clutter``: 18–32 polygons (27–49 on a 100 x 100 map): random convex polygons,
  boxes, bars and L-shapes, overlapping at times, around the target and between it and the
  starts.
- ``mixed``: several blocks on one map, each a small building of rooms, a nest of cups or a
  patch of clutter (2–3 blocks on a 50 x 50 map, 3–5 on a 100 x 100 one); the target in a
  building or a nest, the starts mostly in or by the other blocks. The issue's "100 x 100
  worlds mixing cups, rooms and clutter" are ``--family mixed --size 100``.

They work at any ``--size`` from 20 up (``mixed`` from 40). On bigger maps a building has
more rooms and a maze more cells rather than stretched walls: doors, gaps and corridors
keep their widths, which the robot's size sets; the nest, the clutter and the distance to
the starts grow with the map. A world takes well under a second on a 50 x 50 map and
0.3–4 s on a 100 x 100 one (most of it in the reachability grid: one clearance per grid
node and obstacle).

Every world goes through :func:`~apf_physics.worldfile.world_from_dict` (so it honours the
world-file contract), and every start is reachable: a path with the robot's clearance
exists (:func:`apf_physics.search.reachable`). Generation is deterministic for a seed.

:func:`generate_world` is fast enough for domain randomisation during training (no
rollouts); :func:`apf_physics.worldsets.generate_set` writes files and a manifest that
labels each start with whether gradient descent reaches the target from it and the A* path
length.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from apf_physics import geometry
from apf_physics.errors import UserError
from apf_physics.field import FIELD_PRESETS
from apf_physics.search import SearchGrid, reachable
from apf_physics.world import World
from apf_physics.worldfile import world_from_dict

FAMILIES = ("point", "line", "two_points", "concave", "bent_line", "clutter")
"""The families of static worlds the thesis's general curriculum and the project's general recipes train on."""
STATIC_FAMILIES = FAMILIES
MOVING_FAMILIES = ("moving",)
FORMATION_FAMILIES = ("crossing",)
STRUCTURE_FAMILIES = ("rooms", "maze", "nested_cups", "narrow_gap", "dense_clutter", "mixed")
"""Larger structures (issue 12): rooms, mazes, nested cups, a narrow gap, dense clutter, and a mix of them."""
ALL_FAMILIES = FAMILIES + MOVING_FAMILIES + FORMATION_FAMILIES + STRUCTURE_FAMILIES
"""Every family :func:`generate_world` draws."""

ROBOT_RADIUS = 0.25
# ≥ √2/2: a robot moving in unit steps (Model Table 1) from any start passes within √2/2 of
# every point, so every target is reachable within this tolerance (0.5 is only from aligned starts).
GOAL_TOLERANCE = 0.75
START_CLEARANCE = 0.75   # starts keep this clearance from obstacles and the map's edge [units]
MAX_ATTEMPTS = 200       # worlds drawn per requested world before giving up


# ---------------------------------------------------------------------------------------
# Shapes, in a frame: origin ``c``, axis ``u`` (toward the starts), ``v`` = u rotated +90°
# ---------------------------------------------------------------------------------------

def _thick_polyline(points: np.ndarray, thickness: float) -> np.ndarray:
    """A simple polygon of the given thickness around an open polyline of 2 or 3 points.

    Consecutive segments are joined with a mitre on the outside of the bend, so a bent line
    stays a simple polygon for bend angles of up to about 150°.
    """
    points = np.asarray(points, float)
    half = thickness / 2
    dirs = np.diff(points, axis=0)
    dirs /= np.hypot(dirs[:, 0], dirs[:, 1])[:, None]
    normals = np.column_stack([-dirs[:, 1], dirs[:, 0]])
    left, right = [], []
    for k, p in enumerate(points):
        if k == 0:
            n = normals[0]
            left.append(p + half * n)
            right.append(p - half * n)
        elif k == len(points) - 1:
            n = normals[-1]
            left.append(p + half * n)
            right.append(p - half * n)
        else:
            # Mitre joint: offset along the bisector of the two normals.
            bis = normals[k - 1] + normals[k]
            bis /= np.hypot(*bis)
            scale = half / max(np.dot(bis, normals[k]), 0.2)
            left.append(p + scale * bis)
            right.append(p - scale * bis)
    return np.vstack([left, right[::-1]])


def _frame(c: np.ndarray, u: np.ndarray, a: float, b: float) -> np.ndarray:
    """World point ``c + a·u + b·v``."""
    v = np.array([-u[1], u[0]])
    return c + a * u + b * v


def _line(rng: np.random.Generator, c: np.ndarray, u: np.ndarray, length: tuple[float, float]) -> dict:
    """A straight thin line centred at ``c``, roughly across ``u`` (tilted up to 30°)."""
    half = rng.uniform(*length) / 2
    tilt = rng.uniform(-math.pi / 6, math.pi / 6)
    along = np.array([math.cos(tilt), math.sin(tilt)])  # in (u, v) coordinates, mostly along v
    a = _frame(c, u, -half * along[1], -half * along[0])
    b = _frame(c, u, half * along[1], half * along[0])
    return {"polygon": _thick_polyline(np.array([a, b]), rng.uniform(0.3, 0.6)).tolist()}


def _bent(rng: np.random.Generator, c: np.ndarray, u: np.ndarray, arm: tuple[float, float]) -> dict:
    """A bent thin line (V or L) with its apex at ``c`` pointing at the target, arms toward the starts."""
    opening = math.radians(rng.uniform(60, 150))    # angle between the two arms
    skew = rng.uniform(-0.3, 0.3)
    arms = []
    for sign in (-1, 1):
        angle = sign * opening / 2 + skew
        length = rng.uniform(*arm)
        arms.append(_frame(c, u, length * math.cos(angle), length * math.sin(angle)))
    return {"polygon": _thick_polyline(np.array([arms[0], c, arms[1]]), rng.uniform(0.3, 0.6)).tolist()}


def _cup(rng: np.random.Generator, c: np.ndarray, u: np.ndarray) -> dict:
    """A U-shaped cup: back wall across ``u`` at ``c``, arms reaching toward the starts."""
    width = rng.uniform(6, 14)
    depth = rng.uniform(3, 8)
    t = rng.uniform(0.5, 1.0)
    w = width / 2
    # (a, b) in the frame; the opening is at a = +depth (toward the starts).
    outline = [(0, -w), (depth, -w), (depth, -w + t), (t, -w + t), (t, w - t), (depth, w - t), (depth, w), (0, w)]
    return {"polygon": [_frame(c, u, a, b).tolist() for a, b in outline]}


def _disc(center: np.ndarray, radius: float) -> dict:
    return {"circle": {"center": [float(center[0]), float(center[1])], "radius": float(radius)}}


def _box(rng: np.random.Generator, c: np.ndarray) -> dict:
    w, h = rng.uniform(0.5, 4, size=2)
    angle = rng.uniform(0, math.pi)
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2
    return {"polygon": (c + corners @ rot.T).tolist()}


def _obstacles(family: str, rng: np.random.Generator, target: np.ndarray, u: np.ndarray,
               gap: float) -> list[dict]:
    """The family's obstacles, ``gap`` units from the target along ``u``."""
    c = target + gap * u
    if family == "point":
        return [_disc(c, 0.0)]
    if family == "line":
        return [_line(rng, c, u, (6, 16))]
    if family == "two_points":
        half = rng.uniform(1.5, 4) / 2
        shift = rng.uniform(-1, 1)
        return [_disc(_frame(c, u, 0, shift - half), 0.0), _disc(_frame(c, u, 0, shift + half), 0.0)]
    if family == "concave":
        return [_cup(rng, c, u)]
    if family == "bent_line":
        bent = _bent(rng, c, u, (4, 9))
        side = rng.choice([-1, 1])
        straight = _line(rng, _frame(c, u, rng.uniform(3, 8), side * rng.uniform(6, 11)), u, (4, 10))
        return [bent, straight]
    if family == "clutter":
        out = []
        for _ in range(int(rng.integers(5, 11))):
            p = _frame(c, u, rng.uniform(-3, 10), rng.uniform(-8, 8))
            kind = rng.choice(["point", "disc", "line", "box"], p=[0.25, 0.3, 0.25, 0.2])
            if kind == "point":
                out.append(_disc(p, 0.0))
            elif kind == "disc":
                out.append(_disc(p, rng.uniform(0.3, 2.0)))
            elif kind == "line":
                out.append(_line(rng, p, u, (3, 8)))
            else:
                out.append(_box(rng, p))
        return out
    raise UserError(f"--family: unknown family {family!r} (known: {', '.join(FAMILIES)})")


def _movers(rng: np.random.Generator, target: np.ndarray, u: np.ndarray, gap: float, scale: float) -> list[dict]:
    """3–8 moving obstacles whose routes cross the axis between the starts and the target."""
    v = np.array([-u[1], u[0]])
    out = []
    for _ in range(int(rng.integers(3, 9))):
        centre = target + rng.uniform(2.5, gap + 12) * scale * u
        speed = float(rng.uniform(0.15, 0.6))
        if rng.random() < 0.6:   # back and forth across the axis
            half = rng.uniform(3, 8) * scale
            shift = rng.uniform(-1, 1) * half
            first = centre + (shift - half) * v
            path = [(2 * half * v).tolist()]
            loop, length = False, 4 * half
        else:                    # round a loop through three points around the crossing
            corners = [centre + rng.uniform(2, 6) * scale * np.array([math.cos(a), math.sin(a)])
                       for a in rng.uniform(0, 2 * math.pi) + np.array([0.0, 2.1, 4.2]) + rng.uniform(-0.3, 0.3, 3)]
            first = corners[0]
            path = [(corners[1] - first).tolist(), (corners[2] - first).tolist()]
            loop = True
            length = sum(np.hypot(*(corners[(i + 1) % 3] - corners[i])) for i in range(3))
        motion = {"path": path, "speed": speed, "phase": float(rng.uniform(0, length))}
        if loop:
            motion["loop"] = True
        if rng.random() < 0.6:
            shape = _disc(first, rng.uniform(0.4, 1.2))
        else:
            w, h = rng.uniform(0.6, 2.5), rng.uniform(0.4, 1.0)
            angle = rng.uniform(0, math.pi)
            rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
            shape = {"polygon": (first + (np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2) @ rot.T).tolist()}
        out.append({**shape, "motion": motion})
    return out


def _route_points(obstacle: dict) -> np.ndarray:
    """The obstacle's outline points at every vertex of its route (bounds everywhere it goes)."""
    if "polygon" in obstacle:
        outline = np.asarray(obstacle["polygon"], float)
    else:
        c, r = np.asarray(obstacle["circle"]["center"], float), obstacle["circle"]["radius"]
        outline = c + r * np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], float)
    offsets = np.vstack([[0.0, 0.0], np.asarray(obstacle.get("motion", {}).get("path", []), float).reshape(-1, 2)])
    return (outline[None] + offsets[:, None]).reshape(-1, 2)


def _inside(obstacle: dict, size: float, pad: float) -> bool:
    pts = _route_points(obstacle)
    return bool(pts.min() >= pad and pts.max() <= size - pad)


def _clear_of_target(obstacle: dict, target: np.ndarray, room: float) -> bool:
    """Whether a moving obstacle's swept region stays ``room`` away from the target (its bounding box does)."""
    if "motion" not in obstacle:
        return True
    pts = _route_points(obstacle)
    lo, hi = pts.min(axis=0) - room, pts.max(axis=0) + room
    return not bool(np.all((target >= lo) & (target <= hi)))


def _round(value: Any) -> Any:
    """Round coordinates to 3 decimals so written files read back to the same world."""
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, list):
        return [_round(v) for v in value]
    if isinstance(value, dict):
        return {k: _round(v) for k, v in value.items()}
    return value


def generate_world(family: str, rng: np.random.Generator, size: float = 50, field: str = "thesis-general",
                   n_starts: int = 4, name: str | None = None) -> World:
    """Draw one world of ``family`` with ``n_starts`` reachable starts behind its obstacles.

    Fast (no rollouts, only the reachability check), so training can call it for domain
    randomisation.

    Args:
        family: One of :data:`ALL_FAMILIES`.
        rng: The random generator (the world is a deterministic function of its state).
        size: Width and height of the square map [units].
        field: A field preset name from :data:`~apf_physics.world.FIELD_PRESETS`.
        n_starts: Number of starts.
        name: The world's name (default: the family's name).

    Raises:
        UserError: unknown family or field preset, or no valid world found in
            :data:`MAX_ATTEMPTS` draws (the map is too small for the family).
    """
    if family not in ALL_FAMILIES:
        raise UserError(f"--family: unknown family {family!r} (known: {', '.join(ALL_FAMILIES)})")
    if family == "crossing":
        return _crossing_world(rng, float(size), field, name)
    if field not in FIELD_PRESETS:
        raise UserError(f"--field: unknown field preset {field!r} (known: {', '.join(FIELD_PRESETS)})")
    if family in STRUCTURE_FAMILIES:
        return _structure_world(family, rng, float(size), field, n_starts, name)
    size = float(size)
    scale = size / 50.0  # distances below are for a 50 x 50 map
    for _ in range(MAX_ATTEMPTS):
        target = rng.uniform(0.1 * size, 0.9 * size, size=2)
        angle = rng.uniform(0, 2 * math.pi)
        u = np.array([math.cos(angle), math.sin(angle)])
        gap = rng.uniform(5, 12) * scale
        if family == "moving":
            base = STATIC_FAMILIES[int(rng.integers(len(STATIC_FAMILIES)))]
            obstacles = _obstacles(base, rng, target, u, gap) + _movers(rng, target, u, gap, scale)
        else:
            obstacles = _obstacles(family, rng, target, u, gap)
        if not all(_inside(o, size, 0.5) and _clear_of_target(o, target, 1.5) for o in obstacles):
            continue
        data = {
            "name": name or family,
            "size": [size, size],
            "robot_radius": ROBOT_RADIUS,
            "goal_tolerance": GOAL_TOLERANCE,
            "field": field,
            "obstacles": _round(obstacles),
            "targets": _round([target.tolist()]),
            "starts": [],
        }
        try:
            bare = world_from_dict(data, source=f"<generated {family}>")
        except UserError:
            continue  # e.g. the target landed inside an obstacle
        starts = _draw_starts(bare, rng, target, u, gap, n_starts, scale, reachable)
        if starts is None:
            continue
        data["starts"] = _round(starts.tolist())
        return world_from_dict(data, source=f"<generated {family}>")
    raise UserError(f"no valid {family!r} world found in {MAX_ATTEMPTS} draws on a {size:g} x {size:g} map")


def _draw_starts(world: World, rng: np.random.Generator, target: np.ndarray, u: np.ndarray, gap: float,
                 count: int, scale: float, reachable: Callable[[World, np.ndarray], bool]) -> np.ndarray | None:
    """Starts behind the obstacles seen from the target, free and reachable; None if too few."""
    out: list[np.ndarray] = []
    for _ in range(30 * max(count, 1)):
        if len(out) == count:
            break
        behind = gap + rng.uniform(2, 14) * scale
        p = _frame(target, u, behind, rng.normal(0, 3.5 * scale))
        p = np.round(p, 3)
        if world.clearance(p[None])[0] < START_CLEARANCE:
            continue
        if np.hypot(*(p - target)) <= 2 * world.goal_tolerance:
            continue
        if any(np.hypot(*(p - q)) < 1.0 for q in out):
            continue
        if not reachable(world, p):
            continue
        out.append(p)
    return np.array(out).reshape(-1, 2) if len(out) == count else None


def _crossing_world(rng: np.random.Generator, size: float, field: str, name: str | None) -> World:
    """2–4 formations whose straight routes cross near the middle, among a few obstacles off the crossing."""
    scale = size / 50.0
    for _ in range(MAX_ATTEMPTS):
        centre = size / 2 + rng.uniform(-4, 4, 2) * scale
        count = int(rng.integers(2, 5))
        angles = rng.uniform(0, 2 * math.pi) + np.arange(count) * 2 * math.pi / count + rng.uniform(-0.3, 0.3, count)
        formations, ends = [], []
        for angle in angles:
            u = np.array([math.cos(angle), math.sin(angle)])
            v = np.array([-u[1], u[0]])
            start = centre + rng.uniform(15, 20) * scale * u + rng.uniform(-2, 2) * scale * v
            target = centre - rng.uniform(15, 20) * scale * u + rng.uniform(-2, 2) * scale * v
            shape = "line" if rng.random() < 0.5 else "wedge"
            formations.append({"start": np.round(start, 3).tolist(), "target": np.round(target, 3).tolist(),
                               "followers": 2, "shape": shape, "spacing": 1.0, "comm_range": 3.0})
            ends += [start, target]
        ends = np.array(ends)
        if ends.min() < 3 or ends.max() > size - 3:
            continue
        if np.min(np.hypot(*(ends[:, None] - ends[None]).transpose(2, 0, 1)) + 99 * np.eye(len(ends))) < 4:
            continue
        obstacles = []
        for _ in range(int(rng.integers(2, 5))):
            p = centre + rng.uniform(-14, 14, 2) * scale
            if np.hypot(*(p - centre)) < 5 * scale or np.min(np.hypot(*(ends - p).T)) < 5:
                continue   # off the crossing, and off every start and target
            obstacles.append(_disc(p, rng.uniform(0.5, 2.0)) if rng.random() < 0.5 else _box(rng, p))
        if not all(_inside(o, size, 0.5) for o in obstacles):
            continue
        data = {"name": name or "crossing", "size": [size, size], "robot_radius": ROBOT_RADIUS,
                "goal_tolerance": GOAL_TOLERANCE, "field": field, "obstacles": _round(obstacles),
                "formations": formations}
        try:
            world = world_from_dict(data, source="<generated crossing>")
        except UserError:
            continue
        if all(world.clearance(task.start[None])[0] >= 2.0 and reachable(world.formation_world(f), task.start)
               for f, task in enumerate(world.formations)):
            return world
    raise UserError(f"no valid 'crossing' world found in {MAX_ATTEMPTS} draws on a {size:g} x {size:g} map")


# ---------------------------------------------------------------------------------------
# Structure families (issue 12): rooms, mazes, nested cups, a narrow gap, dense clutter, a mix
# ---------------------------------------------------------------------------------------

STRUCTURE_ROBOT_RADIUS = 0.3
"""The robot's radius in the structure families (the issue's measurements used 0.3)."""
PATH_SHARE = 0.6
"""Every start of a structure world has an A* path shorter than this share of :func:`step_limit`."""
DOOR_WIDTH = (1.6, 3.2)     # doors between rooms [units]
GAP_WIDTH = (1.3, 1.8)      # the narrow gap [units]
CUP_SPACING = (1.8, 4.0)    # free width between nested cups [units]
TARGET_CLEARANCE = 1.0      # the target keeps this clearance from obstacles [units]
START_SPACING = 2.0         # starts of one world keep this far apart [units]


def step_limit(size: float) -> int:
    """The default step limit of an episode on a ``size`` x ``size`` map.

    The same rule as :func:`apf_physics.rollout.default_max_steps` (four times width plus
    height: 400 steps on a 50 x 50 map, 800 on a 100 x 100 one), which this module cannot
    import (it sits below the rollout in the package's layers); a test keeps the two equal.
    """
    return int(4 * (size + size))


class _Frame:
    """A placement: local points ``p`` go to ``origin + R(angle) p``."""

    def __init__(self, origin: np.ndarray, angle: float):
        self.origin = np.asarray(origin, float)
        self.rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])

    def __call__(self, points: np.ndarray) -> np.ndarray:
        return self.origin + np.asarray(points, float) @ self.rot.T


def _box_corners(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)


def _rotated_extent(w: float, h: float, angle: float) -> np.ndarray:
    """Width and height of the bounding box of a ``w`` x ``h`` box turned by ``angle``."""
    c, s = abs(math.cos(angle)), abs(math.sin(angle))
    return np.array([w * c + h * s, w * s + h * c])


def _fit_frame(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, angle: float, size: float,
               pad: float) -> _Frame | None:
    """A frame at ``angle`` putting the local box [lo, hi] at a random place in the map, ``pad`` from its edge."""
    corners = _box_corners(lo[0], hi[0], lo[1], hi[1])
    turned = corners @ _Frame(np.zeros(2), angle).rot.T
    low, high = turned.min(axis=0), turned.max(axis=0)
    room = (size - 2 * pad) - (high - low)
    if np.any(room < 0):
        return None
    origin = pad - low + rng.uniform(0, 1, 2) * room
    return _Frame(origin, angle)


def _wall_pieces(extent: tuple[float, float], holes: list[tuple[float, float]], shortest: float = 0.5
                 ) -> list[tuple[float, float]]:
    """The intervals of ``extent`` left once ``holes`` are cut out (pieces shorter than ``shortest`` dropped)."""
    pieces, at = [], extent[0]
    for lo, hi in sorted(holes):
        if lo > at:
            pieces.append((at, min(lo, extent[1])))
        at = max(at, hi)
    if at < extent[1]:
        pieces.append((at, extent[1]))
    return [(a, b) for a, b in pieces if b - a >= shortest]


def _merge(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Overlapping or touching intervals joined."""
    out: list[list[float]] = []
    for lo, hi in sorted(intervals):
        if out and lo <= out[-1][1] + 1e-9:
            out[-1][1] = max(out[-1][1], hi)
        else:
            out.append([lo, hi])
    return [(a, b) for a, b in out]


def _line_walls(xs: np.ndarray, ys: np.ndarray, t: float, vertical: dict[int, list[tuple[float, float]]],
                horizontal: dict[int, list[tuple[float, float]]]) -> list[np.ndarray]:
    """Rectangles of thickness ``t`` along grid lines: ``vertical[i]`` are the solid intervals (in y) on x = xs[i]."""
    out = []
    for i, pieces in vertical.items():
        out += [_box_corners(xs[i] - t / 2, xs[i] + t / 2, a, b) for a, b in pieces]
    for j, pieces in horizontal.items():
        out += [_box_corners(a, b, ys[j] - t / 2, ys[j] + t / 2) for a, b in pieces]
    return out


def _spanning_tree(rng: np.random.Generator, n: int, edges: list[tuple[int, int]]) -> set[int]:
    """Indices of the edges of a random spanning forest of ``n`` nodes (Kruskal's algorithm, random order)."""
    parent = list(range(n))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    tree = set()
    for k in rng.permutation(len(edges)).tolist():
        a, b = root(edges[k][0]), root(edges[k][1])
        if a != b:
            parent[a] = b
            tree.add(k)
    return tree


class _Block:
    """A structure placed on the map: its wall polygons and the regions where targets and starts go.

    Attributes:
        polygons: Wall polygons, world coordinates.
        spots: Local boxes ``(x0, x1, y0, y1)`` (rooms, cells, a cup's inside) in ``frame``.
        frame: Local to world.
        inner: Index in ``spots`` of the place for a target (a room, a cell, the innermost cup).
        outer: Local box the structure covers (for keeping blocks apart and drawing starts).
    """

    def __init__(self, polygons: list[np.ndarray], spots: list[tuple[float, float, float, float]], frame: _Frame,
                 inner: int, outer: tuple[float, float, float, float]):
        self.polygons, self.spots, self.frame, self.inner, self.outer = polygons, spots, frame, inner, outer

    def point_in(self, rng: np.random.Generator, k: int, margin: float) -> np.ndarray | None:
        """A random point of spot ``k``, ``margin`` inside its box (None if the box is too small)."""
        x0, x1, y0, y1 = self.spots[k]
        if x1 - x0 < 2 * margin or y1 - y0 < 2 * margin:
            return None
        local = np.array([rng.uniform(x0 + margin, x1 - margin), rng.uniform(y0 + margin, y1 - margin)])
        return self.frame(local[None])[0]

    def around(self, rng: np.random.Generator, reach: float) -> np.ndarray:
        """A random point of the local box ``outer`` grown by ``reach``."""
        x0, x1, y0, y1 = self.outer
        local = np.array([rng.uniform(x0 - reach, x1 + reach), rng.uniform(y0 - reach, y1 + reach)])
        return self.frame(local[None])[0]


def _rooms_block(rng: np.random.Generator, w: float, h: float, frame: _Frame, outer: bool, most: int) -> _Block:
    """A building of rooms in the local box [0, w] x [0, h] (with outside walls if ``outer``)."""
    t = rng.uniform(0.3, 0.7)
    room = rng.uniform(7, 16)
    nx = int(np.clip(round(w / room), 1, most))
    ny = int(np.clip(round(h / rng.uniform(0.7, 1.4) / room), 1, most))
    if nx * ny < 2:
        nx = 2
    xs = np.linspace(0, w, nx + 1)
    ys = np.linspace(0, h, ny + 1)
    xs[1:-1] += rng.uniform(-0.2, 0.2, nx - 1) * w / nx
    ys[1:-1] += rng.uniform(-0.2, 0.2, ny - 1) * h / ny
    # Walls between neighbouring rooms: (vertical?, line, segment, room a, room b).
    walls = [(True, i, j, j * nx + i - 1, j * nx + i) for i in range(1, nx) for j in range(ny)]
    walls += [(False, j, i, (j - 1) * nx + i, j * nx + i) for j in range(1, ny) for i in range(nx)]
    tree = _spanning_tree(rng, nx * ny, [(a, b) for _, _, _, a, b in walls])
    p_door = rng.uniform(0.05, 0.4)
    holes: dict[tuple[bool, int], list[tuple[float, float]]] = {}

    def cut(vertical: bool, line: int, seg: int, whole: bool) -> None:
        cuts = ys if vertical else xs
        a, b = cuts[seg] + t / 2, cuts[seg + 1] - t / 2
        width = rng.uniform(*DOOR_WIDTH)
        if whole or b - a - 1.2 < width:
            hole = (a, b)
        else:
            lo = rng.uniform(a + 0.6, b - 0.6 - width)
            hole = (lo, lo + width)
        holes.setdefault((vertical, line), []).append(hole)

    for k, (vertical, line, seg, _, _) in enumerate(walls):
        u = rng.random()
        if k in tree:
            cut(vertical, line, seg, whole=u < 0.1)
        elif u < p_door:
            cut(vertical, line, seg, whole=False)
    lines_v = list(range(nx + 1)) if outer else list(range(1, nx))
    lines_h = list(range(ny + 1)) if outer else list(range(1, ny))
    if outer:   # 1-3 doors to the outside
        sides = [(True, 0, j) for j in range(ny)] + [(True, nx, j) for j in range(ny)]
        sides += [(False, 0, i) for i in range(nx)] + [(False, ny, i) for i in range(nx)]
        for k in rng.choice(len(sides), size=min(len(sides), int(rng.integers(1, 4))), replace=False).tolist():
            cut(*sides[k], whole=False)
    pad = t / 2 if outer else 0.0
    vertical = {i: _wall_pieces((ys[0] - pad, ys[-1] + pad), holes.get((True, i), [])) for i in lines_v}
    horizontal = {j: _wall_pieces((xs[0] - pad, xs[-1] + pad), holes.get((False, j), [])) for j in lines_h}
    polygons = [frame(p) for p in _line_walls(xs, ys, t, vertical, horizontal)]
    spots = [(xs[i] + t / 2, xs[i + 1] - t / 2, ys[j] + t / 2, ys[j + 1] - t / 2) for j in range(ny) for i in range(nx)]
    return _Block(polygons, spots, frame, int(rng.integers(len(spots))), (0.0, w, 0.0, h))


def _maze_block(rng: np.random.Generator, nx: int, ny: int, cx: float, cy: float, frame: _Frame,
                outer: bool) -> _Block:
    """A grid maze of ``nx`` x ``ny`` cells of ``cx`` x ``cy`` in the local box [0, nx·cx] x [0, ny·cy]."""
    t = rng.uniform(0.3, 0.7)
    xs, ys = np.arange(nx + 1) * cx, np.arange(ny + 1) * cy
    walls = [(True, i, j, j * nx + i - 1, j * nx + i) for i in range(1, nx) for j in range(ny)]
    walls += [(False, j, i, (j - 1) * nx + i, j * nx + i) for j in range(1, ny) for i in range(nx)]
    pairs = [(a, b) for _, _, _, a, b in walls]
    if rng.random() < 0.5:
        open_ = _spanning_tree(rng, nx * ny, pairs)
    else:   # depth-first walk: long winding corridors
        neighbours: dict[int, list[tuple[int, int]]] = {}
        for k, (a, b) in enumerate(pairs):
            neighbours.setdefault(a, []).append((b, k))
            neighbours.setdefault(b, []).append((a, k))
        first = int(rng.integers(nx * ny))
        seen, stack, open_ = {first}, [first], set()
        while stack:
            options = [(c, k) for c, k in neighbours.get(stack[-1], []) if c not in seen]
            if not options:
                stack.pop()
                continue
            c, k = options[int(rng.integers(len(options)))]
            open_.add(k)
            seen.add(c)
            stack.append(c)
    p_loop = rng.uniform(0.05, 0.3)
    loops = rng.random(len(walls)) < p_loop
    segments: dict[tuple[bool, int], list[tuple[float, float]]] = {}
    for k, (vertical, line, seg, _, _) in enumerate(walls):
        if k not in open_ and not loops[k]:
            cuts = ys if vertical else xs
            segments.setdefault((vertical, line), []).append((cuts[seg] - t / 2, cuts[seg + 1] + t / 2))
    if outer:   # the outside wall, with 1-3 entrances of one cell each
        sides = [(True, 0, j) for j in range(ny)] + [(True, nx, j) for j in range(ny)]
        sides += [(False, 0, i) for i in range(nx)] + [(False, ny, i) for i in range(nx)]
        gates = set(rng.choice(len(sides), size=int(rng.integers(1, 4)), replace=False).tolist())
        for k, (vertical, line, seg) in enumerate(sides):
            if k not in gates:
                cuts = ys if vertical else xs
                segments.setdefault((vertical, line), []).append((cuts[seg] - t / 2, cuts[seg + 1] + t / 2))
    span_y, span_x = (ys[0], ys[-1]), (xs[0], xs[-1])
    if outer:
        span_y, span_x = (ys[0] - t / 2, ys[-1] + t / 2), (xs[0] - t / 2, xs[-1] + t / 2)

    def clip(pieces: list[tuple[float, float]], span: tuple[float, float]) -> list[tuple[float, float]]:
        return [(max(a, span[0]), min(b, span[1])) for a, b in _merge(pieces)]

    vertical = {i: clip(p, span_y) for (v, i), p in segments.items() if v}
    horizontal = {j: clip(p, span_x) for (v, j), p in segments.items() if not v}
    polygons = [frame(p) for p in _line_walls(xs, ys, t, vertical, horizontal)]
    spots = [(xs[i] + t / 2, xs[i + 1] - t / 2, ys[j] + t / 2, ys[j + 1] - t / 2) for j in range(ny) for i in range(nx)]
    return _Block(polygons, spots, frame, int(rng.integers(len(spots))), (0.0, xs[-1], 0.0, ys[-1]))


def _cup_outline(rng: np.random.Generator, ax: float, ay: float, side: int, round_: bool) -> np.ndarray:
    """The centre line of a cup around the origin (half-extents ``ax``, ``ay``) open on ``side`` (0 = +x, 1 = +y, ...).

    U-shaped (the whole side open) or with a partial opening (at least 1.8 wide) at a random
    place on that side; rectangular or round (an ellipse).
    """
    turn = _Frame(np.zeros(2), side * math.pi / 2).rot
    if side % 2:            # work with the opening on +x, then turn
        ax, ay = ay, ax
    if round_:
        half = rng.uniform(0.35, 1.0) * math.pi / 2      # half the opening angle
        half = max(half, math.asin(min(1.0, 1.3 / ay)))   # an opening at least ~2.6 wide
        angles = np.linspace(half, 2 * math.pi - half, 24)
        line = np.column_stack([ax * np.cos(angles), ay * np.sin(angles)])
    else:
        f = 1.0 if rng.random() < 0.5 else rng.uniform(0.3, 0.8)
        width = max(f * 2 * ay, 1.8)
        if width >= 2 * ay - 0.6:   # U: the whole side open
            line = np.array([[ax, ay], [-ax, ay], [-ax, -ay], [ax, -ay]])
        else:
            lo = rng.uniform(-ay + 0.3, ay - 0.3 - width)
            line = np.array([[ax, lo + width], [ax, ay], [-ax, ay], [-ax, -ay], [ax, -ay], [ax, lo]])
    return line @ turn.T


def _cups_block(rng: np.random.Generator, frame_at: Callable[[np.ndarray, np.ndarray], _Frame | None],
                grow: float) -> _Block | None:
    """Two or three nested cups around the origin of the local frame, openings alternating."""
    t = rng.uniform(0.3, 0.7)
    count = 2 if rng.random() < 0.5 else 3
    ax, ay = rng.uniform(2.2, 4.5 * grow, 2)
    side = int(rng.integers(4))
    round_ = rng.random() < 0.3
    lines, extents = [], []
    for k in range(count):
        lines.append(_cup_outline(rng, ax, ay, side, round_))
        extents.append((ax, ay))
        side = (side + 2) % 4 if rng.random() < 0.75 else (side + int(rng.choice([1, 3]))) % 4
        ax += t + rng.uniform(CUP_SPACING[0], CUP_SPACING[1] * grow)
        ay += t + rng.uniform(CUP_SPACING[0], CUP_SPACING[1] * grow)
    ex, ey = extents[-1][0] + t, extents[-1][1] + t
    frame = frame_at(np.array([-ex, -ey]), np.array([ex, ey]))
    if frame is None:
        return None
    polygons = [frame(_thick_polyline(line, t)) for line in lines]
    ix, iy = extents[0][0] - t / 2, extents[0][1] - t / 2
    if round_:   # the box inside the innermost ellipse
        ix, iy = ix / math.sqrt(2), iy / math.sqrt(2)
    return _Block(polygons, [(-ix, ix, -iy, iy)], frame, 0, (-ex, ex, -ey, ey))


def _clutter_polygon(rng: np.random.Generator, c: np.ndarray, grow: float) -> np.ndarray:
    """One polygon of dense clutter at ``c``: a random convex polygon, a box, a bar or an L."""
    kind = rng.choice(4, p=[0.35, 0.3, 0.2, 0.15])
    angle = rng.uniform(0, 2 * math.pi)
    if kind == 0:
        n = int(rng.integers(3, 8))
        angles = np.sort(rng.uniform(0, 2 * math.pi, n))
        angles = angles[np.diff(np.append(angles, angles[0] + 2 * math.pi)) > 0.2]
        if len(angles) < 3:
            angles = np.array([0.0, 2.1, 4.2])
        radius = rng.uniform(0.6, 2.2) * grow * rng.uniform(0.7, 1.0, len(angles))
        local = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)])
    elif kind == 1:
        w, h = rng.uniform(0.6, 3.5, 2) * grow
        local = _box_corners(-w / 2, w / 2, -h / 2, h / 2)
    elif kind == 2:
        length, thick = rng.uniform(2, 6) * grow, rng.uniform(0.3, 0.6)
        local = _box_corners(-length / 2, length / 2, -thick / 2, thick / 2)
    else:
        a, b = rng.uniform(2, 5, 2) * grow
        thick = rng.uniform(0.4, 0.8)
        local = np.array([[0, 0], [a, 0], [a, thick], [thick, thick], [thick, b], [0, b]]) - [a / 3, b / 3]
    return _Frame(c, angle)(local)


def _clutter_polygons(rng: np.random.Generator, count: int, region: Callable[[], np.ndarray], size: float,
                      keep_out: np.ndarray | None, grow: float) -> list[np.ndarray]:
    """``count`` clutter polygons at points drawn by ``region``, inside the map and 1.5 from ``keep_out``."""
    out = []
    for _ in range(20 * count):
        if len(out) == count:
            break
        poly = _clutter_polygon(rng, region(), grow)
        if poly.min() < 0.5 or poly.max() > size - 0.5:
            continue
        if keep_out is not None and _polygon_distance(poly, keep_out) < TARGET_CLEARANCE + 0.5:
            continue
        out.append(poly)
    return out


def _polygon_distance(poly: np.ndarray, point: np.ndarray) -> float:
    """Distance from ``point`` to a simple polygon's boundary, negative inside."""
    d, _ = geometry.polygon_signed_distance(np.asarray(point, float)[None], np.asarray(poly, float))
    return float(d[0])


def _clip_convex(poly: np.ndarray, size: float) -> np.ndarray:
    """A convex polygon clipped to the map [0, size]² (Sutherland–Hodgman)."""
    pts = [np.asarray(p, float) for p in poly]
    for axis, bound, keep_below in ((0, 0.0, False), (0, size, True), (1, 0.0, False), (1, size, True)):
        inside = (lambda p: p[axis] <= bound) if keep_below else (lambda p: p[axis] >= bound)
        out = []
        for k, p in enumerate(pts):
            q = pts[k - 1]
            if inside(p):
                if not inside(q):
                    out.append(q + (p - q) * (bound - q[axis]) / (p[axis] - q[axis]))
                out.append(p)
            elif inside(q):
                out.append(q + (p - q) * (bound - q[axis]) / (p[axis] - q[axis]))
        pts = out
        if not pts:
            return np.zeros((0, 2))
    clipped = np.clip(np.round(np.array(pts), 3), 0.0, size)
    keep = np.hypot(*(clipped - np.roll(clipped, 1, axis=0)).T) > 1e-3
    return clipped[keep]


Drawn = tuple[list[np.ndarray], np.ndarray, Callable[[], np.ndarray | None]]
"""What a structure family draws: wall polygons, the target, and a proposer of start candidates."""


def _rooms_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    most = 2 + round(2 * scale)          # rooms per side: 4 on a 50 x 50 map, 6 on a 100 x 100 one
    outer = rng.random() >= 0.4
    if not outer:                        # the building is the map: its edge is the outside wall
        block = _rooms_block(rng, size, size, _Frame(np.zeros(2), 0.0), False, most)
    else:
        w, h = rng.uniform(0.5, 0.85, 2) * size
        angle = 0.0 if rng.random() < 0.5 else rng.uniform(0, math.pi / 2)
        shrink = min(1.0, (size - 8) / _rotated_extent(w, h, angle).max())
        w, h = w * shrink, h * shrink
        frame = _fit_frame(rng, np.zeros(2), np.array([w, h]), angle, size, 3.0)
        if frame is None:
            return None
        block = _rooms_block(rng, w, h, frame, True, most)
    if outer and rng.random() < 0.15:    # the target outside the building, by a wall
        x0, x1, y0, y1 = block.outer
        along, off = rng.uniform(0.1, 0.9), rng.uniform(1.5, 3.0)
        local = [(x0 + along * (x1 - x0), y0 - off), (x0 + along * (x1 - x0), y1 + off),
                 (x0 - off, y0 + along * (y1 - y0)), (x1 + off, y0 + along * (y1 - y0))][int(rng.integers(4))]
        target = block.frame(np.array([local]))[0]
    else:
        target = block.point_in(rng, block.inner, TARGET_CLEARANCE + 0.2)
    if target is None:
        return None

    def propose() -> np.ndarray | None:
        if outer and rng.random() < 0.25:
            return block.around(rng, 8 * scale)
        return block.point_in(rng, int(rng.integers(len(block.spots))), START_CLEARANCE)

    return block.polygons, target, propose


def _maze_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    # cells of 3-6 units on 50 x 50, 3.5-8 on 100 x 100 (larger where there would be more than ``most`` a side)
    cell = rng.uniform(3.0 + 0.5 * (scale - 1), 6.0 + 2.0 * (scale - 1))
    most = int(round(10 + 2 * (scale - 1)))                               # cells per side
    outer = rng.random() >= 0.35
    if not outer:                         # the maze fills the map: its edge is the outside wall
        n = min(most, max(2, int(size // cell)))
        m = min(most, max(2, int(round(n * rng.uniform(0.8, 1.25)))))
        nx, ny = (n, m) if rng.random() < 0.5 else (m, n)
        block = _maze_block(rng, nx, ny, size / nx, size / ny, _Frame(np.zeros(2), 0.0), False)
    else:
        w, h = rng.uniform(0.4, 0.9, 2) * size
        angle = 0.0 if rng.random() < 0.5 else rng.uniform(0, math.pi / 2)
        fit = min(1.0, (size - 6) / _rotated_extent(w, h, angle).max())
        cell = max(cell, w * fit / most, h * fit / most)
        nx, ny = max(3, int(w * fit / cell)), max(3, int(h * fit / cell))
        frame = _fit_frame(rng, np.zeros(2), np.array([nx * cell, ny * cell]), angle, size, 3.0)
        if frame is None:
            return None
        block = _maze_block(rng, nx, ny, cell, cell, frame, True)
    target = block.point_in(rng, block.inner, TARGET_CLEARANCE + 0.2)
    if target is None:
        return None

    def propose() -> np.ndarray | None:
        if outer and rng.random() < 0.2:
            return block.around(rng, 6 * scale)
        return block.point_in(rng, int(rng.integers(len(block.spots))), START_CLEARANCE)

    return block.polygons, target, propose


def _cups_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    angle = rng.uniform(0, 2 * math.pi)
    block = _cups_block(rng, lambda lo, hi: _fit_frame(rng, lo, hi, angle, size, 2.5), math.sqrt(scale))
    if block is None:
        return None
    target = block.point_in(rng, 0, TARGET_CLEARANCE + 0.3)
    if target is None:
        return None
    reach = max(block.outer[1], block.outer[3])

    def propose() -> np.ndarray | None:
        heading = rng.uniform(0, 2 * math.pi)
        r = rng.uniform(0.3 * reach, reach + rng.uniform(2, 14) * scale)
        return block.frame(np.array([[r * math.cos(heading), r * math.sin(heading)]]))[0]

    return block.polygons, target, propose


def _gap_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    target = rng.uniform(0.15 * size, 0.85 * size, 2)
    angle = rng.uniform(0, 2 * math.pi)
    u = np.array([math.cos(angle), math.sin(angle)])
    tilt = angle + math.pi / 2 + rng.uniform(-0.6, 0.6)
    along = np.array([math.cos(tilt), math.sin(tilt)])        # the wall's direction
    normal = np.array([-along[1], along[0]])
    gap_at = target + rng.uniform(3, 10) * scale * u + rng.uniform(-12, 12) * scale * along
    if np.any(gap_at < 3) or np.any(gap_at > size - 3):
        return None
    t, width = rng.uniform(0.3, 1.0), rng.uniform(*GAP_WIDTH)
    side = float(np.sign(np.dot(target - gap_at, normal)))
    if abs(np.dot(target - gap_at, normal)) < t / 2 + 2.0:
        return None
    polygons = []
    for sign in (-1, 1):
        near, far = gap_at + sign * width / 2 * along, gap_at + sign * 3 * size * along
        piece = _clip_convex(_thick_polyline(np.array([near, far]), t), size)
        if len(piece) < 3:
            return None
        polygons.append(piece)

    def propose() -> np.ndarray | None:
        return gap_at - side * rng.uniform(1.5, 22 * scale) * normal + rng.normal(0, 10 * scale) * along

    return polygons, target, propose


def _clutter_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    target = rng.uniform(0.15 * size, 0.85 * size, 2)
    angle = rng.uniform(0, 2 * math.pi)
    u = np.array([math.cos(angle), math.sin(angle)])
    count = int(round(rng.integers(18, 33) * scale ** 0.6))   # 18-32 on 50 x 50, 27-48 on 100 x 100
    polygons = _clutter_polygons(rng, count, lambda: _frame(target, u, rng.uniform(-5, 16) * scale,
                                                                 rng.uniform(-11, 11) * scale),
                                 size, target, scale ** 0.5)
    if len(polygons) < count:
        return None

    def propose() -> np.ndarray | None:
        return _frame(target, u, rng.uniform(3, 24) * scale, rng.normal(0, 7 * scale))

    return polygons, target, propose


def _mixed_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    grow = math.sqrt(scale)
    count = int(rng.integers(2 + (scale >= 1.5), 2 + round(2 * scale)))   # 2-3 blocks on 50 x 50, 3-5 on 100 x 100
    kinds = ["rooms" if rng.random() < 0.5 else "cups"]
    kinds += [str(rng.choice(["rooms", "cups", "clutter"], p=[0.3, 0.3, 0.4])) for _ in range(count - 1)]
    blocks: list[_Block] = []
    boxes: list[tuple[np.ndarray, np.ndarray]] = []
    for kind in kinds:
        for _ in range(30):
            angle = 0.0 if kind == "rooms" and rng.random() < 0.5 else rng.uniform(0, math.pi / 2)
            if kind == "rooms":
                w, h = np.minimum(rng.uniform(14, 30, 2) * grow, 0.6 * size)
                frame = _fit_frame(rng, np.zeros(2), np.array([w, h]), angle, size, 2.0)
                block = None if frame is None else _rooms_block(rng, w, h, frame, True, 3)
            elif kind == "cups":
                block = _cups_block(rng, lambda lo, hi: _fit_frame(rng, lo, hi, angle, size, 2.0), grow)
            else:
                w, h = np.minimum(rng.uniform(10, 22, 2) * grow, 0.5 * size)
                frame = _fit_frame(rng, np.zeros(2), np.array([w, h]), angle, size, 1.0)
                if frame is None:
                    continue
                n = int(w * h / rng.uniform(10, 18))
                polys = _clutter_polygons(rng, n, lambda: frame(rng.uniform(0, 1, 2) * [w, h]), size, None, 1.0)
                block = _Block(polys, [(0.0, w, 0.0, h)], frame, 0, (0.0, w, 0.0, h))
            if block is None or not block.polygons:
                continue
            pts = np.vstack(block.polygons)
            lo, hi = pts.min(axis=0) - 2.5, pts.max(axis=0) + 2.5
            if any(np.all(lo < b_hi) and np.all(b_lo < hi) for b_lo, b_hi in boxes):
                continue
            blocks.append(block)
            boxes.append((lo, hi))
            break
        if not blocks:
            return None   # the target's block did not fit
    if len(blocks) < 2:
        return None
    home = blocks[0]
    target = home.point_in(rng, home.inner, TARGET_CLEARANCE + 0.3)
    if target is None:
        return None

    def propose() -> np.ndarray | None:   # mostly in or by the other blocks: traps at both ends
        if rng.random() < 0.7:
            other = blocks[int(rng.integers(1, len(blocks)))]
            if rng.random() < 0.6:
                return other.point_in(rng, int(rng.integers(len(other.spots))), START_CLEARANCE)
            return other.around(rng, 3.0)
        return rng.uniform(1, size - 1, 2)

    return [p for b in blocks for p in b.polygons], target, propose


_STRUCTURES: dict[str, Callable[[np.random.Generator, float], Drawn | None]] = {
    "rooms": _rooms_world, "maze": _maze_world, "nested_cups": _cups_world, "narrow_gap": _gap_world,
    "dense_clutter": _clutter_world, "mixed": _mixed_world,
}
STRUCTURE_ATTEMPTS = 60   # structure worlds drawn per requested world before giving up


def _structure_world(family: str, rng: np.random.Generator, size: float, field: str, n_starts: int,
                     name: str | None) -> World:
    """A world of a structure family (:data:`STRUCTURE_FAMILIES`) with ``n_starts`` starts out of the target's sight."""
    limit = PATH_SHARE * step_limit(size)
    for _ in range(STRUCTURE_ATTEMPTS):
        drawn = _STRUCTURES[family](rng, size)
        if drawn is None:
            continue
        polygons, target, propose = drawn
        # 3 decimals as everywhere (+ 0.0: no -0.0, which would not read back the same)
        obstacles = [{"polygon": (np.round(np.asarray(p, float), 3) + 0.0).tolist()} for p in polygons]
        if any(min(min(v) for v in o["polygon"]) < 0 or max(max(v) for v in o["polygon"]) > size for o in obstacles):
            continue
        data = {
            "name": name or family,
            "size": [size, size],
            "robot_radius": STRUCTURE_ROBOT_RADIUS,
            "goal_tolerance": GOAL_TOLERANCE,
            "field": field,
            "obstacles": obstacles,
            "targets": _round([np.asarray(target, float).tolist()]),
            "starts": [],
        }
        try:
            bare = world_from_dict(data, source=f"<generated {family}>")
        except UserError:
            continue
        target = bare.targets[0]
        if bare.clearance(target[None])[0] < TARGET_CLEARANCE:
            continue
        starts = _hidden_starts(bare, rng, target, propose, n_starts, limit)
        if starts is None:
            continue
        data["starts"] = _round(starts.tolist())
        return world_from_dict(data, source=f"<generated {family}>")
    raise UserError(f"no valid {family!r} world found in {STRUCTURE_ATTEMPTS} draws on a {size:g} x {size:g} map")


def _hidden_starts(world: World, rng: np.random.Generator, target: np.ndarray, propose: Callable[[], np.ndarray | None],
                   count: int, limit: float) -> np.ndarray | None:
    """``count`` starts from ``propose``: free, out of the target's sight, reachable, with a short enough A* path.

    Reachable as :func:`~apf_physics.search.reachable` means it: a path with the robot's clearance.

    Out of sight: the straight segment to the target comes within the robot's radius of an
    obstacle (the start is behind a structure as seen from the target). Short enough: the
    grid path (an upper bound on :func:`~apf_physics.search.shortest_path_length`, which adds
    at most the goal tolerance) plus the goal tolerance stays below ``limit``. Candidates are
    drawn and screened in batches (one clearance and one sight computation per batch).
    """
    grid = SearchGrid.of(world)
    out: list[np.ndarray] = []
    batch = 16 * max(count, 1)
    for _ in range(6):
        drawn = [propose() for _ in range(batch)]
        points = np.round(np.array([p for p in drawn if p is not None], float).reshape(-1, 2), 3)
        points = points[(world.clearance(points) >= START_CLEARANCE) & (np.hypot(*(points - target).T) >= 3.0)]
        if len(points):
            ends = np.broadcast_to(target, points.shape)
            points = points[world.path_clearance(points, ends, 0.1) < world.robot_radius]   # out of the target's sight
        for p in points:
            if len(out) == count:
                break
            if any(np.hypot(*(p - q)) < START_SPACING for q in out):
                continue
            entries = grid.entry_nodes(p)
            if not len(entries):
                continue
            # A finite cost from an entry node is what :func:`~apf_physics.search.reachable` checks
            # (the entry nodes share a component with the target's nodes); it is not called
            # again, which would find the same entry nodes a second time.
            length = float(np.min(grid.cost_to_go[entries] + np.hypot(*(grid.node_xy(entries) - p).T)))
            if length + world.goal_tolerance < limit:   # False also when unreachable (infinite)
                out.append(p)
        if len(out) == count:
            return np.array(out)
    return None
