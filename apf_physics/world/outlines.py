"""A world's obstacles as arrays of segments and discs, built once per world.

The range sensor casts its beams against them (:mod:`apf_physics.sensing.lidar`) and the physics
indexes them for its exact swept distances (:mod:`apf_physics.sim.swept`): one outline of the
world, whoever asks.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from apf_physics.common import geometry
from apf_physics.world.core import World
from apf_physics.world.obstacles import CircleObstacle, GridObstacle, PolygonObstacle


class StaticGeometry(NamedTuple):
    """A world's static geometry as arrays: segments ``a → a + e`` and discs."""

    a: np.ndarray          # (S, 2)
    e: np.ndarray          # (S, 2)
    side: np.ndarray       # (S,) +1 a polygon's edge, 0 a grid's boundary run (the cast directs them: _outlines)
    lo: np.ndarray         # (S, 2) bounding boxes
    hi: np.ndarray
    centre: np.ndarray     # (C, 2)
    radius: np.ndarray     # (C,)


class MovingGeometry(NamedTuple):
    """A world's moving obstacles where they are written (route offset 0), as arrays."""

    a: np.ndarray          # (Sm, 2) polygon edges
    e: np.ndarray
    seg_owner: np.ndarray  # (Sm,) index in World.moving
    centre: np.ndarray     # (Cm, 2)
    radius: np.ndarray     # (Cm,)
    disc_owner: np.ndarray  # (Cm,)


def polygon_edges(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return vertices, np.roll(vertices, -1, axis=0) - vertices


def static_geometry(world: World) -> StaticGeometry:
    """The world's static obstacles as segments and discs (built once per world; the map's edge is cast on its own)."""
    def build() -> StaticGeometry:
        a_list, e_list, sides = [np.zeros((0, 2))], [np.zeros((0, 2))], [np.zeros(0)]
        centres, radii = [], []
        for obstacle in world.static_obstacles:
            if isinstance(obstacle, PolygonObstacle):
                a, e = polygon_edges(obstacle.vertices)
                a_list.append(a)
                e_list.append(e)
                sides.append(np.ones(len(a)))
            elif isinstance(obstacle, CircleObstacle):
                centres.append(obstacle.center)
                radii.append(obstacle.radius)
            elif isinstance(obstacle, GridObstacle):
                ga, gb = geometry.grid_boundary(obstacle.occupied)
                origin = np.asarray(obstacle.origin, float)
                a_list.append(ga * obstacle.cell + origin)
                e_list.append((gb - ga) * obstacle.cell)
                sides.append(np.zeros(len(ga)))
        a, e = np.vstack(a_list).astype(float), np.vstack(e_list).astype(float)
        return StaticGeometry(a, e, np.concatenate(sides).astype(float), np.minimum(a, a + e), np.maximum(a, a + e),
                       np.asarray(centres, float).reshape(-1, 2), np.asarray(radii, float))
    return world.cached("static_geometry", build, static=True)


def moving_geometry(world: World) -> MovingGeometry:
    """The world's moving obstacles at route offset 0 as segments and discs (built once per world)."""
    def build() -> MovingGeometry:
        a_list, e_list, seg_owner, centres, radii, disc_owner = [], [], [], [], [], []
        for k, i in enumerate(world.moving):
            obstacle = world.obstacles[i]
            if isinstance(obstacle, PolygonObstacle):
                a, e = polygon_edges(obstacle.vertices)
                a_list.append(a)
                e_list.append(e)
                seg_owner.extend([k] * len(a))
            else:
                centres.append(obstacle.center)
                radii.append(obstacle.radius)
                disc_owner.append(k)
        return MovingGeometry(np.vstack(a_list) if a_list else np.zeros((0, 2)),
                       np.vstack(e_list) if e_list else np.zeros((0, 2)),
                       np.asarray(seg_owner, np.intp), np.asarray(centres, float).reshape(-1, 2),
                       np.asarray(radii, float), np.asarray(disc_owner, np.intp))
    return world.cached("moving_geometry", build)
