"""A range sensor: K beams cast from many robots at once against everything a robot can meet.

A robot at pose ``(x, y, θ)`` casts :attr:`LidarConfig.beams` rays over its field of view and
reads, per beam, the distance from its **centre** to the first thing the ray meets, or
:attr:`LidarConfig.max_range` when it meets nothing that near:

- the world's static obstacles: polygons (their edges), discs, and an occupancy grid (the
  boundary of its occupied cells, cut into maximal straight runs,
  :func:`~apf_physics.common.geometry.grid_boundary`);
- the moving obstacles where their routes have them at step ``t`` (one step for all robots, or
  one per robot: the slots of a vector env are at different steps), and the world's crowd
  (:meth:`~apf_physics.world.World.among`);
- the map's edge (the rectangle ``[0, w] × [0, h]``);
- other robots: discs of the robot radius, given per robot (:func:`teammates` builds them from
  team labels, leaving each robot itself out).

A point obstacle (a disc of radius 0) is met only by a beam exactly through it: a beam has no
width. A robot whose centre is inside a disc reads 0 on every beam; one inside a polygon (it has
collided) does not see that polygon (only edges seen from outside are cast against).

Beams (:meth:`LidarConfig.angles`), relative to the heading, counter-clockwise: with a full
circle (360°), ``−π + 2πk/K`` (beam 0 straight back, beam ``K/2`` straight ahead); with a
narrower field of view, ``K`` beams evenly from ``−fov/2`` to ``+fov/2``, ends included.
Units: lengths in units, angles in radians (the field of view is given in degrees).

Everything is numpy, with no Python loop over robots or beams (the method is told in "the ray
casts" below): the map's edge is solved for every beam in closed form; every other shape is
first paired with the robots that can see it (a polygon's edge from outside, within range), each
pair is turned into the beams within the angle the shape subtends from the robot, and only those
(robot, beam, shape) candidates are solved, exactly, the nearest hit of each beam kept. Robots
are cast :data:`ROBOTS_PER_CAST` at a time (bounding the temporaries). Each world's static
segments and discs (and, on a map of many segments, a table of those seen from each cell of the
map) are built once and kept with the world (:meth:`~apf_physics.world.World.cached`, shared
by the worlds of other targets on the same map).
Optional Gaussian noise (:attr:`LidarConfig.noise`) comes from a seeded generator; noisy ranges
are clipped to ``[0, max_range]``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np

from apf_physics.world.obstacles import GridObstacle, PolygonObstacle
from apf_physics.world.core import Moment, World
from apf_physics.world.outlines import moving_geometry, polygon_edges, static_geometry

ROBOTS_PER_CAST = 2048
"""Most robots cast at a time (bounds the temporaries)."""


@dataclass(frozen=True)
class LidarConfig:
    """A range sensor's beams.

    Attributes:
        beams: Number of beams ``K``.
        fov: Field of view [degrees], ``0 < fov ≤ 360``, centred on the heading.
        max_range: Farthest reading [units]; a beam that meets nothing reads this.
        noise: Standard deviation of Gaussian noise added to each reading [units] (0: none).
    """

    beams: int = 64
    fov: float = 360.0
    max_range: float = 8.0
    noise: float = 0.0

    def __post_init__(self):
        if self.beams < 1:
            raise ValueError(f"lidar beams must be positive, got {self.beams}")
        if not 0 < self.fov <= 360:
            raise ValueError(f"lidar fov must be in (0, 360] degrees, got {self.fov}")
        if not self.max_range > 0:
            raise ValueError(f"lidar max_range must be positive, got {self.max_range}")
        if not self.noise >= 0:
            raise ValueError(f"lidar noise must be >= 0, got {self.noise}")

    def noisy(self, ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``ranges`` (..., K) with Gaussian noise of :attr:`noise` drawn from ``rng``, clipped to
        ``[0, max_range]`` (the one rule for noisy readings, however the generators are kept)."""
        return np.clip(ranges + rng.normal(0.0, self.noise, np.shape(ranges)), 0.0, self.max_range)

    def angles(self) -> np.ndarray:
        """(K,) beam angles relative to the heading [rad], counter-clockwise (module docstring)."""
        k = self.beams
        if self.fov >= 360:
            return -np.pi + 2 * np.pi * np.arange(k) / k
        half = np.deg2rad(self.fov) / 2
        return np.linspace(-half, half, k) if k > 1 else np.zeros(1)


# -- the ray casts ------------------------------------------------------------------------------
#
# The map's edge: every beam in closed form (_edge_ranges); this sets the ranges a cast starts from.
#
# Every other shape, in two stages, both conservative (a shape left out can hold no first hit):
#
# 1. Pairs (_seen, _near_discs). A test over robots × shapes keeps the (robot, shape) pairs
#    that can hold a beam's first hit within range: a segment of an obstacle's outline whose
#    nearest point is within range and whose outer side the robot is on (segments are directed
#    with the obstacle on their left: a polygon's outline counter-clockwise, a grid's boundary in
#    runs cut where the occupied cells change sides, _oriented_runs; a robot in a grid's wall
#    sees that grid's runs from inside); a disc within range. With many static segments (a grid
#    map) a robot tests only those of its cell of the map, a table built once per world and range
#    of the segments that can be seen from somewhere in the cell (_cells, _seen_static).
# 2. Candidates (_cast_segments, _cast_discs, _Beams.candidates). Each pair is turned into the
#    beams within the angle the shape subtends from the robot, a segment first cut to its part
#    within range (a beam meeting it farther reads ``max_range`` anyway), so that a beam is
#    solved only against the few shapes in its direction. The angles come from a cheap
#    approximation of ``atan2`` (_angle) whose error is bounded by ANGLE_ERROR, and each interval
#    is widened by that bound: the candidate sets are a little too large, never too small. Every
#    (pair, beam) candidate is then solved exactly (a 2 × 2 system, or a quadratic for a disc) and
#    the nearest hit of each beam kept (a scatter-min).
#
# Cost (tools/bench_lidar.py): a beam of fixed20 solves about 0.4 candidates besides the map's
# edge; the arrays are a few times the robots × beams. On a grid map every run within range and
# facing the robot is a pair (there is no occlusion: about 86 of ros_arena's 316 runs per robot,
# found among the 64 or so of its cell's table). A DDA over the grid's cells was tried and is
# slower there: a beam crosses about 25 cells of a 0.2 grid before it meets a wall, a step of
# the walk costing about as much as a candidate.

ANGLE_ERROR = 2e-3
"""Bound [rad] on the error of :func:`_angle` (the approximation's own error is below 1.6e-3):
how far the angular interval of a shape is widened before picking the beams in it."""


def _angle(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``atan2(y, x)`` within :data:`ANGLE_ERROR` (and 0 for the zero vector), several times cheaper.

    The vector is folded into the first octant (``z = min/max`` of ``|x|, |y|``), ``atan(z)`` is
    approximated by ``z·(π/4 + (1 − z)(0.2447 + 0.0663 z))`` (error at most 1.51e-3 rad on
    ``[0, 1]``) and unfolded by the octant's symmetries.
    """
    ax, ay = np.abs(x), np.abs(y)
    big = np.maximum(ax, ay)
    z = np.minimum(ax, ay) / np.where(big > 0, big, 1.0)
    a = z * (np.pi / 4 + (1.0 - z) * (0.2447 + 0.0663 * z))
    a = np.where(ay > ax, np.pi / 2 - a, a)
    a = np.where(x < 0, np.pi - a, a)
    return np.copysign(a, y)


@functools.lru_cache(maxsize=16)
def _beam_tables(config: LidarConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The beams' directions in the robot's frame, cosines and sines, and each table index's beam,
    over two turns with a full circle (see :class:`_Beams`)."""
    angles = config.angles()
    turns = 2 if config.fov >= 360 else 1
    tables = np.tile(np.cos(angles), turns), np.tile(np.sin(angles), turns), np.tile(np.arange(config.beams), turns)
    for table in tables:
        table.flags.writeable = False                  # shared by every cast with this config
    return tables


class _Beams:
    """The beams of N robots, worked in each robot's frame (x ahead, y left): the beams' directions
    are one table of K, the shapes are turned into the frames of the robots that see them.

    With a full circle the tables run over two turns (index ``k`` and ``k + K`` are the same
    beam), so that a run of beams past the last one needs no modulo.
    """

    def __init__(self, config: LidarConfig, theta: np.ndarray):
        self.k = config.beams
        self.full = config.fov >= 360
        self.first = -np.pi if self.full else -np.deg2rad(config.fov) / 2
        self.spacing = 2 * np.pi / self.k if self.full else (np.deg2rad(config.fov) / (self.k - 1) if self.k > 1 else 1.0)
        self.cos_beam, self.sin_beam, self.beam_of = _beam_tables(config)
        self.cos, self.sin = np.cos(theta), np.sin(theta)                   # (N,)

    def local(self, robot: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World vectors ``(x, y)`` (P,) in the frames of robots ``robot`` (P,)."""
        c, s = self.cos.take(robot), self.sin.take(robot)
        return c * x + s * y, c * y - s * x

    def candidates(self, robot: np.ndarray, low: np.ndarray, width: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every beam of ``robot[i]`` within the angles ``[low, low + width]`` of its frame (a
        negative width: none): the pair's index, the beam's index ``k`` in the tables and the flat
        index ``robot·K + beam`` of the output."""
        rel = (low - self.first) % (2 * np.pi)                      # from the first beam, [0, 2π)
        parts = []
        for shift in ((0.0,) if self.full else (0.0, 2 * np.pi)):
            x0 = (rel - shift) / self.spacing
            lo = np.ceil(x0).astype(np.intp)
            hi = np.floor(x0 + width / self.spacing).astype(np.intp)
            if self.full:                                            # lo ≤ K: the tables hold 2K
                hi = np.minimum(hi, lo + self.k - 1)
            else:
                lo, hi = np.maximum(lo, 0), np.minimum(hi, self.k - 1)
            count = np.maximum(hi - lo + 1, 0)
            end = np.cumsum(count)
            total = int(end[-1]) if len(end) else 0
            if total:
                pair = np.repeat(np.arange(len(robot)), count)
                parts.append((pair, np.arange(total) + (lo - end + count).take(pair)))
        if not parts:
            empty = np.zeros(0, np.intp)
            return empty, empty, empty
        pair, k = (np.concatenate([p for p, _ in parts]), np.concatenate([k for _, k in parts])) if len(parts) > 1 else parts[0]
        return pair, k, (robot * self.k).take(pair) + self.beam_of.take(k)


def _cast_segments(beams: _Beams, out: np.ndarray, robot: np.ndarray, wx: np.ndarray, wy: np.ndarray,
                   ex: np.ndarray, ey: np.ndarray, reach: float) -> None:
    """Lower ``out`` (N·K,) to the hits of each robot's beams on segments ``a → a + e``, one per
    pair, given in the world's axes from the robot: ``w = a − robot`` and ``e`` (P,) each."""
    if not len(robot):
        return
    # the part of the segment within reach: |w + u·e| ≤ reach for u in [u0, u1] ⊂ [0, 1]
    a2 = ex * ex + ey * ey
    b = wx * ex + wy * ey
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.maximum(b * b - a2 * (wx * wx + wy * wy - reach * reach), 0.0))
        u0, u1 = np.maximum((-b - root) / a2, 0.0), np.minimum((-b + root) / a2, 1.0)
    wx, wy = beams.local(robot, wx, wy)
    ex, ey = beams.local(robot, ex, ey)
    cross = wx * ey - wy * ex                                   # > 0: the segment runs counter-clockwise
    start, stop = _angle(wx + u0 * ex, wy + u0 * ey), _angle(wx + u1 * ex, wy + u1 * ey)
    ccw = cross > 0
    low = np.where(ccw, start, stop) - ANGLE_ERROR
    width = (np.where(ccw, stop, start) - low + ANGLE_ERROR) % (2 * np.pi)
    pair, k, flat = beams.candidates(robot, low, np.where(u0 < u1, width, -1.0))      # none beyond reach
    if not len(pair):
        return
    cx, cy = beams.cos_beam.take(k), beams.sin_beam.take(k)
    ex, ey, wx, wy = ex.take(pair), ey.take(pair), wx.take(pair), wy.take(pair)
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = cx * ey - cy * ex
        t = cross.take(pair) / denom
        u = (wx * cy - wy * cx) / denom
    hit = np.where((u >= 0) & (u <= 1) & (t >= 0), t, np.inf)    # a parallel segment: inf or nan, never a hit
    np.minimum.at(out, flat, hit)


def _cast_discs(beams: _Beams, out: np.ndarray, robot: np.ndarray, fx: np.ndarray, fy: np.ndarray,
                radius: np.ndarray) -> None:
    """Lower ``out`` to the hits of each robot's beams on discs, one per pair, given by the robot
    seen from the disc's centre ``f`` (world axes) and the radius (P,); from inside a disc: 0."""
    if not len(robot):
        return
    q = fx * fx + fy * fy - radius * radius
    inside = q <= 0
    if inside.any():
        out.reshape(len(beams.cos), beams.k)[robot[inside]] = 0.0
    fx, fy = beams.local(robot, fx, fy)
    towards = _angle(-fx, -fy)
    half = _angle(np.sqrt(np.maximum(q, 0.0)), radius)                # asin(radius / distance)
    low = towards - half - 2 * ANGLE_ERROR
    pair, k, flat = beams.candidates(robot, low, np.where(inside, -1.0, 2 * half + 4 * ANGLE_ERROR))
    if not len(pair):
        return
    fx, fy, q = fx.take(pair), fy.take(pair), q.take(pair)
    b = fx * beams.cos_beam.take(k) + fy * beams.sin_beam.take(k)
    disc = b * b - q
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    np.minimum.at(out, flat, np.where((disc >= 0) & (t >= 0), t, np.inf))


def _edge_ranges(beams: _Beams, pos: np.ndarray, size: tuple[float, float]) -> np.ndarray:
    """(N, K) distance along each beam to the map's edge (the rectangle ``[0, w] × [0, h]``, seen
    from inside) in closed form, 0 along the beams leaving the map from a robot on or beyond it.

    The line through ``(x, y)`` of direction ``(dx, dy)`` meets the sides ``x = w`` and ``x = 0``
    at ``(w − x)/dx`` and ``−x/dx``: from a robot strictly inside, one is ahead (positive) and one
    behind (both infinite if ``dx = 0``); likewise in ``y``. The beam reads the nearer side ahead,
    and the beam straight back along the same line the nearer side behind: with a full circle of
    an even number of beams, beam ``k + K/2`` is beam ``k`` turned round, and one line serves both.
    """
    k = beams.k
    half = beams.full and k % 2 == 0
    lines = k // 2 if half else k
    cb, sb = beams.cos_beam[None, :lines], beams.sin_beam[None, :lines]
    c, s = beams.cos[:, None], beams.sin[:, None]
    dx, dy = c * cb - s * sb, s * cb + c * sb                            # the lines' directions in the world
    x, y = pos[:, 0, None], pos[:, 1, None]
    ranges = np.empty((len(pos), k))
    with np.errstate(divide="ignore", invalid="ignore"):
        ix, iy = 1.0 / dx, 1.0 / dy
        far_x, near_x, far_y, near_y = (size[0] - x) * ix, -x * ix, (size[1] - y) * iy, -y * iy
        np.minimum(np.maximum(far_x, near_x), np.maximum(far_y, near_y), out=ranges[:, :lines])
        if half:
            np.negative(np.maximum(np.minimum(far_x, near_x), np.minimum(far_y, near_y)), out=ranges[:, lines:])
    inside = (x[:, 0] > 0) & (x[:, 0] < size[0]) & (y[:, 0] > 0) & (y[:, 0] < size[1])
    if not inside.all():                     # on or beyond the edge: each side ahead, or 0
        out = ~inside
        cb, sb = beams.cos_beam[None, :k], beams.sin_beam[None, :k]
        c, s, x, y = c[out], s[out], x[out], y[out]
        dx, dy = c * cb - s * sb, s * cb + c * sb
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(dx > 0, (size[0] - x) / dx, np.where(dx < 0, -x / dx, np.inf))
            ty = np.where(dy > 0, (size[1] - y) / dy, np.where(dy < 0, -y / dy, np.inf))
        ranges[out] = np.maximum(np.minimum(tx, ty), 0.0)
    return ranges


class _Outlines(NamedTuple):
    """The static segments as the cast sees them (built once per world): every segment directed
    with the obstacle on its left, a polygon's edges and a grid's boundary alike."""

    a: np.ndarray          # (S, 2) segments a → a + e
    e: np.ndarray          # (S, 2)
    grid: np.ndarray       # (S,) the grid a segment bounds (index in ``grids``), -1 a polygon's edge
    grids: tuple[GridObstacle, ...]


def _oriented_runs(occupied: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The boundary of a grid's occupied cells as maximal straight runs ``a → b`` in cell units,
    each directed with the occupied cells on its left (cells beyond the grid are free).

    As :func:`~apf_physics.common.geometry.grid_boundary`, but a run is also cut where the occupied
    cells change sides (one line can bound cells above it, then cells below it), so that a run
    can be cast against from one side only.
    """
    padded = np.pad(np.asarray(occupied, np.int8), 1)
    above = (padded[1:] - padded[:-1])[:, 1:-1]           # (rows + 1, cols): on the line y = i, above − below
    right = (padded[:, 1:] - padded[:, :-1])[1:-1].T      # (cols + 1, rows): on the line x = i, right − left
    starts, ends = [np.zeros((0, 2))], [np.zeros((0, 2))]
    for lines, horizontal in ((above, True), (right, False)):
        for sign in (1, -1):
            edge = np.diff(np.pad((lines == sign).astype(np.int8), ((0, 0), (1, 1))), axis=1)
            line, first = np.nonzero(edge == 1)
            _, last = np.nonzero(edge == -1)                     # runs [first, last) along each line
            # occupied on the left: along +x below occupied cells, along -x above them, along -y
            # left of occupied cells, along +y right of them
            lo, hi = (first, last) if (sign == 1) == horizontal else (last, first)
            a, b = (np.column_stack([lo, line]), np.column_stack([hi, line])) if horizontal else \
                (np.column_stack([line, lo]), np.column_stack([line, hi]))
            starts.append(a)
            ends.append(b)
    return np.vstack(starts).astype(float), np.vstack(ends).astype(float)


def _outlines(world: World) -> _Outlines:
    """The world's static polygons' edges and grids' boundary runs, each directed with its
    obstacle on the left (:func:`_oriented_runs`), for :func:`_seen`."""
    def build() -> _Outlines:
        a_list, e_list, owner, grids = [np.zeros((0, 2))], [np.zeros((0, 2))], [np.zeros(0, np.intp)], []
        for obstacle in world.static_obstacles:
            if isinstance(obstacle, PolygonObstacle):
                a, e = polygon_edges(obstacle.vertices)
                owner.append(np.full(len(a), -1))
            elif isinstance(obstacle, GridObstacle):
                ga, gb = _oriented_runs(obstacle.occupied)
                a, e = ga * obstacle.cell + np.asarray(obstacle.origin, float), (gb - ga) * obstacle.cell
                owner.append(np.full(len(a), len(grids)))
                grids.append(obstacle)
            else:
                continue
            a_list.append(a)
            e_list.append(e)
        return _Outlines(np.vstack(a_list).astype(float), np.vstack(e_list).astype(float),
                         np.concatenate(owner).astype(np.intp), tuple(grids))
    return world.cached("lidar_outlines", build, static=True)


def _in_walls(pos: np.ndarray, grids: Sequence[GridObstacle]) -> np.ndarray:
    """(N, G) whether each robot's centre is in an occupied cell of each grid (it has collided)."""
    inside = np.zeros((len(pos), len(grids)), bool)
    for g, grid in enumerate(grids):
        rows, cols = grid.occupied.shape
        cell = np.floor((pos - np.asarray(grid.origin, float)) / grid.cell).astype(np.intp)
        ok = (cell[:, 0] >= 0) & (cell[:, 0] < cols) & (cell[:, 1] >= 0) & (cell[:, 1] < rows)
        inside[ok, g] = grid.occupied[cell[ok, 1], cell[ok, 0]]
    return inside


def _facing(wx: np.ndarray, wy: np.ndarray, ex: np.ndarray, ey: np.ndarray, reach: float,
            run: np.ndarray | None = None, flip: np.ndarray | None = None) -> np.ndarray:
    """Whether a robot can meet segments ``a → a + e`` first within ``reach``, given ``w = a − robot``
    (arrays that broadcast): it is on the segment's outer side (right: the segments are directed
    with the obstacle on their left), or on the other with ``flip``, or on the line of a grid's
    ``run``; and the segment's nearest point is within ``reach``."""
    cross = wx * ey - wy * ex                                             # > 0: the robot is left of the segment
    mask = cross < 0
    if flip is not None:
        mask ^= flip
    if run is not None:
        mask |= (cross == 0) & run
    a2 = ex * ex + ey * ey
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.minimum(np.maximum(-(wx * ex + wy * ey) / a2, 0.0), 1.0)       # the nearest point: w + u·e
    nx, ny = wx + u * ex, wy + u * ey
    return mask & (nx * nx + ny * ny <= reach * reach)


def _seen(pos: np.ndarray, a: np.ndarray, e: np.ndarray, reach: float, grid: np.ndarray | None = None,
          grids: Sequence[GridObstacle] = ()) -> tuple[np.ndarray, ...]:
    """(robot, segment) pairs that can hold a beam's first hit within ``reach``, and their ``w = a − robot``.

    Segments are directed with the obstacle on their left (a polygon's outline counter-clockwise):
    a robot sees those it is right of. A grid's boundary is also seen from the left by a robot in
    an occupied cell of that grid (it has collided: its beams end where they leave the wall), and
    from a robot on its line. Only segments whose nearest point is within ``reach`` (:func:`_facing`).

    Args:
        pos: (N, 2) robot centres.
        a, e: segments ``a → a + e``: (S, 2) for all robots, or ``a`` (N, S, 2) per robot.
        grid: (S,) the grid of each segment in ``grids``, -1 none (default: none).

    Returns:
        robot, segment, wx, wy: (P,) each.
    """
    wx = a[..., 0] - pos[:, 0, None]                                      # (N, S)
    wy = a[..., 1] - pos[:, 1, None]
    run = flip = None
    if grid is not None and len(grids):
        run = grid >= 0
        inside = _in_walls(pos, grids)
        if inside.any():
            flip = inside[:, np.maximum(grid, 0)] & run                     # from inside a wall: the other side
    mask = _facing(wx, wy, e[:, 0], e[:, 1], reach, run, flip)
    robot, shape = np.nonzero(mask)
    return robot, shape, wx[mask], wy[mask]


CELLS_ABOVE = 64
"""With more static segments than this, the segments a robot can see are looked up by the cell of
the map it is in (:func:`_cells`) rather than tested one and all."""
MOST_CELLS = 4096
"""The cells of :func:`_cells`' table are at most ``max_range / 16`` wide, and no more than this many."""


class _Cells(NamedTuple):
    """For each square cell of the map, the static segments a robot in it can see within range."""

    size: float            # a cell's side
    shape: tuple[int, int]  # (columns, rows) over [0, w] × [0, h]
    start: np.ndarray      # (cells + 1,) the segments of cell c are segment[start[c]:start[c + 1]]
    segment: np.ndarray


def _cells(world: World, reach: float) -> _Cells:
    """Per cell of the map, the static segments (:func:`_outlines`) that a robot anywhere in the
    cell can be on the outer side (or on the line) of, within ``reach`` of it (built once per world and range).

    Conservative: a segment is kept if one of the cell's corners is not on its inner side (the
    sign of a linear function over a square is extreme at a corner), and if its bounding box is
    within ``reach`` of the cell (which is nearer than the segment).
    """
    def build() -> _Cells:
        lines = _outlines(world)
        w, h = world.size
        size = max(reach / 16, float(np.sqrt(w * h / MOST_CELLS)))
        cols, rows = max(int(np.ceil(w / size)), 1), max(int(np.ceil(h / size)), 1)
        b = lines.a + lines.e
        lo, hi = np.minimum(lines.a, b), np.maximum(lines.a, b)
        ex, ey = lines.e[:, 0], lines.e[:, 1]
        kept = []
        for row in range(rows):                        # a row of cells at a time (bounds the temporaries)
            x0, y0 = (np.arange(cols) * size)[:, None], row * size
            gx = np.maximum(np.maximum(lo[:, 0] - (x0 + size), x0 - hi[:, 0]), 0.0)
            gy = np.maximum(np.maximum(lo[:, 1] - (y0 + size), y0 - hi[:, 1]), 0.0)
            near = gx * gx + gy * gy <= reach * reach
            outer = np.zeros_like(near)
            for cx, cy in ((0.0, 0.0), (size, 0.0), (0.0, size), (size, size)):
                outer |= (lines.a[:, 0] - (x0 + cx)) * ey - (lines.a[:, 1] - (y0 + cy)) * ex <= 0
            kept.append(near & outer)
        kept = np.vstack(kept)                          # (cells, S), cell = row · cols + column
        start = np.concatenate([[0], np.cumsum(kept.sum(axis=1))]).astype(np.intp)
        return _Cells(size, (cols, rows), start, np.nonzero(kept)[1].astype(np.intp))
    return world.cached(("lidar_cells", reach), build, static=True)


def _seen_static(pos: np.ndarray, world: World, reach: float) -> tuple[np.ndarray, ...]:
    """:func:`_seen` for the world's static segments: with many, a robot strictly inside the map
    and in no wall tests only the segments of its cell (:func:`_cells`), every other all of them."""
    lines = _outlines(world)
    if len(lines.a) <= CELLS_ABOVE:
        return _seen(pos, lines.a, lines.e, reach, lines.grid, lines.grids)
    cells = _cells(world, reach)
    cols, rows = cells.shape
    column = np.floor(pos[:, 0] / cells.size).astype(np.intp)
    row = np.floor(pos[:, 1] / cells.size).astype(np.intp)
    w, h = world.size
    other = ~((pos[:, 0] > 0) & (pos[:, 0] < w) & (pos[:, 1] > 0) & (pos[:, 1] < h))
    other |= _in_walls(pos, lines.grids).any(axis=1)
    cell = np.where(other, 0, np.minimum(row, rows - 1) * cols + np.minimum(column, cols - 1))
    first = cells.start[cell]
    count = np.where(other, 0, cells.start[cell + 1] - first)
    end = np.cumsum(count)
    robot = np.repeat(np.arange(len(pos)), count)
    shape = cells.segment[np.arange(int(end[-1]) if len(end) else 0) + (first - end + count).take(robot)]
    wx = lines.a[shape, 0] - pos[robot, 0]
    wy = lines.a[shape, 1] - pos[robot, 1]
    keep = _facing(wx, wy, lines.e[shape, 0], lines.e[shape, 1], reach, lines.grid[shape] >= 0)
    robot, shape, wx, wy = robot[keep], shape[keep], wx[keep], wy[keep]
    if other.any():
        apart = np.flatnonzero(other)
        more = _seen(pos[apart], lines.a, lines.e, reach, lines.grid, lines.grids)
        robot, shape, wx, wy = (np.concatenate([mine, theirs]) for mine, theirs in
                                zip((robot, shape, wx, wy), (apart[more[0]],) + more[1:]))
    return robot, shape, wx, wy


def _near_discs(pos: np.ndarray, centre: np.ndarray, radius: np.ndarray, reach: float) -> tuple[np.ndarray, ...]:
    """(robot, disc) pairs whose disc (centres (C, 2) or (N, C, 2)) reaches within ``reach`` of
    the robot, and the robot seen from the disc's centre ``(fx, fy)``."""
    fx = pos[:, 0, None] - centre[..., 0]
    fy = pos[:, 1, None] - centre[..., 1]
    gap = reach + radius
    near = fx * fx + fy * fy <= gap * gap
    robot, shape = np.nonzero(near)
    return robot, shape, fx[near], fy[near]


def teammates(positions: np.ndarray, team: np.ndarray) -> np.ndarray:
    """(N, D, 2) for each robot the centres of the other robots of its team (NaN-padded), for :func:`scan`'s ``others``.

    Args:
        positions: (N, 2) robot centres.
        team: (N,) labels: robots with the same label see each other (a formation's slot, a
            crowd); a robot never sees itself.
    """
    positions = np.asarray(positions, float).reshape(-1, 2)
    team = np.asarray(team).reshape(-1)
    n = len(positions)
    order = np.argsort(team, kind="stable")
    labels, first, size = np.unique(team[order], return_index=True, return_counts=True)
    d = int(size.max()) - 1 if n else 0
    out = np.full((n, max(d, 0), 2), np.nan)
    if d <= 0:
        return out
    group = np.searchsorted(labels, team)                         # each robot's team number
    rank = np.empty(n, np.intp)
    rank[order] = np.arange(n) - np.repeat(first, size)           # place within its team
    members = np.full((len(labels), d + 1), -1, np.intp)
    members[group, rank] = np.arange(n)
    # robot i's others: its team's members but itself
    cols = np.arange(d + 1)[None, :]
    keep = cols != rank[:, None]
    mates = members[group][keep].reshape(n, d)
    ok = mates >= 0
    out[ok] = positions[mates[ok]]
    return out


def _cast(world: World, poses: np.ndarray, config: LidarConfig, t: np.ndarray,
          others: np.ndarray | None) -> np.ndarray:
    """(n, K) ranges, without noise: :func:`scan` for a few robots."""
    n, k = len(poses), config.beams
    pos = poses[:, :2]
    beams = _Beams(config, poses[:, 2])
    reach = float(config.max_range)
    out = _edge_ranges(beams, pos, world.size).ravel()
    np.minimum(out, reach, out=out)
    lines = _outlines(world)
    robot, shape, wx, wy = _seen_static(pos, world, reach)
    _cast_segments(beams, out, robot, wx, wy, lines.e[shape, 0], lines.e[shape, 1], reach)
    geo = static_geometry(world)
    if len(geo.radius):
        robot, shape, fx, fy = _near_discs(pos, geo.centre, geo.radius, reach)
        _cast_discs(beams, out, robot, fx, fy, geo.radius[shape])
    if world.moving:
        mov = moving_geometry(world)
        shift = np.broadcast_to(world.moving_offsets(t), (n, len(world.moving), 2))      # (n, M, 2)
        if len(mov.a):
            robot, shape, wx, wy = _seen(pos, mov.a[None] + shift[:, mov.seg_owner], mov.e, reach)
            _cast_segments(beams, out, robot, wx, wy, mov.e[shape, 0], mov.e[shape, 1], reach)
        if len(mov.centre):
            robot, shape, fx, fy = _near_discs(pos, mov.centre[None] + shift[:, mov.disc_owner], mov.radius, reach)
            _cast_discs(beams, out, robot, fx, fy, mov.radius[shape])
    discs = []
    if len(world.others):
        discs.append(np.broadcast_to(world.others[None], (n,) + world.others.shape))
    if others is not None:
        discs.append(others)
    if discs:
        centre = np.concatenate(discs, axis=1)                                              # (n, D, 2)
        robot, shape, fx, fy = _near_discs(pos, centre, world.robot_radius, reach)
        _cast_discs(beams, out, robot, fx, fy, np.full(len(robot), world.robot_radius))
    return out.reshape(n, k)


def scan(where: World | Moment, poses: np.ndarray, config: LidarConfig = LidarConfig(),
         t: np.ndarray | float | None = None, others: np.ndarray | None = None,
         rng: np.random.Generator | None = None) -> np.ndarray:
    """(N, K) float ranges of the beams of robots at ``poses`` (N, 3) ``(x, y, θ)`` (module docstring).

    Args:
        where: A world, or the world at a step (:meth:`World.at`): its step is ``t``'s default.
        poses: (N, 3) robot centres and headings [units, rad].
        config: The beams.
        t: The control step the moving obstacles are placed at: one for all robots, or (N,)
            (default: the moment's step, else 0).
        others: (N, D, 2) centres of the other robots each robot sees (NaN rows: none), discs of
            the world's robot radius (:func:`teammates`).
        rng: Generator of the noise (required when ``config.noise > 0``).
    """
    world = where.world if isinstance(where, Moment) else where
    if t is None:
        t = where.t if isinstance(where, Moment) else 0.0
    poses = np.asarray(poses, float).reshape(-1, 3)
    n = len(poses)
    t = np.broadcast_to(np.asarray(t, float), (n,))
    others = None if others is None or not np.size(others) else np.asarray(others, float).reshape(n, -1, 2)
    best = np.empty((n, config.beams))
    for first in range(0, n, ROBOTS_PER_CAST):
        part = slice(first, min(first + ROBOTS_PER_CAST, n))
        best[part] = _cast(world, poses[part], config, t[part], None if others is None else others[part])
    ranges = best
    if config.noise > 0:
        if rng is None:
            raise ValueError("lidar noise needs a random generator (rng)")
        ranges = config.noisy(ranges, rng)
    return ranges


class Lidar:
    """A range sensor with its own seeded noise generator: :func:`scan` with a config and an ``rng``.

    Args:
        config: The beams.
        seed: Seed of the noise generator (Gymnasium envs pass their reset seed).
    """

    def __init__(self, config: LidarConfig = LidarConfig(), seed: int | None = None):
        self.config = config
        self.rng = np.random.default_rng(seed)

    def seed(self, seed: int | None) -> None:
        """Restart the noise generator."""
        self.rng = np.random.default_rng(seed)

    def scan(self, where: World | Moment, poses: np.ndarray, t: np.ndarray | float | None = None,
             others: np.ndarray | None = None) -> np.ndarray:
        """(N, K) ranges: :func:`scan`."""
        return scan(where, poses, self.config, t, others, self.rng)

    def scan_worlds(self, worlds: Sequence[World], world_of: np.ndarray, poses: np.ndarray,
                    t: np.ndarray | float = 0.0, others: np.ndarray | None = None) -> np.ndarray:
        """(N, K) ranges of robots each in a world of its own (``worlds[world_of[n]]``), one cast per world."""
        poses = np.asarray(poses, float).reshape(-1, 3)
        world_of = np.asarray(world_of, np.intp).reshape(-1)
        t = np.broadcast_to(np.asarray(t, float), (len(poses),))
        out = np.empty((len(poses), self.config.beams))
        for w in np.unique(world_of).tolist():
            mine = np.flatnonzero(world_of == w)
            out[mine] = self.scan(worlds[w], poses[mine], t[mine], None if others is None else np.asarray(others)[mine])
        return out
