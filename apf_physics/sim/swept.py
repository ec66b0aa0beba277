"""The physics' exact questions about a world's static obstacles, compiled.

Which robots does the physics send to pymunk this step
(:meth:`~apf_physics.sim.physics.Physics.needs_physics`)? Those whose move comes within their
radius (and a margin) of something: :meth:`SweptDistances.near` measures, for every robot, the least
distance between the segment its centre sweeps (from where it is to where its command takes
it) and every static edge, disc, grid boundary and the map's edge. A robot sliding along a wall
that it never touches stays out of pymunk.

Where does a robot alone in its slot end when pymunk left it overlapping a shape at its last
substep? :meth:`SweptDistances.settle` pushes it out, asking for the nearest static shape after each push.

Each world's static geometry (:func:`~apf_physics.world.outlines.static_geometry`) goes into a bucket
index (:class:`~apf_physics.world.buckets.SegmentIndex` of reach 0: square buckets, each listing the
primitives that pass through it); a query scans the buckets its box covers, in one compiled
loop over all robots (:func:`_near_static`, :func:`_settle`). The worlds in use are stacked, so
one call serves robots of many worlds.
"""

from __future__ import annotations

import math

import numpy as np

from apf_physics.world.buckets import EDGE, DISC, SegmentIndex
from apf_physics.common.compiled import kernel
from apf_physics.world.outlines import static_geometry
from apf_physics.world.core import World

BUCKET_SIDE = 0.5
"""The side of the bucket index's squares (:class:`~apf_physics.world.buckets.SegmentIndex` of reach 0:
each lists the primitives that pass through it), or larger on a map of more than
:data:`MOST_BUCKETS` of them. A query scans every bucket its box covers, so a query of any
distance is exact."""
MOST_BUCKETS = 1_000_000


def _index(world: World) -> SegmentIndex | None:
    """The world's static obstacles' edges, discs and grid runs in a bucket index within
    ``REACH`` (built once per map), or None if it has none."""
    def build() -> SegmentIndex | None:
        geometry = static_geometry(world)
        a = np.vstack([geometry.a, geometry.centre])
        b = np.vstack([geometry.a + geometry.e, geometry.centre])
        if not len(a):
            return None
        radius = np.concatenate([np.zeros(len(geometry.a)), geometry.radius])
        kind = np.concatenate([np.full(len(geometry.a), EDGE), np.full(len(geometry.centre), DISC)]).astype(np.int8)
        zeros = np.zeros((len(a), 2))
        side = max(BUCKET_SIDE, math.sqrt(world.size[0] * world.size[1] / MOST_BUCKETS))
        return SegmentIndex(0.0, (a, b, radius, np.zeros(len(a), np.intp), kind, zeros, zeros, zeros), side=side)
    return world.cached(("swept_index", BUCKET_SIDE), build, static=True)


class SweptDistances:
    """The static geometry of the worlds in use, stacked for one compiled query over robots of many worlds."""

    def __init__(self):
        self._ids: dict[int, int] = {}
        self._worlds: list[tuple[SegmentIndex | None, tuple[float, float]]] = []
        self._tables: tuple | None = None

    def add(self, world: World) -> int:
        """The number of ``world``'s map among those added (added if new)."""
        index = _index(world)
        key = id(index) if index is not None else id(world)
        if key not in self._ids:
            self._ids[key] = len(self._worlds)
            self._worlds.append((index, (float(world.size[0]), float(world.size[1]))))
            self._tables = None
        return self._ids[key]

    def _stack(self) -> tuple:
        """Every world's buckets and primitives in one set of arrays (per-world offsets)."""
        grids, starts, members, prims = [], [], [], []
        bucket_base = member_base = prim_base = 0
        for index, size in self._worlds:
            if index is None:
                grids.append((0.0, 0.0, 1.0, 0, 0, 0, *size))
                continue
            cols, rows = (int(n) for n in index.shape)
            grids.append((float(index.origin[0]), float(index.origin[1]), float(index.side), cols, rows,
                          bucket_base, *size))
            starts.append(index.start[:-1] + member_base)
            members.append(index.members + prim_base)
            prims.append(np.column_stack([index.ax, index.ay, index.dx, index.dy, index.radius]))
            bucket_base += cols * rows
            member_base += len(index.members)
            prim_base += len(index.ax)
        start = np.concatenate(starts + [[member_base]]).astype(np.intp)
        member = np.concatenate(members).astype(np.intp) if members else np.zeros(0, np.intp)
        prim = np.vstack(prims) if prims else np.zeros((0, 5))
        grid = np.array([g[:3] + g[6:] for g in grids], float).reshape(-1, 5)        # origin x, y, side, width, height
        shape = np.array([g[3:6] for g in grids], np.intp).reshape(-1, 3)          # cols, rows, first bucket
        return grid, shape, start, member, np.ascontiguousarray(prim)

    def tables(self) -> tuple:
        """The stacked worlds' arrays ``(grid, shape, start, member, prim)``, as the compiled loops take them."""
        if self._tables is None:
            self._tables = self._stack()
        return self._tables

    def near(self, world: np.ndarray, p: np.ndarray, move: np.ndarray, distance: np.ndarray) -> np.ndarray:
        """(K,) bool: the segment from ``p`` to ``p + move`` (each (K, 2)) comes within ``distance``
        (K,) of a static obstacle or the map's edge of its world (``world`` (K,), numbers from
        :meth:`add`). Exact up to rounding."""
        if self._tables is None:
            self._tables = self._stack()
        grid, shape, start, member, prim = self._tables
        p = np.ascontiguousarray(p, float)
        q = np.ascontiguousarray(p + move, float)
        return _near_static(np.ascontiguousarray(world, np.intp), p, q, np.ascontiguousarray(distance, float),
                            grid, shape, start, member, prim)

    def near_one(self, world: int, px: float, py: float, qx: float, qy: float, distance: float) -> bool:
        """:meth:`near` for one move ``(px, py) → (qx, qy)``, in plain floats."""
        if self._tables is None:
            self._tables = self._stack()
        return _move_near(world, px, py, qx, qy, distance, *self._tables)

    def settle(self, world: np.ndarray, p: np.ndarray, before: np.ndarray, radius: np.ndarray, first: np.ndarray,
               planes: np.ndarray, tolerance: float, rounds: int) -> np.ndarray:
        """Robots that meet no other robot, at ``p`` (K, 2), overlapping static shapes, pushed out.

        Robot ``i`` overlaps the shapes whose ``planes[first[i]:first[i + 1]]`` (way out x, y;
        depth) were read at ``p[i]`` (the last substep's arbiters); each shape's boundary is taken
        as the plane there. The robot is pushed out of the plane it overlaps most, 0.001 beyond,
        until none by more than ``tolerance``; then the static shape nearest its centre (the map's
        edge included) is looked up, and one overlapped by more than ``tolerance`` is added as a
        plane, and so on. After ``rounds`` lookups a robot still overlapping goes back to
        ``before[i]`` (where it started the step) and is settled there the same way.

        Returns:
            (K, 2) where each robot ends.
        """
        if self._tables is None:
            self._tables = self._stack()
        grid, shape, start, member, prim = self._tables
        return _settle(np.ascontiguousarray(world, np.intp), np.ascontiguousarray(p, float),
                       np.ascontiguousarray(before, float), np.ascontiguousarray(radius, float),
                       np.ascontiguousarray(first, np.intp), np.ascontiguousarray(planes, float).reshape(-1, 3),
                       float(tolerance), int(rounds), grid, shape, start, member, prim)


@kernel
def _near_static(world, p, q, distance, grid, shape, start, member, prim):
    """For each move ``p[i] → q[i]`` in world ``world[i]``: :func:`_move_near`."""
    n = p.shape[0]
    out = np.zeros(n, np.bool_)
    for i in range(n):
        out[i] = _move_near(world[i], p[i, 0], p[i, 1], q[i, 0], q[i, 1], distance[i], grid, shape, start, member, prim)
    return out


@kernel
def _move_near(w, px, py, qx, qy, need, grid, shape, start, member, prim):
    """Does the move ``(px, py) → (qx, qy)`` in world ``w`` come within ``need`` of the map's edge
    or of a primitive (a segment ``a + t·e``, ``t ∈ [0, 1]``, with a radius) listed in a bucket
    that the move's box, widened by ``need``, covers?"""
    # the map's edge: a straight move is nearest to it at one of its ends
    width, height = grid[w, 3], grid[w, 4]
    if min(px, qx) < need or min(py, qy) < need or width - max(px, qx) < need or height - max(py, qy) < need:
        return True
    cols, rows, first = shape[w, 0], shape[w, 1], shape[w, 2]
    if cols == 0:
        return False
    ox, oy, side = grid[w, 0], grid[w, 1], grid[w, 2]
    c0 = max(int(np.floor((min(px, qx) - need - ox) / side)), 0)
    c1 = min(int(np.floor((max(px, qx) + need - ox) / side)), cols - 1)
    r0 = max(int(np.floor((min(py, qy) - need - oy) / side)), 0)
    r1 = min(int(np.floor((max(py, qy) + need - oy) / side)), rows - 1)
    dx, dy = qx - px, qy - py
    for row in range(r0, r1 + 1):
        for col in range(c0, c1 + 1):
            bucket = first + row * cols + col
            for k in range(start[bucket], start[bucket + 1]):
                j = member[k]
                if _segment_distance(px, py, dx, dy, prim[j, 0], prim[j, 1], prim[j, 2], prim[j, 3]) < need + prim[j, 4]:
                    return True
    return False


@kernel
def _point_segment(x, y, ax, ay, ex, ey):
    """Distance from ``(x, y)`` to the segment ``a + t·e``, ``t ∈ [0, 1]``."""
    length2 = ex * ex + ey * ey
    t = 0.0
    if length2 > 0.0:
        t = min(max(((x - ax) * ex + (y - ay) * ey) / length2, 0.0), 1.0)
    return np.hypot(x - ax - t * ex, y - ay - t * ey)


@kernel
def _segment_distance(px, py, dx, dy, ax, ay, ex, ey):
    """Least distance between the segments ``p + s·d`` and ``a + t·e`` (``s, t ∈ [0, 1]``): 0 if
    they cross, else the least distance from an end of one to the other."""
    # they cross when each one's ends lie strictly on both sides of the other's line
    side_a = dx * (ay - py) - dy * (ax - px)
    side_b = dx * (ay + ey - py) - dy * (ax + ex - px)
    side_p = ex * (py - ay) - ey * (px - ax)
    side_q = ex * (py + dy - ay) - ey * (px + dx - ax)
    if side_a * side_b < 0.0 and side_p * side_q < 0.0:
        return 0.0
    return min(min(_point_segment(px, py, ax, ay, ex, ey), _point_segment(px + dx, py + dy, ax, ay, ex, ey)),
               min(_point_segment(ax, ay, px, py, dx, dy), _point_segment(ax + ex, ay + ey, px, py, dx, dy)))


@kernel
def _nearest_static(w, x, y, within, grid, shape, start, member, prim):
    """The static shape of world ``w`` nearest to ``(x, y)`` if nearer than ``within``:
    ``(found, way out x, y (unit), distance)``; the map's edge counts (a wall beyond each side)."""
    width, height = grid[w, 3], grid[w, 4]
    best, gx, gy = within, 0.0, 0.0
    for d, nx, ny in ((x, 1.0, 0.0), (width - x, -1.0, 0.0), (y, 0.0, 1.0), (height - y, 0.0, -1.0)):
        if d < best:
            best, gx, gy = d, nx, ny
    cols, rows, first = shape[w, 0], shape[w, 1], shape[w, 2]
    if cols > 0:
        ox, oy, side = grid[w, 0], grid[w, 1], grid[w, 2]
        c0 = max(int(np.floor((x - within - ox) / side)), 0)
        c1 = min(int(np.floor((x + within - ox) / side)), cols - 1)
        r0 = max(int(np.floor((y - within - oy) / side)), 0)
        r1 = min(int(np.floor((y + within - oy) / side)), rows - 1)
        for row in range(r0, r1 + 1):
            for col in range(c0, c1 + 1):
                bucket = first + row * cols + col
                for k in range(start[bucket], start[bucket + 1]):
                    j = member[k]
                    ax, ay, ex, ey = prim[j, 0], prim[j, 1], prim[j, 2], prim[j, 3]
                    length2 = ex * ex + ey * ey
                    t = 0.0
                    if length2 > 0.0:
                        t = min(max(((x - ax) * ex + (y - ay) * ey) / length2, 0.0), 1.0)
                    rx, ry = x - ax - t * ex, y - ay - t * ey
                    norm = np.hypot(rx, ry)
                    if norm - prim[j, 4] < best and norm > 0.0:
                        best, gx, gy = norm - prim[j, 4], rx / norm, ry / norm
    return best < within, gx, gy, best


@kernel
def _settle(world, p, before, radius, first, planes, tolerance, rounds, grid, shape, start, member, prim):
    """Robots alone in their slots, each at ``p[i]`` overlapping the static shapes whose planes
    ``planes[first[i]:first[i + 1]]`` (way out x, y; depth) were read at ``p[i]``, pushed out:
    see :meth:`SweptDistances.settle`."""
    n = p.shape[0]
    out = p.copy()
    for i in range(n):
        w, r = world[i], radius[i]
        x, y = p[i, 0], p[i, 1]
        size = first[i + 1] - first[i]
        plane = np.empty((size + 2 * rounds, 5))   # way out x, y; depth; where measured x, y
        for k in range(size):
            plane[k, 0], plane[k, 1], plane[k, 2] = planes[first[i] + k, 0], planes[first[i] + k, 1], planes[first[i] + k, 2]
            plane[k, 3], plane[k, 4] = x, y
        for round_ in range(2 * rounds):
            if round_ == rounds:   # still overlapping: back to the step's start, and what is there
                x, y = before[i, 0], before[i, 1]
                size = 0
            for _ in range(20):
                if size == 0:
                    break
                depth, nx, ny = -np.inf, 0.0, 0.0
                for k in range(size):
                    d = plane[k, 2] - plane[k, 0] * (x - plane[k, 3]) - plane[k, 1] * (y - plane[k, 4])
                    if d > depth:
                        depth, nx, ny = d, plane[k, 0], plane[k, 1]
                if depth <= tolerance:
                    break
                x, y = x + (depth + 1e-3) * nx, y + (depth + 1e-3) * ny
            found, gx, gy, distance = _nearest_static(w, x, y, r - tolerance, grid, shape, start, member, prim)
            if not found:
                break
            plane[size, 0], plane[size, 1], plane[size, 2], plane[size, 3], plane[size, 4] = gx, gy, r - distance, x, y
            size += 1
        out[i, 0], out[i, 1] = x, y
    return out
