"""The artificial potential field of Model §1, over arrays of points, and its cached raster.

One small function per term, each over ``(N, 2)`` arrays of points:

- :func:`attractive` ``U_att = katt/2 · d_T²`` summed over targets,
- :func:`repulsive` ``U_rep = krep/2 · (1/d_O − 1/p0)²`` for ``d_O ≤ p0``, one capped term per obstacle,
- :func:`black_hole` ``U_bh = −kstr/2 · (ps − d_T)²`` for ``d_T ≤ ps``, one per target,

and their gradients. ``d_O`` is the distance from the point (the robot's centre) to the
obstacle's boundary (a circle: to its rim; radius 0: to its centre). The robot has a size:
where a robot of radius ``surface`` (which the world passes; 0: the thesis's point robot)
centred at the point would touch or overlap the obstacle (``d_O ≤ surface``), the repulsive
term equals the cap ``u_max`` and contributes no gradient, as inside the obstacle
(:func:`contact_distance`).

The map's edge is not part of U: it is a hard limit that only the physics (walls) and the
observation (points outside read as impassable) see. ``potential()`` outside the map is the
same formula continued.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

from apf_physics.common.compiled import kernel
from apf_physics.world.obstacles import Obstacle
from apf_physics.world.spatial import ShapeSet

FIELD_PRESETS: dict[str, dict[str, float]] = {
    # Model §1, thesis Tables 2–4. u_max is the cap used in place of infinity (thesis Fig. 11).
    "thesis-demo": {"katt": 1, "krep": 20, "kstr": 8, "p0": 3, "ps": 8, "u_max": 100},
    "thesis-fixed": {"katt": 2, "krep": 20, "kstr": 8, "p0": 0.5, "ps": 8, "u_max": 100},
    "thesis-general": {"katt": 1, "krep": 20, "kstr": 8, "p0": 3, "ps": 8, "u_max": 100},
}
"""The thesis's parameter sets by name."""


@dataclass(frozen=True)
class FieldParams:
    """Parameters of the artificial potential field (Model §1)."""

    katt: float   # attraction gain
    krep: float   # repulsion gain
    kstr: float   # black-hole strength
    p0: float     # repulsion range [world units]
    ps: float     # black-hole range [world units]
    u_max: float  # cap of each repulsive term, also its value inside an obstacle

    @classmethod
    def preset(cls, name: str) -> "FieldParams":
        """One of :data:`FIELD_PRESETS` by name."""
        return cls(**{k: float(v) for k, v in FIELD_PRESETS[name].items()})

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def equals_preset(self, name: str) -> bool:
        """Whether these parameters are exactly those of preset ``name``."""
        return self.as_dict() == {k: float(v) for k, v in FIELD_PRESETS[name].items()}


def _target_offsets(points: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    diff = points[:, None, :] - targets[None, :, :]        # (N, T, 2)
    return diff, np.sqrt(np.einsum("ntj,ntj->nt", diff, diff))


def _target_distances(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(N, T) distances, column by column (cheaper than a 3-D difference array)."""
    x, y = points[:, 0], points[:, 1]
    return np.column_stack([np.hypot(x - tx, y - ty) for tx, ty in targets])


def attractive(points: np.ndarray, targets: np.ndarray, katt: float) -> np.ndarray:
    """``Σ_T katt/2 · d_T²`` (Model eq. 1–3)."""
    _, d = _target_offsets(points, targets)
    return 0.5 * katt * np.sum(d * d, axis=1)


def attractive_gradient(points: np.ndarray, targets: np.ndarray, katt: float) -> np.ndarray:
    """``∇U_att = katt · Σ_T (P − T)``."""
    diff, _ = _target_offsets(points, targets)
    return katt * diff.sum(axis=1)


def black_hole(points: np.ndarray, targets: np.ndarray, kstr: float, ps: float) -> np.ndarray:
    """``Σ_T −kstr/2 · (ps − d_T)²`` where ``d_T ≤ ps`` (Model eq. 8–10)."""
    _, d = _target_offsets(points, targets)
    well = np.clip(ps - d, 0.0, None)
    return -0.5 * kstr * np.sum(well * well, axis=1)


def black_hole_gradient(points: np.ndarray, targets: np.ndarray, kstr: float, ps: float) -> np.ndarray:
    """``∇U_bh = Σ_T kstr · (ps − d_T) · (P − T)/d_T`` where ``d_T ≤ ps`` (0 at the target itself)."""
    diff, d = _target_offsets(points, targets)
    well = np.clip(ps - d, 0.0, None)
    scale = np.where(d > 0, kstr * well / np.where(d > 0, d, 1.0), 0.0)
    return np.einsum("nt,ntj->nj", scale, diff)


@kernel
def repulsive_term_at(d, krep, p0, u_max):
    """One obstacle's term at signed distance ``d`` (Model eq. 4–7): the cap ``u_max`` for ``d ≤ 0``,
    ``min(krep/2 · (1/d − 1/p0)², u_max)`` for ``0 < d ≤ p0``, 0 beyond.

    The one definition of the term: :func:`repulsive_term` applies it over arrays, and the
    observations' compiled loops call it point by point.
    """
    if d <= 0.0:
        return u_max
    if d <= p0:
        return min(0.5 * krep * (1.0 / d - 1.0 / p0) ** 2, u_max)
    return 0.0


@kernel
def _repulsive_terms(d, krep, p0, u_max, out):
    for i in range(d.shape[0]):
        out[i] = repulsive_term_at(d[i], krep, p0, u_max)


def repulsive_term(d: np.ndarray, krep: float, p0: float, u_max: float) -> np.ndarray:
    """:func:`repulsive_term_at` of every element of ``d``."""
    d = np.asarray(d, dtype=float)
    out = np.empty(d.size)
    _repulsive_terms(np.ascontiguousarray(d).reshape(-1), float(krep), float(p0), float(u_max), out)
    return out.reshape(d.shape)


def repulsive_term_slope(d: np.ndarray, krep: float, p0: float, u_max: float) -> np.ndarray:
    """``dU_rep/dd`` of one obstacle's term: ``−krep (1/d − 1/p0)/d²`` where uncapped, else 0."""
    u = repulsive_term(d, krep, p0, u_max)
    live = (d > 0) & (d <= p0) & (u < u_max)
    safe = np.where(live, d, 1.0)
    return np.where(live, -krep * (1.0 / safe - 1.0 / p0) / (safe * safe), 0.0)


def contact_distance(d: np.ndarray, surface: float) -> np.ndarray:
    """``d`` where the robot (a disc of radius ``surface`` centred at the point) is clear of the
    obstacle, 0 where it touches or overlaps it: there the repulsive term is the cap."""
    return np.where(d <= surface, 0.0, d)


def _shape_set(obstacles: Sequence[Obstacle] | ShapeSet, params: FieldParams, surface: float = 0.0) -> ShapeSet:
    """``obstacles`` ready for queries out to ``max(p0, surface)`` (a world passes its own, built once)."""
    reach = max(params.p0, surface)
    if isinstance(obstacles, ShapeSet):
        if obstacles.reach < reach:
            raise ValueError(f"a shape set of reach {obstacles.reach:g} cannot give a field of range p0 = {params.p0:g} "
                             f"for a robot of radius {surface:g}")
        return obstacles
    return ShapeSet(obstacles, reach)


def repulsive(points: np.ndarray, obstacles: Sequence[Obstacle] | ShapeSet, params: FieldParams,
              surface: float = 0.0) -> np.ndarray:
    """``Σ_O U_rep,O`` (Model eq. 4–7), each term capped at ``u_max``, and at the cap where a robot
    of radius ``surface`` at the point touches the obstacle.

    Only the (point, obstacle) pairs within ``max(p0, surface)`` are measured (:class:`~apf_physics.world.spatial.ShapeSet`):
    beyond, the term is 0, so the cost does not grow with the number of obstacles.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    who, _, d, _ = _shape_set(obstacles, params, surface).pairs(points, with_nearest=False)
    return np.bincount(who, weights=repulsive_term(contact_distance(d, surface), params.krep, params.p0, params.u_max),
                       minlength=len(points))


def repulsive_gradient(points: np.ndarray, obstacles: Sequence[Obstacle] | ShapeSet, params: FieldParams,
                       surface: float = 0.0) -> np.ndarray:
    """``Σ_O dU_rep/dd · ∇d``, with ``∇d = (P − Q)/d`` for the nearest boundary point Q (0 where a
    robot of radius ``surface`` touches the obstacle: the term is at its cap)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    who, _, d, nearest = _shape_set(obstacles, params, surface).pairs(points)
    slope = repulsive_term_slope(contact_distance(d, surface), params.krep, params.p0, params.u_max)
    safe = np.where(d > 0, d, 1.0)
    pull = (slope / safe)[:, None] * (points[who] - nearest)
    return np.column_stack([np.bincount(who, weights=pull[:, 0], minlength=len(points)),
                            np.bincount(who, weights=pull[:, 1], minlength=len(points))])


def discs_repulsive(points: np.ndarray, centres: np.ndarray, radius: float, params: FieldParams) -> np.ndarray:
    """``Σ_D U_rep,D`` of discs of one radius at ``centres`` (K, 2) (other robots): all at once."""
    d = np.hypot(points[:, None, 0] - centres[None, :, 0], points[:, None, 1] - centres[None, :, 1]) - radius
    return repulsive_term(d, params.krep, params.p0, params.u_max).sum(axis=1)


def discs_repulsive_gradient(points: np.ndarray, centres: np.ndarray, radius: float, params: FieldParams) -> np.ndarray:
    """``∇`` of :func:`discs_repulsive`."""
    diff = points[:, None, :] - centres[None, :, :]                     # (N, K, 2)
    r = np.hypot(diff[..., 0], diff[..., 1])
    slope = repulsive_term_slope(r - radius, params.krep, params.p0, params.u_max)
    return np.einsum("nk,nkj->nj", np.where(r > 0, slope / np.where(r > 0, r, 1.0), 0.0), diff)


def potential(points: np.ndarray, targets: np.ndarray, obstacles: Sequence[Obstacle] | ShapeSet,
              params: FieldParams, surface: float = 0.0) -> np.ndarray:
    """Total ``U = U_att + U_rep + U_bh`` (Model eq. 11) at each point, for a robot of radius ``surface``."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    d = _target_distances(points, targets)
    well = np.clip(params.ps - d, 0.0, None)
    # U_att + U_bh from the same distances (see attractive() and black_hole())
    u = 0.5 * params.katt * np.sum(d * d, axis=1) - 0.5 * params.kstr * np.sum(well * well, axis=1)
    return u + repulsive(points, obstacles, params, surface)


def gradient(points: np.ndarray, targets: np.ndarray, obstacles: Sequence[Obstacle] | ShapeSet,
             params: FieldParams, surface: float = 0.0) -> np.ndarray:
    """``∇U`` at each point; the force is ``F = −∇U`` (Model eq. 12), for a robot of radius ``surface``."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    return (attractive_gradient(points, targets, params.katt)
            + repulsive_gradient(points, obstacles, params, surface)
            + black_hole_gradient(points, targets, params.kstr, params.ps))


@dataclass(frozen=True)
class Grid:
    """World ↔ grid conversion for a regular lattice of nodes.

    Node ``[row, col]`` sits at ``(x0 + col/resolution, y0 + row/resolution)``: row 0 is the
    lowest y (flip it for an image).

    Attributes:
        origin: World coordinates ``(x0, y0)`` of node ``[0, 0]``.
        resolution: Nodes per world unit.
        shape: ``(rows, cols)``.
    """

    origin: tuple[float, float]
    resolution: int
    shape: tuple[int, int]

    @classmethod
    def covering(cls, lower: Sequence[float], upper: Sequence[float], resolution: int) -> Grid:
        """The grid whose nodes span ``[lower, upper]`` at ``resolution`` nodes per unit."""
        cols = int(round((upper[0] - lower[0]) * resolution)) + 1
        rows = int(round((upper[1] - lower[1]) * resolution)) + 1
        return cls((float(lower[0]), float(lower[1])), int(resolution), (rows, cols))

    def to_index(self, points: np.ndarray) -> np.ndarray:
        """Continuous ``(col, row)`` index of each world point."""
        return (np.asarray(points, dtype=float) - np.asarray(self.origin)) * self.resolution

    def to_world(self, index: np.ndarray) -> np.ndarray:
        """World point of each continuous ``(col, row)`` index."""
        return np.asarray(index, dtype=float) / self.resolution + np.asarray(self.origin)

    def map_nodes(self, function, chunk: int) -> np.ndarray:
        """``function(points)`` at every node, ``chunk`` nodes at a time, as a ``(rows, cols)`` array."""
        rows, cols = self.shape
        out = np.empty(rows * cols)
        xs = self.origin[0] + np.arange(cols) / self.resolution
        step = max(1, chunk // max(cols, 1))
        for r0 in range(0, rows, step):
            ys = self.origin[1] + np.arange(r0, min(rows, r0 + step)) / self.resolution
            gx, gy = np.meshgrid(xs, ys)
            out[r0 * cols:r0 * cols + gx.size] = function(np.column_stack([gx.ravel(), gy.ravel()]))
        return out.reshape(rows, cols)

    def node_points(self) -> np.ndarray:
        """All node coordinates, row-major, ``(rows*cols, 2)``."""
        rows, cols = self.shape
        xs = self.origin[0] + np.arange(cols) / self.resolution
        ys = self.origin[1] + np.arange(rows) / self.resolution
        gx, gy = np.meshgrid(xs, ys)
        return np.column_stack([gx.ravel(), gy.ravel()])


@dataclass(frozen=True, eq=False)
class Raster:
    """Values at the nodes of a :class:`Grid`, sampled bilinearly anywhere inside it.

    Attributes:
        grid: Where the nodes are.
        values: ``(rows, cols)`` float64 values at the nodes.
    """

    grid: Grid
    values: np.ndarray

    def sample(self, points: np.ndarray) -> np.ndarray:
        """Bilinear interpolation at ``(N, 2)`` points; points outside are clamped to the edge."""
        rows, cols = self.grid.shape
        idx = self.grid.to_index(np.asarray(points, dtype=float).reshape(-1, 2))
        cx = np.clip(idx[:, 0], 0.0, cols - 1.0)
        cy = np.clip(idx[:, 1], 0.0, rows - 1.0)
        c0 = np.minimum(np.floor(cx).astype(np.intp), cols - 2)
        r0 = np.minimum(np.floor(cy).astype(np.intp), rows - 2)
        fx, fy = cx - c0, cy - r0
        v = self.values
        return ((1 - fy) * ((1 - fx) * v[r0, c0] + fx * v[r0, c0 + 1])
                + fy * ((1 - fx) * v[r0 + 1, c0] + fx * v[r0 + 1, c0 + 1]))


SAMPLE_ROW = 512
"""Points per row of the map :meth:`Atlas.sample` hands ``cv2.remap``: a column of N points (one
per row) cost OpenCV 3–4 times as much as rows of 512 (its work is split by rows, and a row of
one point is mostly overhead), and a map may not have 32,767 rows."""

class Atlas:
    """Several rasters of one resolution packed into one float32 image, sampled in one call.

    Sampling thousands of points spread over several worlds' rasters is one
    ``cv2.remap`` (bilinear, float weights from OpenCV 5 on): the environments sample every
    robot's observation window this way, and the physics its clearance. Points must lie
    within their own raster (callers pad their rasters to cover every point they ask
    for): unlike :meth:`Raster.sample`, nothing is clamped, which would cost more than the
    lookup itself.

    Args:
        resolution: Nodes per world unit of every raster added.
    """

    def __init__(self, resolution: int):
        self.resolution = int(resolution)
        self.rasters: list[Raster] = []
        self._image: np.ndarray | None = None
        self._offsets: np.ndarray | None = None   # the last offsets sampled with, and them scaled
        self._scaled: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, raster: Raster) -> int:
        """Add a raster (its grid must have this atlas's resolution) and return its index."""
        if raster.grid.resolution != self.resolution:
            raise ValueError(f"raster resolution {raster.grid.resolution} in an atlas of resolution {self.resolution}")
        self.rasters.append(raster)
        self._image = None
        return len(self.rasters) - 1

    def _build(self) -> None:
        """Lay the rasters out in blocks on a square-ish grid of one float32 image."""
        rows = max(r.grid.shape[0] for r in self.rasters) + 1   # one spare row and column between blocks
        cols = max(r.grid.shape[1] for r in self.rasters) + 1
        per_row = math.ceil(math.sqrt(len(self.rasters)))
        n_rows = math.ceil(len(self.rasters) / per_row)
        image = np.zeros((n_rows * rows, per_row * cols), np.float32)
        corner = np.zeros((len(self.rasters), 2))                # image (col, row) of each raster's node [0, 0]
        for i, raster in enumerate(self.rasters):
            r0, c0 = (i // per_row) * rows, (i % per_row) * cols
            h, w = raster.grid.shape
            image[r0:r0 + h, c0:c0 + w] = raster.values
            corner[i] = (c0, r0)
        self._image = image
        origin = np.array([r.grid.origin for r in self.rasters], float)
        self._shift = corner - origin * self.resolution          # image index = world point · resolution + shift

    def sample(self, points: np.ndarray, ids: np.ndarray | int, offsets: np.ndarray | None = None) -> np.ndarray:
        """Bilinear values at points of the rasters ``ids``.

        Args:
            points: (N, 2) world points; point ``n`` is in raster ``ids[n]`` (or all in raster ``ids``).
            ids: (N,) raster indices, or one index for all.
            offsets: (Q, 2) world offsets (an array not changed afterwards: its scaled copy is kept);
                when given, each point stands for the Q points
                ``points[n] + offsets[q]`` (e.g. an observation window around a robot).

        Returns:
            (N,) float32 values, or (N, Q) with ``offsets``.
        """
        import cv2

        if self._image is None:
            self._build()
            self._shift_floats = self._shift.tolist()   # the shifts as Python floats (one window)
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if offsets is not None and len(points) == 1:
            # one window (a single robot): its corner in Python floats, then the same float32 maps
            # as below (a fixed cost of five small array operations less)
            (x, y), = points.tolist()
            sx, sy = self._shift_floats[ids.item(0) if isinstance(ids, np.ndarray) else int(ids)]
            scaled = self._scaled_offsets(offsets)
            map_x = scaled[0] + np.float32(x * self.resolution + sx)
            map_y = scaled[1] + np.float32(y * self.resolution + sy)
            return cv2.remap(self._image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # image coordinates, in float32 (what remap takes)
        index = (points * self.resolution + self._shift[ids]).astype(np.float32)
        if not len(index):  # no points (e.g. a batch step where every slot is restarting): remap refuses empty maps
            return np.zeros(0 if offsets is None else (0, len(offsets)), np.float32)
        if offsets is None:   # one two-channel map, in rows of up to SAMPLE_ROW points
            n = len(index)
            width = min(n, SAMPLE_ROW)
            rows = -(-n // width)
            if rows * width != n:
                index = np.concatenate([index, np.zeros((rows * width - n, 2), np.float32)])
            return cv2.remap(self._image, index.reshape(rows, width, 2), None, cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE).reshape(-1)[:n]
        # x and y maps apart: broadcasting over a last axis of 2 is several times slower
        scaled = self._scaled_offsets(offsets)
        map_x = index[:, 0:1] + scaled[0]
        map_y = index[:, 1:2] + scaled[1]
        return cv2.remap(self._image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _scaled_offsets(self, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``offsets`` in image units as float32 rows of x and of y (the last array's kept)."""
        if self._offsets is not offsets:
            scaled = (np.asarray(offsets, float).reshape(-1, 2) * self.resolution).astype(np.float32)
            self._offsets, self._scaled = offsets, (scaled[None, :, 0].copy(), scaled[None, :, 1].copy())
        return self._scaled
