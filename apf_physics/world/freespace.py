"""A world's free space: where a robot fits, rasters of clearance, and random free positions.

:class:`FreeSpace` is a part of :class:`~apf_physics.world.core.World` (its base): the queries built
on the world's clearance (:meth:`World.clearance`, :meth:`World.static_clearance`) and cached with
it (:meth:`World.cached`), kept apart so that the World's own class says what a world is.
"""

from __future__ import annotations

import numpy as np

from apf_physics.errors import WorldError
from apf_physics.world import field as apf

RASTER_CHUNK = 1 << 16
"""Raster nodes computed at a time (bounds the temporaries of a large map)."""


class FreeSpace:
    """Free-space queries of a world (mixed into :class:`~apf_physics.world.core.World`)."""

    def clearance_raster(self, resolution: int = 8, cap: float = 4.0, margin: float = 2.0) -> apf.Raster:
        """``min(clearance, cap)`` from the static obstacles, at the nodes of a grid over the map and ``margin`` beyond; cached.

        Capped clearance is still 1-Lipschitz (``cap`` must not exceed :attr:`reach`). A bilinear
        sample is within ``0.71 / resolution`` of the true capped clearance (the largest
        weighted distance to a cell's corners, at its centre). Beyond the map's edge the
        clearance is negative.
        """
        def build() -> apf.Raster:
            grid = apf.Grid.covering((-margin, -margin), (self.size[0] + margin, self.size[1] + margin), resolution)
            values = grid.map_nodes(lambda nodes: np.minimum(self.static_clearance(nodes), cap), RASTER_CHUNK)
            return apf.Raster(grid, values)
        return self.cached(("clearance_raster", int(resolution), float(cap), float(margin)), build, static=True)

    def node_clearance(self, resolution: int) -> np.ndarray:
        """Static clearance at the nodes of the grid over the map at ``resolution`` nodes per unit
        (``Grid.covering((0, 0), size, resolution)``), computed in chunks; shared by every target."""
        def build() -> np.ndarray:
            grid = apf.Grid.covering((0.0, 0.0), self.size, resolution)
            return grid.map_nodes(self.static_clearance, RASTER_CHUNK)
        return self.cached(("node_clearance", int(resolution)), build, static=True)

    @property
    def thinnest_obstacle(self) -> float:
        """Least thickness of any obstacle (a point obstacle: 0); +inf without obstacles."""
        return self.cached("thinnest", lambda: min((o.thickness for o in self.obstacles), default=np.inf))

    def is_free(self, points: np.ndarray, margin: float | None = None) -> np.ndarray:
        """True where a robot centred at the point keeps ``margin`` (default: its radius) from everything."""
        margin = self.robot_radius if margin is None else margin
        return self.clearance(points) >= margin

    def free_cells(self, margin: float | None = None, resolution: int = 4) -> np.ndarray:
        """Centres of the grid cells (side ``1/resolution``) in which every point is free.

        A cell qualifies when its centre's clearance exceeds ``margin`` plus half the cell's
        diagonal (clearance changes no faster than distance). Built once and cached.
        """
        margin = self.robot_radius if margin is None else margin

        def build() -> np.ndarray:
            h = 1.0 / resolution
            xs = np.arange(h / 2, self.size[0], h)
            ys = np.arange(h / 2, self.size[1], h)
            centres = np.column_stack([a.ravel() for a in np.meshgrid(xs, ys)])
            return centres[self.clearance(centres) > margin + h / np.sqrt(2)]
        return self.cached(("free_cells", float(margin), int(resolution)), build, static=True)

    def start_cells(self) -> np.ndarray:
        """The :meth:`free_cells` (resolution 4) in which every point is farther than the goal tolerance from every target."""
        def build() -> np.ndarray:
            cells = self.free_cells()
            return cells[self.distance_to_target(cells) > self.goal_tolerance + 0.125 * np.sqrt(2)]
        return self.cached("start_cells", build)

    def random_free_positions(self, rng: np.random.Generator, count: int, margin: float | None = None,
                              away_from_targets: bool = False) -> np.ndarray:
        """``count`` positions where a robot fits, drawn uniformly over the free cells of :meth:`free_cells`.

        Args:
            rng: The random generator.
            count: How many.
            margin: Clearance to keep (default: the robot's radius).
            away_from_targets: Only positions farther than the goal tolerance from every target
                (:meth:`start_cells`; ``margin`` must be None).

        Raises:
            WorldError: No free position exists.
        """
        cells = self.start_cells() if away_from_targets else self.free_cells(margin)
        if not len(cells):
            raise WorldError(f"{self.label}: no free position for a robot of radius "
                             f"{self.robot_radius * self.frame.unit:g}{' ' + self.frame.name if self.frame.name else ''}")
        half = 0.5 / 4
        return cells[rng.integers(len(cells), size=count)] + rng.uniform(-half, half, size=(count, 2))
