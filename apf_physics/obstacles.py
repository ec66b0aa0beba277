"""Obstacle types: the shapes that the world, the field and the physics all share.

Both are stored in world coordinates. A polygon is simple (its edges do not cross),
counter-clockwise, concave allowed; a circle of radius 0 is the thesis's point obstacle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Union

import numpy as np

from apf_physics import geometry


@dataclass(frozen=True, eq=False)
class PolygonObstacle:
    """A simple polygon, stored counter-clockwise; concave allowed."""

    vertices: np.ndarray  # (M, 2)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the bounding box."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

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
        return {"polygon": self.vertices.tolist()}


@dataclass(frozen=True, eq=False)
class CircleObstacle:
    """A disc; radius 0 is the thesis's point obstacle."""

    center: np.ndarray  # (2,)
    radius: float

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower-left and upper-right corners of the bounding box."""
        return self.center - self.radius, self.center + self.radius

    def signed_distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance of ``(N, 2)`` points to the rim (negative inside) and the nearest rim point."""
        return geometry.circle_signed_distance(points, self.center, self.radius)

    @property
    def thickness(self) -> float:
        """Its diameter."""
        return 2.0 * self.radius

    def to_dict(self) -> dict[str, Any]:
        return {"circle": {"center": self.center.tolist(), "radius": self.radius}}


Obstacle = Union[PolygonObstacle, CircleObstacle]
