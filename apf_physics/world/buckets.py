"""A bucket index of segments and discs: exact distances within a reach, at a cost set by what is near.

:class:`SegmentIndex` serves the obstacles of a world (polygon edges and circles, through
:class:`~apf_physics.world.spatial.ShapeSet`) and the boundary of a grid's occupied cells
(:class:`~apf_physics.world.obstacles.GridObstacle`).
"""

from __future__ import annotations

import copy
import math
from typing import Callable

import numpy as np

EDGE, DISC, MARKER = 0, 1, 2
"""Kinds of primitive: a polygon's edge (or a bare segment), a disc, a bucket inside an owner."""
REGISTER_CHUNK = 2048
"""Primitives registered in buckets at a time (their temporaries stay within about 30 MB)."""
MAX_BUCKETS = 64_000_000
"""Most buckets of one index (larger ones are taken beyond, up to ``reach / √2``)."""


class SegmentIndex:
    """Segments and discs (a segment with a radius), bucketed for distance queries within ``reach``.

    The plane is cut into square buckets (of at most ``reach / √2``); each bucket lists the
    primitives within ``reach`` of it, sorted by owner. A query measures each point only against
    its bucket's list, in one vectorised pass over all (point, primitive) pairs, and keeps per
    (point, owner) the nearest: the cost per point depends on what is near it, not on how many
    primitives there are.

    Args:
        reach: Distances up to this are exact; farther ones read ``±reach``.
        primitives: ``(a, b, radius, owner, kind, normal, pn_a, pn_b)``: segment ends (K, 2),
            radius (a disc: a = b), owner (K,), kind (:data:`EDGE`, :data:`DISC`), each edge's
            outward normal and the pseudonormals at its two ends (zeros: no sides).
        interior: Given ``(origin, side, shape)`` of the buckets, rows ``(col, row, owner)`` of
            buckets wholly inside an owner, farther than ``reach`` from its boundary: points
            there read ``−reach`` for it.
        side: The buckets' side (default: set by ``reach``, as above). With ``reach`` 0, each
            bucket lists the primitives that pass through it (for queries that scan every bucket
            a region covers, :mod:`apf_physics.sim.swept`).
    """

    def __init__(self, reach: float, primitives: tuple, interior: Callable | None = None, nearest: bool = False,
                 side: float | None = None):
        a, b, radius, owner, kind, normal, pn_a, pn_b = primitives
        lo = np.minimum(a, b) - radius[:, None]
        hi = np.maximum(a, b) + radius[:, None]
        self.reach = reach
        self.origin = lo.min(axis=0) - reach
        extent = hi.max(axis=0) + reach - self.origin
        if side is None:
            side = self.bucket_side(reach)
        if np.prod(np.ceil(extent / side) + 1) > MAX_BUCKETS:
            side = min(reach / math.sqrt(2.0), float(np.sqrt(np.prod(extent) / MAX_BUCKETS)) * 1.01)
        self.side = side
        self.shape = np.maximum(np.ceil(extent / side).astype(np.intp), 1)     # (cols, rows)
        # (bucket, primitive) registrations, a chunk of primitives at a time (bounded memory)
        chunks = range(0, len(a), REGISTER_CHUNK)
        if nearest:   # one owner, least distances only: keep what may be nearest (as nearest_only does)
            least = np.full(int(self.shape[0] * self.shape[1]), np.inf)
            for first in chunks:
                bucket, prim, gap = self._register(a, b, radius, first)
                np.minimum.at(least, bucket, gap)
            parts = []
            for first in chunks:
                bucket, prim, gap = self._register(a, b, radius, first)
                keep = gap <= least[bucket] + side * math.sqrt(2.0)
                parts.append((bucket[keep], prim[keep]))
        else:
            parts = [self._register(a, b, radius, first)[:2] for first in chunks]
        bucket = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.intp)
        prim = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, np.intp)
        # markers: buckets wholly inside a polygon, farther than reach from its edges
        marks = interior(self.origin, side, self.shape) if interior is not None else np.zeros((0, 3), np.intp)
        if len(marks):
            first = len(a)
            a = np.vstack([a, np.zeros((len(marks), 2))])
            b = np.vstack([b, np.zeros((len(marks), 2))])
            radius = np.concatenate([radius, np.zeros(len(marks))])
            owner = np.concatenate([owner, marks[:, 2]])
            kind = np.concatenate([kind, np.full(len(marks), MARKER, np.int8)])
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
        self._pruned: SegmentIndex | None = self if nearest else None

    @staticmethod
    def bucket_side(reach: float) -> float:
        """The buckets' side for distances within ``reach``: small (fewer candidates per point), but at
        most ``reach / √2`` (so that ``interior`` can mark them)."""
        return min(reach / math.sqrt(2.0), max(0.5, reach / 6.0))

    @classmethod
    def registrations(cls, reach: float, segments: int, length: float) -> float:
        """About how many (bucket, primitive) registrations an index of ``segments`` segments of
        total ``length`` takes for ``reach``: each is listed in the buckets within ``reach`` of it
        (what building it costs, about 3 million a second)."""
        side = cls.bucket_side(reach)
        across = 2.0 * reach / side + 2.0
        return length / side * across + segments * across * across

    def _register(self, a: np.ndarray, b: np.ndarray, radius: np.ndarray,
                  first: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(bucket, primitive, gap)`` for primitives ``first`` to ``first + REGISTER_CHUNK``: each in every
        bucket whose centre is within reach plus half a bucket's diagonal of it (so every point of the
        bucket within reach of it is covered), with its distance from that centre."""
        side, reach = self.side, self.reach
        a, b, radius = a[first:first + REGISTER_CHUNK], b[first:first + REGISTER_CHUNK], radius[first:first + REGISTER_CHUNK]
        lo = np.minimum(a, b) - radius[:, None]
        hi = np.maximum(a, b) + radius[:, None]
        c0 = np.floor((lo - reach - self.origin) / side).astype(np.intp).clip(0, self.shape - 1)
        c1 = np.floor((hi + reach - self.origin) / side).astype(np.intp).clip(0, self.shape - 1)
        span = c1 - c0 + 1
        count = span[:, 0] * span[:, 1]
        prim = np.repeat(np.arange(len(a)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        bx = c0[prim, 0] + k % span[prim, 0]
        by = c0[prim, 1] + k // span[prim, 0]
        cx = self.origin[0] + (bx + 0.5) * side - a[prim, 0]
        cy = self.origin[1] + (by + 0.5) * side - a[prim, 1]
        dx, dy = b[prim, 0] - a[prim, 0], b[prim, 1] - a[prim, 1]
        t = np.clip((cx * dx + cy * dy) / np.maximum(dx * dx + dy * dy, 1e-300), 0.0, 1.0)
        gap = np.hypot(cx - t * dx, cy - t * dy) - radius[prim]
        near = gap <= reach + side * math.sqrt(2.0) / 2
        return (by * self.shape[0] + bx)[near], prim[near] + first, gap[near]

    @classmethod
    def of_segments(cls, a: np.ndarray, b: np.ndarray, reach: float) -> SegmentIndex:
        """Bare segments (one owner, no sides), for least distances only (:meth:`nearest_only`, built
        in one pass without the full lists): e.g. the boundary of a grid's occupied cells, whose
        inside the grid itself knows."""
        k = len(a)
        zeros = np.zeros((k, 2))
        return cls(reach, (a, b, np.zeros(k), np.zeros(k, np.intp), np.full(k, EDGE, np.int8), zeros, zeros, zeros),
                   nearest=True)

    def nearest_only(self) -> SegmentIndex:
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
        keep &= (self.kind[self.members] == MARKER) | (gap <= np.abs(d[group]) + h2)
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
            gap = np.where(self.kind[prim] == MARKER, self.reach, gap)
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
        edge = kind == EDGE
        signed = np.where(edge & (side < 0), -least, least)
        signed = np.where(edge & (least > self.reach), self.reach, signed)
        if self.has_markers:
            signed = np.where(kind == MARKER, -self.reach, signed)
        np.clip(signed, -self.reach, self.reach, out=signed)
        who, owner = who[best], owner[best]
        if not with_nearest:
            return who, owner, signed, None
        p = points[who]
        nearest = p - np.column_stack([ex, ey])
        r = self.radius[e]
        circle = (kind == DISC) & (r > 0)
        if circle.any():
            norm = np.hypot(ex[circle], ey[circle])
            unit = np.where(norm[:, None] > 0, np.column_stack([ex[circle], ey[circle]]) / np.where(norm > 0, norm, 1.0)[:, None],
                            [1.0, 0.0])
            nearest[circle] = nearest[circle] + unit * r[circle, None]
        if self.has_markers:
            nearest = np.where((kind == MARKER)[:, None], p, nearest)
        return who, owner, signed, nearest
