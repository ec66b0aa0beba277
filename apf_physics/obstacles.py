"""Obstacle types: the shapes that the world, the field and the physics all share.

Both are stored in world coordinates. A polygon is simple (its edges do not cross),
counter-clockwise, concave allowed; a circle of radius 0 is the thesis's point obstacle.

Any obstacle may move: a :class:`Motion` translates it along a route, as a pure function of
the control step ``t`` (no rotation). The shape as stored is where it is at route offset
``[0, 0]``; :meth:`PolygonObstacle.at` gives the shape at a step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

from apf_physics import geometry


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

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the bounding box (where it is written)."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def moved(self, offset: np.ndarray) -> "PolygonObstacle":
        """The same shape translated by ``offset``, without motion."""
        return PolygonObstacle(self.vertices + np.asarray(offset, float))

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
        if self.motion is not None:
            data["motion"] = self.motion.to_dict()
        return data


@dataclass(frozen=True, eq=False)
class CircleObstacle:
    """A disc; radius 0 is the thesis's point obstacle."""

    center: np.ndarray  # (2,)
    radius: float
    motion: Motion | None = None

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the bounding box (where it is written)."""
        return self.center - self.radius, self.center + self.radius

    def moved(self, offset: np.ndarray) -> "CircleObstacle":
        """The same disc translated by ``offset``, without motion."""
        return CircleObstacle(self.center + np.asarray(offset, float), self.radius)

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance of ``(N, 2)`` points to the rim (negative inside) and the nearest rim point."""
        return geometry.circle_signed_distance(points, self.center, self.radius)

    @property
    def thickness(self) -> float:
        """Its diameter."""
        return 2.0 * self.radius

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {"circle": {"center": self.center.tolist(), "radius": self.radius}}
        if self.motion is not None:
            data["motion"] = self.motion.to_dict()
        return data


Obstacle = Union[PolygonObstacle, CircleObstacle]


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
