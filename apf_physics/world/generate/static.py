"""The static families (:data:`FAMILIES`): a few obstacles across an axis between the target and the starts.

- ``point``: one point obstacle (a circle of radius 0), the thesis's basic learning.
- ``line``: one line-shaped obstacle (a thin rectangle) across the axis.
- ``two_points``: two point obstacles either side of the axis, a gap of 1.5–4 units between.
- ``concave``: a U-shaped cup whose opening faces the starts.
- ``bent_line``: two line-shaped obstacles, one bent (a V or L whose inside faces the starts).
- ``clutter``: 5–10 mixed obstacles (discs, points, lines, boxes) scattered around the axis.

The target is drawn first, then an axis ``u`` pointing from the target toward where the
starts will be; the obstacles sit across that axis a few units from the target, and the
starts behind them (seen from the target), spread around the axis (:func:`axis_world`, which
the moving family shares).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from apf_physics.errors import UserError
from apf_physics.world.generate.common import (MAX_ATTEMPTS, ROBOT_RADIUS, START_CLEARANCE, clear_of_target, inside_map,
                                         round_coordinates, world_data)
from apf_physics.world.generate.shapes import axis_point, bent_line, cup, disc, random_box, thin_line
from apf_physics.world.search import reachable
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import world_from_dict

FAMILIES = ("point", "line", "two_points", "concave", "bent_line", "clutter")
"""The families of static worlds the thesis's general curriculum and the project's general recipes train on."""
STATIC_FAMILIES = FAMILIES

AxisObstacles = Callable[[np.random.Generator, np.ndarray, np.ndarray, float, float], list[dict]]
"""What a family draws about the axis: ``(rng, target, u, gap, scale)`` to obstacle mappings."""


def family_obstacles(family: str, rng: np.random.Generator, target: np.ndarray, u: np.ndarray,
               gap: float) -> list[dict]:
    """The family's obstacles, ``gap`` units from the target along ``u``."""
    c = target + gap * u
    if family == "point":
        return [disc(c, 0.0)]
    if family == "line":
        return [thin_line(rng, c, u, (6, 16))]
    if family == "two_points":
        half = rng.uniform(1.5, 4) / 2
        shift = rng.uniform(-1, 1)
        return [disc(axis_point(c, u, 0, shift - half), 0.0), disc(axis_point(c, u, 0, shift + half), 0.0)]
    if family == "concave":
        return [cup(rng, c, u)]
    if family == "bent_line":
        bent = bent_line(rng, c, u, (4, 9))
        side = rng.choice([-1, 1])
        straight = thin_line(rng, axis_point(c, u, rng.uniform(3, 8), side * rng.uniform(6, 11)), u, (4, 10))
        return [bent, straight]
    if family == "clutter":
        out = []
        for _ in range(int(rng.integers(5, 11))):
            p = axis_point(c, u, rng.uniform(-3, 10), rng.uniform(-8, 8))
            kind = rng.choice(["point", "disc", "line", "box"], p=[0.25, 0.3, 0.25, 0.2])
            if kind == "point":
                out.append(disc(p, 0.0))
            elif kind == "disc":
                out.append(disc(p, rng.uniform(0.3, 2.0)))
            elif kind == "line":
                out.append(thin_line(rng, p, u, (3, 8)))
            else:
                out.append(random_box(rng, p))
        return out
    raise UserError(f"--family: unknown family {family!r} (known: {', '.join(FAMILIES)})")


def static_world(family: str, rng: np.random.Generator, size: float, field: str, n_starts: int,
                 name: str | None) -> World:
    """A world of a static family (:data:`FAMILIES`) with ``n_starts`` reachable starts behind its obstacles."""
    return axis_world(family, lambda rng, target, u, gap, scale: family_obstacles(family, rng, target, u, gap),
                      rng, size, field, n_starts, name)


def axis_world(family: str, draw: AxisObstacles, rng: np.random.Generator, size: float, field: str, n_starts: int,
               name: str | None) -> World:
    """A world of ``family``: a target, an axis ``u`` from it and a gap along it, the obstacles
    ``draw`` puts there, and ``n_starts`` reachable starts behind them.

    Raises:
        UserError: no valid world found in :data:`MAX_ATTEMPTS` draws (the map is too small for the family).
    """
    scale = size / 50.0  # distances below are for a 50 x 50 map
    for _ in range(MAX_ATTEMPTS):
        target = rng.uniform(0.1 * size, 0.9 * size, size=2)
        angle = rng.uniform(0, 2 * math.pi)
        u = np.array([math.cos(angle), math.sin(angle)])
        gap = rng.uniform(5, 12) * scale
        obstacles = draw(rng, target, u, gap, scale)
        if not all(inside_map(o, size, 0.5) and clear_of_target(o, target, 1.5) for o in obstacles):
            continue
        data = world_data(family, name, size, ROBOT_RADIUS, field, round_coordinates(obstacles), target)
        try:
            bare = world_from_dict(data, source=f"<generated {family}>")
        except UserError:
            continue  # e.g. the target landed inside an obstacle
        starts = _draw_starts(bare, rng, target, u, gap, n_starts, scale, reachable)
        if starts is None:
            continue
        data["starts"] = round_coordinates(starts.tolist())
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
        p = axis_point(target, u, behind, rng.normal(0, 3.5 * scale))
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
