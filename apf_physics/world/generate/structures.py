"""The structure families (:data:`STRUCTURE_FAMILIES`): rooms, mazes, nested cups, a narrow gap, dense clutter, a mix.

Larger structures than the static families' (:mod:`~apf_physics.world.generate.static`),
for testing whether a planner generalises. They use a robot of radius 0.3
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

Each family draws its walls, its target and a proposer of starts (:data:`Drawn`, from the
blocks of :mod:`apf_physics.world.generate.blocks`); :func:`structure_world` keeps the starts that
are free, hidden and near enough.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from apf_physics.errors import UserError
from apf_physics.world.generate.blocks import (TARGET_CLEARANCE, Block, LocalFrame, clutter_polygons, cups_block, fit_frame,
                                         maze_block, rooms_block, rotated_extent)
from apf_physics.world.generate.common import START_CLEARANCE, round_coordinates, world_data
from apf_physics.world.generate.shapes import axis_point, clip_convex, thick_polyline
from apf_physics.world.search import SearchGrid
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import world_from_dict

STRUCTURE_FAMILIES = ("rooms", "maze", "nested_cups", "narrow_gap", "dense_clutter", "mixed")
"""Larger structures: rooms, mazes, nested cups, a narrow gap, dense clutter, and a mix of them."""
STRUCTURE_ROBOT_RADIUS = 0.3
"""The robot's radius in the structure families (the issue's measurements used 0.3)."""
PATH_SHARE = 0.6
"""Every start of a structure world has an A* path shorter than this share of :func:`step_limit`."""
GAP_WIDTH = (1.3, 1.8)      # the narrow gap [units]
START_SPACING = 2.0         # starts of one world keep this far apart [units]


def step_limit(size: float) -> int:
    """The default step limit of an episode on a ``size`` x ``size`` map.

    The same rule as :func:`apf_physics.experiments.rollout.default_max_steps` (four times width plus
    height: 400 steps on a 50 x 50 map, 800 on a 100 x 100 one), which this module cannot
    import (it sits below the rollout in the package's layers); a test keeps the two equal.
    """
    return int(4 * (size + size))


Drawn = tuple[list[np.ndarray], np.ndarray, Callable[[], np.ndarray | None]]
"""What a structure family draws: wall polygons, the target, and a proposer of start candidates."""


def _rooms_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    most = 2 + round(2 * scale)          # rooms per side: 4 on a 50 x 50 map, 6 on a 100 x 100 one
    outer = rng.random() >= 0.4
    if not outer:                        # the building is the map: its edge is the outside wall
        block = rooms_block(rng, size, size, LocalFrame(np.zeros(2), 0.0), False, most)
    else:
        w, h = rng.uniform(0.5, 0.85, 2) * size
        angle = 0.0 if rng.random() < 0.5 else rng.uniform(0, math.pi / 2)
        shrink = min(1.0, (size - 8) / rotated_extent(w, h, angle).max())
        w, h = w * shrink, h * shrink
        frame = fit_frame(rng, np.zeros(2), np.array([w, h]), angle, size, 3.0)
        if frame is None:
            return None
        block = rooms_block(rng, w, h, frame, True, most)
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
    return block.polygons, target, block.proposer(rng, 0.25 if outer else 0.0, 8 * scale, START_CLEARANCE)


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
        block = maze_block(rng, nx, ny, size / nx, size / ny, LocalFrame(np.zeros(2), 0.0), False)
    else:
        w, h = rng.uniform(0.4, 0.9, 2) * size
        angle = 0.0 if rng.random() < 0.5 else rng.uniform(0, math.pi / 2)
        fit = min(1.0, (size - 6) / rotated_extent(w, h, angle).max())
        cell = max(cell, w * fit / most, h * fit / most)
        nx, ny = max(3, int(w * fit / cell)), max(3, int(h * fit / cell))
        frame = fit_frame(rng, np.zeros(2), np.array([nx * cell, ny * cell]), angle, size, 3.0)
        if frame is None:
            return None
        block = maze_block(rng, nx, ny, cell, cell, frame, True)
    target = block.point_in(rng, block.inner, TARGET_CLEARANCE + 0.2)
    if target is None:
        return None
    return block.polygons, target, block.proposer(rng, 0.2 if outer else 0.0, 6 * scale, START_CLEARANCE)


def _cups_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    angle = rng.uniform(0, 2 * math.pi)
    block = cups_block(rng, lambda lo, hi: fit_frame(rng, lo, hi, angle, size, 2.5), math.sqrt(scale))
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
        piece = clip_convex(thick_polyline(np.array([near, far]), t), size)
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
    polygons = clutter_polygons(rng, count, lambda: axis_point(target, u, rng.uniform(-5, 16) * scale,
                                                                 rng.uniform(-11, 11) * scale),
                                 size, target, scale ** 0.5)
    if len(polygons) < count:
        return None

    def propose() -> np.ndarray | None:
        return axis_point(target, u, rng.uniform(3, 24) * scale, rng.normal(0, 7 * scale))

    return polygons, target, propose


def _mixed_world(rng: np.random.Generator, size: float) -> Drawn | None:
    scale = size / 50.0
    grow = math.sqrt(scale)
    count = int(rng.integers(2 + (scale >= 1.5), 2 + round(2 * scale)))   # 2-3 blocks on 50 x 50, 3-5 on 100 x 100
    kinds = ["rooms" if rng.random() < 0.5 else "cups"]
    kinds += [str(rng.choice(["rooms", "cups", "clutter"], p=[0.3, 0.3, 0.4])) for _ in range(count - 1)]
    blocks: list[Block] = []
    boxes: list[tuple[np.ndarray, np.ndarray]] = []
    for kind in kinds:
        for _ in range(30):
            angle = 0.0 if kind == "rooms" and rng.random() < 0.5 else rng.uniform(0, math.pi / 2)
            if kind == "rooms":
                w, h = np.minimum(rng.uniform(14, 30, 2) * grow, 0.6 * size)
                frame = fit_frame(rng, np.zeros(2), np.array([w, h]), angle, size, 2.0)
                block = None if frame is None else rooms_block(rng, w, h, frame, True, 3)
            elif kind == "cups":
                block = cups_block(rng, lambda lo, hi: fit_frame(rng, lo, hi, angle, size, 2.0), grow)
            else:
                w, h = np.minimum(rng.uniform(10, 22, 2) * grow, 0.5 * size)
                frame = fit_frame(rng, np.zeros(2), np.array([w, h]), angle, size, 1.0)
                if frame is None:
                    continue
                n = int(w * h / rng.uniform(10, 18))
                polys = clutter_polygons(rng, n, lambda: frame(rng.uniform(0, 1, 2) * [w, h]), size, None, 1.0)
                block = Block(polys, [(0.0, w, 0.0, h)], frame, 0, (0.0, w, 0.0, h))
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
                return other.in_a_spot(rng, START_CLEARANCE)
            return other.around(rng, 3.0)
        return rng.uniform(1, size - 1, 2)

    return [p for b in blocks for p in b.polygons], target, propose


_STRUCTURES: dict[str, Callable[[np.random.Generator, float], Drawn | None]] = {
    "rooms": _rooms_world, "maze": _maze_world, "nested_cups": _cups_world, "narrow_gap": _gap_world,
    "dense_clutter": _clutter_world, "mixed": _mixed_world,
}
STRUCTURE_ATTEMPTS = 60   # structure worlds drawn per requested world before giving up


def structure_world(family: str, rng: np.random.Generator, size: float, field: str, n_starts: int,
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
        data = world_data(family, name, size, STRUCTURE_ROBOT_RADIUS, field, obstacles, target)
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
        data["starts"] = round_coordinates(starts.tolist())
        return world_from_dict(data, source=f"<generated {family}>")
    raise UserError(f"no valid {family!r} world found in {STRUCTURE_ATTEMPTS} draws on a {size:g} x {size:g} map")


def _hidden_starts(world: World, rng: np.random.Generator, target: np.ndarray, propose: Callable[[], np.ndarray | None],
                   count: int, limit: float) -> np.ndarray | None:
    """``count`` starts from ``propose``: free, out of the target's sight, reachable, with a short enough A* path.

    Reachable as :func:`~apf_physics.world.search.reachable` means it: a path with the robot's clearance.

    Out of sight: the straight segment to the target comes within the robot's radius of an
    obstacle (the start is behind a structure as seen from the target). Short enough: the
    grid path (an upper bound on :func:`~apf_physics.world.search.shortest_path_length`, which adds
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
            # A finite cost from an entry node is what :func:`~apf_physics.world.search.reachable` checks
            # (the entry nodes share a component with the target's nodes); it is not called
            # again, which would find the same entry nodes a second time.
            length = float(np.min(grid.cost_to_go[entries] + np.hypot(*(grid.node_xy(entries) - p).T)))
            if length + world.goal_tolerance < limit:   # False also when unreachable (infinite)
                out.append(p)
        if len(out) == count:
            return np.array(out)
    return None
