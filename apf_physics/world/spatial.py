"""Distances to many obstacles at a cost that does not grow with their number.

A :class:`ShapeSet` answers one question for ``(N, 2)`` points: the signed distance to each
obstacle within a ``reach`` (docs/real-maps.md). The field sums a repulsive term
over those pairs, and the world takes their least as the clearance.

Polygons and circles, when there are more than :data:`LOOSE_AT_MOST` of them, go into a
bucket index (:class:`~apf_physics.world.buckets.SegmentIndex`): the plane is cut into square
buckets (of at most ``reach / √2``), and each bucket lists the edges and circles within
``reach`` of it, sorted by obstacle. A point is measured only against its bucket's list, in one
vectorised pass over all (point, edge) pairs, so the work per point depends on how many
obstacles are near it, not on how many there are.
Inside a polygon, the side of the nearest edge (or the pseudonormal at the nearest vertex)
gives the sign; a bucket wholly inside a polygon, farther than ``reach`` from its boundary,
carries a marker so that points there read ``−reach``.

Grids, and polygons or circles when there are few, are measured one obstacle at a time (a
grid indexes its own boundary the same way: :meth:`~apf_physics.world.obstacles.GridObstacle.signed_distance`).

Either way a distance is exact wherever ``|d| ≤ reach``; beyond, ``±reach`` is reported,
which no caller can tell apart: the field's repulsion ends at ``p0 ≤ reach`` and every
clearance test asks about less than ``reach``.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from apf_physics.common import geometry
from apf_physics.world.buckets import DISC, EDGE, SegmentIndex
from apf_physics.world.obstacles import CircleObstacle, GridObstacle, Obstacle, PolygonObstacle

QUERY_CHUNK = 1 << 15
"""Points measured at a time by :meth:`ShapeSet.distance` (a whole map's nodes would hold many pairs each)."""
LOOSE_AT_MOST = 8
"""Up to this many polygons and circles are measured one by one: an index would cost more than it saves."""


class ShapeSet:
    """Obstacles, as they stand, ready for distance queries within ``reach``.

    Args:
        obstacles: The obstacles (moving ones as they are written; pass moved copies to
            measure them elsewhere).
        reach: Distances up to this are exact; farther ones read ``±reach``.
    """

    def __init__(self, obstacles: Sequence[Obstacle], reach: float):
        self.obstacles = tuple(obstacles)
        self.reach = float(reach)
        shapes = [i for i, o in enumerate(self.obstacles) if isinstance(o, (PolygonObstacle, CircleObstacle))]
        indexed = shapes if len(shapes) > LOOSE_AT_MOST else []
        self.loose = [i for i in range(len(self.obstacles)) if i not in set(indexed)]
        self._index = _index_of([self.obstacles[i] for i in indexed], np.array(indexed, np.intp), self.reach) \
            if indexed else None

    def __len__(self) -> int:
        return len(self.obstacles)

    def pairs(self, points: np.ndarray, nearest_only: bool = False,
              with_nearest: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """Every (point, obstacle) within ``reach`` of each other (some farther ones too).

        ``nearest_only``: only the pairs that may hold a point's least distance (what
        :meth:`distance` needs): the index's pruned lists, a few per point however dense.
        ``with_nearest`` False: the nearest points are not computed (None).

        Returns:
            ``(point (P,), obstacle (P,), distance (P,), nearest (P, 2))``: indices into
            ``points`` and :attr:`obstacles`, the signed distance (negative inside; within
            ``[−reach, reach]``) and the nearest boundary point.
        """
        points = np.asarray(points, float).reshape(-1, 2)
        index = self._index if self._index is None or not nearest_only else self._index.nearest_only()
        parts = [] if index is None else [index.pairs(points, with_nearest)]
        xs, ys = np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])
        for i in self.loose:
            obstacle = self.obstacles[i]
            lo, hi = obstacle.bounds
            idx = np.flatnonzero((xs >= lo[0] - self.reach) & (xs <= hi[0] + self.reach)
                                 & (ys >= lo[1] - self.reach) & (ys <= hi[1] + self.reach))
            if not len(idx):
                continue
            if isinstance(obstacle, GridObstacle):
                d, nearest = obstacle.signed_distance(points[idx], self.reach)
            else:
                d, nearest = obstacle.signed_distance(points[idx])
            parts.append((idx, np.full(len(idx), i, np.intp), np.clip(d, -self.reach, self.reach),
                          nearest if with_nearest else None))
        if not parts:
            return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0), np.zeros((0, 2)) if with_nearest else None
        if len(parts) == 1:
            return parts[0]
        who, owner, d, nearest = zip(*parts)
        return (np.concatenate(who), np.concatenate(owner), np.concatenate(d),
                np.concatenate(nearest) if with_nearest else None)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Least signed distance from each point to any obstacle: exact below ``reach``; ``reach``
        where none is that near; ``+inf`` when the set is empty."""
        points = np.asarray(points, float).reshape(-1, 2)
        if not self.obstacles:
            return np.full(len(points), np.inf)
        out = np.full(len(points), self.reach)
        for first in range(0, len(points), QUERY_CHUNK):   # a chunk at a time: the pairs' temporaries stay small
            who, _, d, _ = self.pairs(points[first:first + QUERY_CHUNK], nearest_only=True, with_nearest=False)
            np.minimum.at(out, who + first, d)
        return out


def _index_of(obstacles: list[Obstacle], numbers: np.ndarray, reach: float) -> SegmentIndex:
    """The bucket index of polygons' edges and circles, with markers inside large polygons."""
    return SegmentIndex(reach, _primitives(obstacles, numbers),
                        lambda origin, side, shape: _interior_buckets(obstacles, numbers, origin, side, shape, reach))


def _primitives(obstacles: list[Obstacle], numbers: np.ndarray):
    """Edges (radius 0) and circles (a point segment with a radius) of polygons and circles, with
    each edge's outward normal and the pseudonormals at its two ends."""
    a, b, radius, owner, kind, normal, pn_a, pn_b = [], [], [], [], [], [], [], []
    for number, obstacle in zip(numbers.tolist(), obstacles):
        if isinstance(obstacle, CircleObstacle):
            a.append(obstacle.center[None])
            b.append(obstacle.center[None])
            radius.append([obstacle.radius])
            owner.append([number])
            kind.append([DISC])
            normal.append(np.zeros((1, 2)))
            pn_a.append(np.zeros((1, 2)))
            pn_b.append(np.zeros((1, 2)))
            continue
        v = obstacle.vertices                      # counter-clockwise
        w = np.roll(v, -1, axis=0)
        edge = w - v
        n = np.column_stack([edge[:, 1], -edge[:, 0]])          # outward (to the right of a CCW edge)
        n /= np.maximum(np.hypot(n[:, 0], n[:, 1]), 1e-300)[:, None]
        at_start = np.roll(n, 1, axis=0) + n                     # vertex i: edges i-1 and i
        a.append(v)
        b.append(w)
        radius.append(np.zeros(len(v)))
        owner.append(np.full(len(v), number))
        kind.append(np.full(len(v), EDGE))
        normal.append(n)
        pn_a.append(at_start)
        pn_b.append(np.roll(at_start, -1, axis=0))
    return (np.vstack(a), np.vstack(b), np.concatenate(radius), np.concatenate(owner).astype(np.intp),
            np.concatenate(kind).astype(np.int8), np.vstack(normal), np.vstack(pn_a), np.vstack(pn_b))


def _interior_buckets(obstacles: list[Obstacle], numbers: np.ndarray, origin: np.ndarray, side: float,
                      shape: np.ndarray, reach: float) -> np.ndarray:
    """``(K, 3)`` rows ``(col, row, obstacle)``: buckets wholly inside a polygon, their centre
    farther than half a bucket's diagonal from its boundary."""
    rows = []
    half = side * math.sqrt(2.0) / 2
    for number, obstacle in zip(numbers.tolist(), obstacles):
        if not isinstance(obstacle, PolygonObstacle):
            continue
        lo, hi = obstacle.bounds
        if np.min(hi - lo) < 2 * half:
            continue   # holds no disc of radius ``half``, so no bucket centre that deep
        c0 = np.floor((lo - origin) / side).astype(np.intp).clip(0, shape - 1)
        c1 = np.floor((hi - origin) / side).astype(np.intp).clip(0, shape - 1)
        cx, cy = np.meshgrid(np.arange(c0[0], c1[0] + 1), np.arange(c0[1], c1[1] + 1))
        cells = np.column_stack([cx.ravel(), cy.ravel()])
        centres = origin + (cells + 0.5) * side
        d, _ = geometry.polygon_signed_distance(centres, obstacle.vertices)
        deep = cells[d <= -half]
        if len(deep):
            rows.append(np.column_stack([deep, np.full(len(deep), number)]))
    return np.vstack(rows).astype(np.intp) if rows else np.zeros((0, 3), np.intp)
