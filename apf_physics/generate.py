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

from apf_physics.errors import UserError
from apf_physics.field import FIELD_PRESETS
from apf_physics.search import reachable
from apf_physics.world import World
from apf_physics.worldfile import world_from_dict

FAMILIES = ("point", "line", "two_points", "concave", "bent_line", "clutter")
"""The families of static worlds the thesis's general curriculum and the project's general recipes train on."""
STATIC_FAMILIES = FAMILIES
MOVING_FAMILIES = ("moving",)
FORMATION_FAMILIES = ("crossing",)
ALL_FAMILIES = FAMILIES + MOVING_FAMILIES + FORMATION_FAMILIES
"""Every family :func:`generate_world` draws."""

ROBOT_RADIUS = 0.25
# ≥ √2/2: a robot moving in unit steps (SPEC Table 1) from any start passes within √2/2 of
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
        family: One of :data:`FAMILIES`.
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
