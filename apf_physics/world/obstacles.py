"""Obstacle types: the shapes that the world, the field and the physics all share.

All are stored in world coordinates. A polygon is simple (its edges do not cross),
counter-clockwise, concave allowed; a circle of radius 0 is the thesis's point obstacle; a
grid is the occupied cells of an occupancy map (a ROS map or a MovingAI map), one obstacle.

Any polygon or circle may move: a :class:`Motion` translates it along a route, as a pure function of
the control step ``t`` (no rotation). The shape as stored is where it is at route offset
``[0, 0]``; :meth:`PolygonObstacle.at` gives the shape at a step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

from apf_physics.common import geometry
from apf_physics.world.buckets import SegmentIndex


@dataclass(frozen=True, eq=False)
class Motion:
    """A route an obstacle translates along, at constant speed (the world-file contract's ``motion``).

    Attributes:
        path: ``(K, 2)`` offsets from the obstacle as written: the route is the polyline
            ``[0, 0] → path[0] → path[1] → …``.
        speed: Distance along the route per control step (``0 < speed ≤ 1``).
        loop: False: at the end of the route, back the same way (ping-pong); True: straight
            back to ``[0, 0]`` and round again.
        phase: Distance along the route at step 0.
    """

    path: np.ndarray
    speed: float
    loop: bool = False
    phase: float = 0.0
    _route: np.ndarray = field(init=False, repr=False)
    _arc: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        route = np.vstack([np.zeros((1, 2)), np.asarray(self.path, float).reshape(-1, 2)])
        if self.loop:
            route = np.vstack([route, np.zeros((1, 2))])
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(route, axis=0).T))])
        object.__setattr__(self, "_route", route)
        object.__setattr__(self, "_arc", arc)

    @property
    def length(self) -> float:
        """Length of the route as travelled one way (for a loop: the whole closed round)."""
        return float(self._arc[-1])

    @property
    def period(self) -> float:
        """Distance travelled before the motion repeats."""
        return self.length if self.loop else 2.0 * self.length

    def offset(self, t: np.ndarray | float) -> np.ndarray:
        """Offset(s) from the obstacle as written at control step(s) ``t`` (fractional steps allowed).

        Returns:
            ``(..., 2)`` for ``t`` of shape ``(...)``.
        """
        t = np.asarray(t, dtype=float)
        if self.period <= 0:
            return np.zeros(t.shape + (2,))
        s = np.mod(self.phase + self.speed * t, self.period)
        if not self.loop:
            s = np.where(s > self.length, self.period - s, s)
        k = np.clip(np.searchsorted(self._arc, s, side="right") - 1, 0, len(self._arc) - 2)
        span = self._arc[k + 1] - self._arc[k]
        f = np.where(span > 0, (s - self._arc[k]) / np.where(span > 0, span, 1.0), 0.0)
        return self._route[k] + f[..., None] * (self._route[k + 1] - self._route[k])

    @property
    def reach(self) -> tuple[np.ndarray, np.ndarray]:
        """Lowest and highest offset anywhere on the route (the route is a polyline: its vertices bound it)."""
        return self._route.min(axis=0), self._route.max(axis=0)

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"path": np.asarray(self.path).tolist(), "speed": self.speed}
        if self.loop:
            data["loop"] = True
        if self.phase:
            data["phase"] = self.phase
        return data


@dataclass(frozen=True, eq=False)
class PolygonObstacle:
    """A simple polygon, stored counter-clockwise; concave allowed."""

    vertices: np.ndarray  # (M, 2)
    motion: Motion | None = None
    name: str | None = None
    """The world file's optional ``name:`` (error messages and figures use it)."""

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the bounding box (where it is written)."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def moved(self, offset: np.ndarray) -> "PolygonObstacle":
        """The same shape translated by ``offset``, without motion."""
        return PolygonObstacle(self.vertices + np.asarray(offset, float), name=self.name)

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance of ``(N, 2)`` points to the boundary (negative inside) and the nearest boundary point."""
        return geometry.polygon_signed_distance(points, self.vertices)

    def convex_pieces(self) -> list[np.ndarray]:
        """Convex pieces covering the polygon (itself when convex): what the physics is built from."""
        return geometry.triangulate(self.vertices)

    @property
    def thickness(self) -> float:
        """Least width of its convex pieces: how thin a wall of it can be."""
        return min(geometry.convex_width(piece) for piece in self.convex_pieces())

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"polygon": self.vertices.tolist()}
        if self.name is not None:
            data["name"] = self.name
        if self.motion is not None:
            data["motion"] = self.motion.to_dict()
        return data


@dataclass(frozen=True, eq=False)
class CircleObstacle:
    """A disc; radius 0 is the thesis's point obstacle."""

    center: np.ndarray  # (2,)
    radius: float
    motion: Motion | None = None
    name: str | None = None
    """The world file's optional ``name:`` (error messages and figures use it)."""

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the bounding box (where it is written)."""
        return self.center - self.radius, self.center + self.radius

    def moved(self, offset: np.ndarray) -> "CircleObstacle":
        """The same disc translated by ``offset``, without motion."""
        return CircleObstacle(self.center + np.asarray(offset, float), self.radius, name=self.name)

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance of ``(N, 2)`` points to the rim (negative inside) and the nearest rim point."""
        return geometry.circle_signed_distance(points, self.center, self.radius)

    @property
    def thickness(self) -> float:
        """Its diameter."""
        return 2.0 * self.radius

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"circle": {"center": self.center.tolist(), "radius": self.radius}}
        if self.name is not None:
            data["name"] = self.name
        if self.motion is not None:
            data["motion"] = self.motion.to_dict()
        return data


@dataclass(frozen=True, eq=False)
class GridObstacle:
    """The occupied cells of an occupancy grid, as **one** obstacle (docs/real-maps.md).

    Its distance ``d_O`` is the exact Euclidean distance to the union of the occupied cells
    (negative inside, to the nearest free cell), so a wall is one wall however it was cut.
    Cells outside the grid are free.

    Attributes:
        occupied: ``(rows, cols)`` bool; row 0 is the lowest y (unknown cells are occupied).
        cell: Side of a cell [world units].
        origin: World coordinates of the lower-left corner of cell ``[0, 0]``.
        spec: The world file's ``grid:`` mapping it was read from (written back by :meth:`to_dict`).
    """

    occupied: np.ndarray
    cell: float
    origin: tuple[float, float] = (0.0, 0.0)
    spec: dict = field(default_factory=dict, compare=False)
    motion: None = None
    _tables: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the grid."""
        rows, cols = self.occupied.shape
        lo = np.asarray(self.origin, float)
        return lo, lo + self.cell * np.array([cols, rows], float)

    @property
    def thickness(self) -> float:
        """One cell: the thinnest wall a grid can hold."""
        return float(self.cell)

    def rectangles(self) -> np.ndarray:
        """``(R, 4)`` world boxes ``[x0, y0, x1, y1]`` that tile the occupied cells exactly (cached)."""
        if "boxes" not in self._tables:
            cells = geometry.occupancy_rectangles(self.occupied).astype(float)
            self._tables["boxes"] = cells * self.cell + np.tile(np.asarray(self.origin, float), 2)
        return self._tables["boxes"]

    def _search_tables(self, inside: bool) -> tuple[np.ndarray, np.ndarray]:
        """For the grid padded by one free cell: the nearest column at or left of, and at or
        right of, each cell that is occupied (``inside`` False) or free (True), per row."""
        key = ("free" if inside else "occupied")
        if key not in self._tables:
            padded = np.pad(self.occupied, 1, constant_values=False)
            self._tables[key] = geometry.nearest_in_rows(~padded if inside else padded)
        return self._tables[key]

    def signed_distance(self, points: np.ndarray, reach: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance of ``(N, 2)`` points to the occupied cells (negative inside) and the nearest boundary point.

        Exact wherever ``|d| ≤ reach``; farther points get ``±reach`` (and themselves as the
        nearest point). Within a finite reach the boundary of the occupied cells, cut into
        maximal straight runs, is looked up in a bucket index (built once per reach); without
        one, rows are searched outward from each point's own. Either way the cost grows with
        what is near a point, not with the size of the grid.
        """
        points = np.asarray(points, float).reshape(-1, 2)
        u = (points - np.asarray(self.origin, float)) / self.cell           # cell units
        rows, cols = self.occupied.shape
        col = np.floor(u[:, 0]).astype(np.intp)
        row = np.floor(u[:, 1]).astype(np.intp)
        within = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
        inside = np.zeros(len(points), bool)
        inside[within] = self.occupied[row[within], col[within]]
        limit = reach / self.cell
        if np.isfinite(limit):
            distance, near = self._boundary_distance(u, limit)
        else:
            distance, near = np.empty(len(points)), np.empty((len(points), 2))
            for flag in (False, True):
                mine = np.flatnonzero(inside == flag)
                if len(mine):
                    left, right = self._search_tables(flag)
                    distance[mine], near[mine] = geometry.nearest_cell_distance(u[mine] + 1.0, left, right, limit)
                    near[mine] -= 1.0
        d = np.where(inside, -distance, distance) * self.cell
        return d, near * self.cell + np.asarray(self.origin, float)

    def _boundary_distance(self, u: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray]:
        """Distance (cell units) from points to the boundary of the occupied cells, up to ``limit``."""
        key = ("boundary", float(limit))
        if key not in self._tables:
            a, b = geometry.grid_boundary(self.occupied)
            self._tables[key] = SegmentIndex.of_segments(a, b, limit) if len(a) else None
        index = self._tables[key]
        distance, near = np.full(len(u), limit), u.copy()
        if index is not None:
            who, _, d, nearest = index.nearest_only().pairs(u)
            distance[who] = np.abs(d)
            near[who] = nearest
        return distance, near

    def to_dict(self) -> dict[str, Any]:
        return {"grid": dict(self.spec)}


Obstacle = Union[PolygonObstacle, CircleObstacle, GridObstacle]


def obstacle_at(obstacle: Obstacle, t: float) -> Obstacle:
    """The obstacle where it is at control step ``t`` (itself if it does not move)."""
    return obstacle if obstacle.motion is None else obstacle.moved(obstacle.motion.offset(t))


def swept_bounds(obstacle: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of everywhere the obstacle ever is."""
    lo, hi = obstacle.bounds
    if obstacle.motion is None:
        return lo, hi
    low, high = obstacle.motion.reach
    return lo + low, hi + high
