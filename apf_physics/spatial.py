"""Distances to many obstacles at a cost that does not grow with their number.

A :class:`ShapeSet` answers one question for ``(N, 2)`` points: the signed distance to each
obstacle within a ``reach`` (docs/model.md, "Obstacles"). The field sums a repulsive term
over those pairs, and the world takes their least as the clearance.

Polygons and circles, when there are more than :data:`LOOSE_AT_MOST` of them, go into a
bucket index: the plane is cut into square buckets (of at most ``reach / √2``), and each
bucket lists the edges and circles within ``reach`` of it, sorted by obstacle. A point is measured
only against its bucket's list, in one vectorised pass over all (point, edge) pairs, so the
work per point depends on how many obstacles are near it, not on how many there are.
Inside a polygon, the side of the nearest edge (or the pseudonormal at the nearest vertex)
gives the sign; a bucket wholly inside a polygon, farther than ``reach`` from its boundary,
carries a marker so that points there read ``−reach``.

Grids, and polygons or circles when there are few, are measured one obstacle at a time
(a grid's own search is already local: :meth:`~apf_physics.obstacles.GridObstacle.signed_distance`).

Either way a distance is exact wherever ``|d| ≤ reach``; beyond, ``±reach`` is reported,
which no caller can tell apart: the field's repulsion ends at ``p0 ≤ reach`` and every
clearance test asks about less than ``reach``.
"""

from __future__ import annotations

import copy
import math
from typing import Sequence

import numpy as np

from apf_physics import geometry
from apf_physics.obstacles import CircleObstacle, GridObstacle, Obstacle, PolygonObstacle

LOOSE_AT_MOST = 8
"""Up to this many polygons and circles are measured one by one: an index would cost more than it saves."""
MAX_BUCKETS = 64_000_000
"""Most buckets of one index (larger ones are taken beyond, up to ``reach / √2``)."""

_EDGE, _CIRCLE, _MARKER = 0, 1, 2


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
        self._index = _BucketIndex([self.obstacles[i] for i in indexed], np.array(indexed, np.intp), self.reach) \
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
        who, _, d, _ = self.pairs(points, nearest_only=True, with_nearest=False)
        np.minimum.at(out, who, d)
        return out


class _BucketIndex:
    """Edges and circles of many obstacles, bucketed (see the module's docstring)."""

    def __init__(self, obstacles: list[Obstacle], numbers: np.ndarray, reach: float):
        a, b, radius, owner, kind, normal, pn_a, pn_b = _primitives(obstacles, numbers)
        lo = np.minimum(a, b) - radius[:, None]
        hi = np.maximum(a, b) + radius[:, None]
        self.reach = reach
        self.origin = lo.min(axis=0) - reach
        extent = hi.max(axis=0) + reach - self.origin
        # small buckets (fewer candidates per point), but at most reach/√2 (see _interior_buckets)
        side = min(reach / math.sqrt(2.0), max(0.5, reach / 6.0))
        if np.prod(np.ceil(extent / side) + 1) > MAX_BUCKETS:
            side = min(reach / math.sqrt(2.0), float(np.sqrt(np.prod(extent) / MAX_BUCKETS)) * 1.01)
        self.side = side
        self.shape = np.maximum(np.ceil(extent / side).astype(np.intp), 1)     # (cols, rows)
        # (bucket, primitive) registrations: each edge or circle in every bucket whose centre is
        # within reach plus half a bucket's diagonal of it (every point of the bucket within reach of it)
        c0 = np.floor((lo - reach - self.origin) / side).astype(np.intp).clip(0, self.shape - 1)
        c1 = np.floor((hi + reach - self.origin) / side).astype(np.intp).clip(0, self.shape - 1)
        span = c1 - c0 + 1
        count = span[:, 0] * span[:, 1]
        prim = np.repeat(np.arange(len(a)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        bx = c0[prim, 0] + k % span[prim, 0]
        by = c0[prim, 1] + k // span[prim, 0]
        centre = self.origin + (np.column_stack([bx, by]) + 0.5) * side
        seg = b[prim] - a[prim]
        t = np.clip(np.einsum("ij,ij->i", centre - a[prim], seg) / np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-300),
                    0.0, 1.0)
        gap = np.hypot(*(centre - a[prim] - t[:, None] * seg).T) - radius[prim]
        near = gap <= reach + side * math.sqrt(2.0) / 2
        prim, bucket = prim[near], (by * self.shape[0] + bx)[near]
        # markers: buckets wholly inside a polygon, farther than reach from its edges
        marks = _interior_buckets(obstacles, numbers, self.origin, side, self.shape, reach)
        if len(marks):
            first = len(a)
            a = np.vstack([a, np.zeros((len(marks), 2))])
            b = np.vstack([b, np.zeros((len(marks), 2))])
            radius = np.concatenate([radius, np.zeros(len(marks))])
            owner = np.concatenate([owner, marks[:, 2]])
            kind = np.concatenate([kind, np.full(len(marks), _MARKER, np.int8)])
            normal, pn_a, pn_b = (np.vstack([x, np.zeros((len(marks), 2))]) for x in (normal, pn_a, pn_b))
            bucket = np.concatenate([bucket, marks[:, 1] * self.shape[0] + marks[:, 0]])
            prim = np.concatenate([prim, np.arange(first, len(a))])
        self.a, self.b, self.radius, self.owner, self.kind = a, b, radius, owner, kind
        self.normal, self.pn_a, self.pn_b = normal, pn_a, pn_b
        self.has_markers = bool(len(marks))
        self.ax, self.ay = a[:, 0].copy(), a[:, 1].copy()
        self.dx, self.dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        length2 = self.dx**2 + self.dy**2
        self.inverse_length2 = np.where(length2 > 0, 1.0 / np.where(length2 > 0, length2, 1.0), 0.0)
        order = np.lexsort((prim, owner[prim], bucket))       # by bucket, then obstacle
        self.members = prim[order]
        counts = np.bincount(bucket, minlength=int(self.shape[0] * self.shape[1]))
        self.start = np.concatenate([[0], np.cumsum(counts)])
        self._pruned: _BucketIndex | None = None

    def nearest_only(self) -> _BucketIndex:
        """This index with each bucket's list cut to what may be nearest to one of its points (built once).

        Signed distance to an obstacle changes no faster than position, so over a bucket of
        centre ``c`` and half-diagonal ``h`` it stays within ``h`` of its value at ``c``. The
        least at any point of the bucket is therefore held by an obstacle with
        ``d_O(c) ≤ min_O' d_O'(c) + 2h``, and by an edge of it no farther from ``c`` than
        ``|d_O(c)| + 2h``; the others are dropped (markers stay with their obstacle).
        """
        if self._pruned is not None:
            return self._pruned
        buckets = np.flatnonzero(np.diff(self.start) > 0)
        cols = self.shape[0]
        centres = self.origin + (np.column_stack([buckets % cols, buckets // cols]) + 0.5) * self.side
        _, _, d, _ = self.pairs(centres, with_nearest=False)   # one row per (bucket, obstacle), in members' order
        counts = np.diff(self.start)[buckets]
        bucket_of = np.repeat(buckets, counts)
        owner = self.owner[self.members]
        change = np.concatenate([[True], (bucket_of[1:] != bucket_of[:-1]) | (owner[1:] != owner[:-1])])
        group = np.cumsum(change) - 1                      # (bucket, obstacle) group of each registration
        first_of_bucket = np.concatenate([[True], bucket_of[1:] != bucket_of[:-1]])[change]
        least = np.minimum.reduceat(d, np.flatnonzero(first_of_bucket))
        least = np.repeat(least, np.diff(np.append(np.flatnonzero(first_of_bucket), len(d))))
        h2 = self.side * math.sqrt(2.0)                    # twice the half-diagonal
        c = self.origin + (np.column_stack([bucket_of % cols, bucket_of // cols]) + 0.5) * self.side
        a, seg = self.a[self.members], self.b[self.members] - self.a[self.members]
        t = np.clip(np.einsum("ij,ij->i", c - a, seg) / np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-300), 0.0, 1.0)
        gap = np.hypot(*(c - a - t[:, None] * seg).T) - self.radius[self.members]
        keep = d[group] <= least[group] + h2
        keep &= (self.kind[self.members] == _MARKER) | (gap <= np.abs(d[group]) + h2)
        pruned = copy.copy(self)
        pruned.members = self.members[keep]
        pruned.start = np.concatenate([[0], np.cumsum(np.bincount(bucket_of[keep], minlength=len(self.start) - 1))])
        pruned._pruned = pruned
        self._pruned = pruned
        return pruned

    def pairs(self, points: np.ndarray, with_nearest: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """One row per (point, obstacle) in the points' buckets: see :meth:`ShapeSet.pairs`."""
        cell = np.floor((points - self.origin) / self.side).astype(np.intp)
        inside = (cell[:, 0] >= 0) & (cell[:, 0] < self.shape[0]) & (cell[:, 1] >= 0) & (cell[:, 1] < self.shape[1])
        bucket = np.where(inside, cell[:, 1] * self.shape[0] + cell[:, 0], 0)
        first = self.start[bucket]
        count = np.where(inside, self.start[bucket + 1] - first, 0)
        total = int(count.sum())
        if not total:
            return np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros(0), np.zeros((0, 2)) if with_nearest else None
        who = np.repeat(np.arange(len(points)), count)
        prim = self.members[np.repeat(first - (np.cumsum(count) - count), count) + np.arange(total)]
        # the point's offset from its nearest point of each primitive (1-D columns: cheaper than (P, 2) rows)
        dx, dy = self.dx[prim], self.dy[prim]
        rx = points[who, 0] - self.ax[prim]
        ry = points[who, 1] - self.ay[prim]
        t = (rx * dx + ry * dy) * self.inverse_length2[prim]
        np.clip(t, 0.0, 1.0, out=t)
        ex = rx - t * dx
        ey = ry - t * dy
        gap = np.hypot(ex, ey) - self.radius[prim]          # a circle: to its rim
        if self.has_markers:
            gap = np.where(self.kind[prim] == _MARKER, self.reach, gap)
        # one row per (point, obstacle): the pairs come sorted by point, then obstacle
        owner = self.owner[prim]
        change = np.empty(total, bool)
        change[0] = True
        np.not_equal(who[1:], who[:-1], out=change[1:])
        change[1:] |= owner[1:] != owner[:-1]
        starts = np.flatnonzero(change)
        if len(starts) == total:
            best = np.arange(total)
            least = gap
        else:
            group = np.cumsum(change) - 1
            least = np.minimum.reduceat(gap, starts)
            best = np.minimum.reduceat(np.where(gap == least[group], np.arange(total), total), starts)
        e = prim[best]
        kind, t, ex, ey = self.kind[e], t[best], ex[best], ey[best]
        # sign: circles carry it already; an edge's side (or its vertex's pseudonormal); a marker is inside
        at_a, at_b = t <= 0.0, t >= 1.0
        side = (ex * np.where(at_a, self.pn_a[e, 0], np.where(at_b, self.pn_b[e, 0], self.normal[e, 0]))
                + ey * np.where(at_a, self.pn_a[e, 1], np.where(at_b, self.pn_b[e, 1], self.normal[e, 1])))
        edge = kind == _EDGE
        signed = np.where(edge & (side < 0), -least, least)
        signed = np.where(edge & (least > self.reach), self.reach, signed)
        if self.has_markers:
            signed = np.where(kind == _MARKER, -self.reach, signed)
        np.clip(signed, -self.reach, self.reach, out=signed)
        who, owner = who[best], owner[best]
        if not with_nearest:
            return who, owner, signed, None
        p = points[who]
        nearest = p - np.column_stack([ex, ey])
        r = self.radius[e]
        circle = (kind == _CIRCLE) & (r > 0)
        if circle.any():
            norm = np.hypot(ex[circle], ey[circle])
            unit = np.where(norm[:, None] > 0, np.column_stack([ex[circle], ey[circle]]) / np.where(norm > 0, norm, 1.0)[:, None],
                            [1.0, 0.0])
            nearest[circle] = nearest[circle] + unit * r[circle, None]
        if self.has_markers:
            nearest = np.where((kind == _MARKER)[:, None], p, nearest)
        return who, owner, signed, nearest


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
            kind.append([_CIRCLE])
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
        kind.append(np.full(len(v), _EDGE))
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
