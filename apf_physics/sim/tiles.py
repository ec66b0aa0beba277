"""Tiles: each world's static geometry laid out side by side in the physics' one pymunk space.

A tile is a world's walls, solid slabs just outside its map, at an offset of its own
(:data:`TILE_GAP` apart), and its static obstacles, built piece by piece (a polygon or circle
whole, a grid's cells as boxes) in :data:`CHUNK` squares when a robot that needs physics first
comes near (:meth:`Tiles.build_near`): a large map costs pymunk only where its robots go.
Which slots share a tile is the physics' choice (:class:`~apf_physics.sim.physics.Physics`).

Each wall of a tile has a static body of its own, and the tile's static obstacles share one, all
labelled in the physics' :class:`~apf_physics.sim.contacts.BodyLabels`: an arbiter's body ids then
say what a robot touched (which of the obstacles: :data:`ANY_OBSTACLE`). One body for thousands of
obstacles, because pymunk's batched reads and writes visit every body of the space at every step.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from apf_physics.sim.contacts import OBSTACLE, WALL, BodyLabels, CollisionType
from apf_physics.world.obstacles import CircleObstacle, GridObstacle, PolygonObstacle
from apf_physics.world.core import World

WALL_THICKNESS = 1.0  # of the slabs around each map [units]
ANY_OBSTACLE = -1
"""The index in the label of a tile's obstacles' shared body: the obstacle touched is the one the
robot's disc is against, found by its world's geometry (:meth:`~apf_physics.sim.physics.Physics`)."""
TILE_GAP = 4.0  # free space between neighbouring tiles, beyond their walls [units]
CHUNK = 4.0
"""Least side of the squares [units] by which a world's static obstacles are built into pymunk as
robots come near (larger where a robot's box of one step would not fit in one)."""


class Tiles:
    """The tiles built in ``space``, their static bodies labelled in ``labels``.

    Attributes:
        index: The tile of each key (the physics' ``(id(world.obstacles), lane)``).
        offset: (T, 2) where each tile's map corner (0, 0) is in the space.
        pieces: Each tile's obstacles, built where robots come.
    """

    def __init__(self, space: pymunk.Space, labels: BodyLabels):
        self.space = space
        self.labels = labels
        self.index: dict[tuple[int, int], int] = {}
        self.offset = np.zeros((0, 2))
        self.pieces: list[TilePieces] = []
        self._next_x = 0.0

    def build(self, key: tuple[int, int], world: World, side: float) -> int:
        """Add ``world``'s walls as static shapes at a fresh offset, and its obstacles to be built
        where robots come (:meth:`build_near`) by squares of ``side`` (at least :data:`CHUNK`);
        returns the new tile's index, now ``index[key]``."""
        tile = len(self.offset)
        ox, oy = self._next_x + WALL_THICKNESS, 0.0
        w, h = world.size
        self._next_x += w + 2 * WALL_THICKNESS + TILE_GAP
        # Walls are solid slabs just outside the map (a zero-thickness segment could be crossed
        # by a robot squeezed against it): bottom, right, top, left.
        t = WALL_THICKNESS
        slabs = [(ox - t, oy - t, ox + w + t, oy), (ox + w, oy - t, ox + w + t, oy + h + t),
                 (ox - t, oy + h, ox + w + t, oy + h + t), (ox - t, oy - t, ox, oy + h + t)]
        bodies = []
        for i, (x0, y0, x1, y1) in enumerate(slabs):
            body = pymunk.Body(body_type=pymunk.Body.STATIC)
            wall = pymunk.Poly(body, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
            wall.collision_type = CollisionType.WALL
            wall.friction = wall.elasticity = 0.0
            self.space.add(body, wall)
            bodies.append((body, WALL, i))
        obstacles = pymunk.Body(body_type=pymunk.Body.STATIC)   # every static obstacle of the tile
        self.space.add(obstacles)
        bodies.append((obstacles, OBSTACLE, ANY_OBSTACLE))
        self.labels.add(bodies)
        self.offset = np.vstack([self.offset, [ox, oy]])
        self.pieces.append(TilePieces(world, max(CHUNK, side), obstacles))
        self.index[key] = tile
        return tile

    @property
    def piece_count(self) -> int:
        """Static pieces of every tile, built or not, and their walls."""
        return sum(len(pieces.owner) + 4 for pieces in self.pieces)

    @property
    def complete(self) -> bool:
        """Every obstacle of every tile is built (small maps soon are)."""
        return all(pieces.complete for pieces in self.pieces)

    def build_near(self, tiles: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        """Build the static obstacles of ``tiles`` near the boxes ``[lo, hi]`` (each in its tile's
        world coordinates, smaller than a chunk) that are not built yet.

        Each world's obstacles (a grid's cells as boxes) are cut into pieces bucketed by
        :data:`CHUNK`; the first box that meets a chunk builds its pieces. A map of any size
        thus costs pymunk only what its robots come near, and so does start-up.

        Only shapes are added (on the tile's obstacles' body, made with the tile): the space's
        bodies stay as they were.
        """
        for tile in np.unique(tiles).tolist():
            mine = tiles == tile
            pieces = self.pieces[tile]
            new = pieces.take(lo[mine], hi[mine])
            if len(new):
                self._add_pieces(tile, pieces, new)

    def _add_pieces(self, tile: int, pieces: TilePieces, new: np.ndarray) -> None:
        """Add pieces ``new`` of ``tile``'s obstacles as static shapes on the tile's obstacles' body."""
        offset = tuple(self.offset[tile])
        shapes = []
        for k in new.tolist():
            shapes += piece_shapes(pieces.body, pieces.world.obstacles[int(pieces.owner[k])], pieces.box(k), offset)
        for shape in shapes:
            shape.friction = 0.0
            shape.elasticity = 0.0
        self.space.add(*shapes)


class TilePieces:
    """A world's static obstacles cut into pieces (a polygon or circle whole, a grid box by box),
    bucketed by squares of ``side`` (at least :data:`CHUNK`), and which of them are built."""

    def __init__(self, world: World, side: float, body: pymunk.Body):
        self.world = world
        self.side = float(side)
        self.body = body
        """The static body every piece's shapes go on."""
        owners, boxes = [], []
        for i, obstacle in enumerate(world.obstacles):
            if obstacle.motion is not None:
                continue   # moving obstacles are lent per step (Physics._lend_movers)
            if isinstance(obstacle, GridObstacle):
                rects = obstacle.rectangles()
                owners.append(np.full(len(rects), i))
                boxes.append(rects)
            else:
                lo, hi = obstacle.bounds
                owners.append([i])
                boxes.append(np.concatenate([lo, hi])[None])
        self.owner = np.concatenate(owners).astype(np.intp) if owners else np.zeros(0, np.intp)
        self.boxes = np.vstack(boxes) if boxes else np.zeros((0, 4))
        self.built = np.zeros(len(self.owner), bool)
        self.cols = max(1, int(math.ceil(world.size[0] / self.side)))
        rows = max(1, int(math.ceil(world.size[1] / self.side)))
        self.chunk_done = np.zeros(self.cols * rows, bool)
        self.complete = False
        """Every chunk is built."""
        self.rows = rows
        c0 = np.clip(np.floor(self.boxes[:, :2] / self.side).astype(np.intp), 0, [self.cols - 1, rows - 1])
        c1 = np.clip(np.floor(self.boxes[:, 2:] / self.side).astype(np.intp), 0, [self.cols - 1, rows - 1])
        span = c1 - c0 + 1
        count = span[:, 0] * span[:, 1]
        piece = np.repeat(np.arange(len(self.owner)), count)
        k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        chunk = (c0[piece, 1] + k // span[piece, 0]) * self.cols + c0[piece, 0] + k % span[piece, 0]
        order = np.argsort(chunk, kind="stable")
        self.members = piece[order]
        self.start = np.concatenate([[0], np.cumsum(np.bincount(chunk, minlength=self.cols * rows))])

    def box(self, k: int) -> np.ndarray | None:
        """The box of piece ``k`` when it is one box of a grid, else None (the whole obstacle)."""
        return self.boxes[k] if isinstance(self.world.obstacles[self.owner[k]], GridObstacle) else None

    def take(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The pieces not built yet of the chunks that the boxes ``[lo, hi]`` (each smaller than a
        chunk) meet, now marked built."""
        top = [self.cols - 1, self.rows - 1]
        c0 = np.clip(np.floor(lo / self.side).astype(np.intp), 0, top)
        c1 = np.clip(np.floor(hi / self.side).astype(np.intp), 0, top)
        corners = np.concatenate([c0[:, 1] * self.cols + c0[:, 0], c0[:, 1] * self.cols + c1[:, 0],
                                  c1[:, 1] * self.cols + c0[:, 0], c1[:, 1] * self.cols + c1[:, 0]])
        chunks = corners[~self.chunk_done[corners]]
        if not len(chunks):
            return np.zeros(0, np.intp)
        chunks = np.unique(chunks)
        self.chunk_done[chunks] = True
        self.complete = bool(self.chunk_done.all())
        pieces = np.unique(np.concatenate([self.members[self.start[c]:self.start[c + 1]] for c in chunks.tolist()]))
        pieces = pieces[~self.built[pieces]]
        self.built[pieces] = True
        return pieces


def piece_shapes(body: pymunk.Body, obstacle, box: np.ndarray | None, offset: tuple[float, float]) -> list[pymunk.Shape]:
    """The shapes of one piece: one box of a grid, or a whole polygon or circle."""
    if box is None:
        return obstacle_shapes(body, obstacle, offset)
    (x0, y0, x1, y1), (ox, oy) = box.tolist(), offset
    shape = pymunk.Poly(body, [(x0 + ox, y0 + oy), (x1 + ox, y0 + oy), (x1 + ox, y1 + oy), (x0 + ox, y1 + oy)])
    shape.collision_type = CollisionType.OBSTACLE
    return [shape]


def obstacle_shapes(body: pymunk.Body, obstacle, offset: tuple[float, float]) -> list[pymunk.Shape]:
    """The obstacle's shapes on ``body``, its written coordinates shifted by ``offset``."""
    ox, oy = offset
    if isinstance(obstacle, PolygonObstacle):
        shapes = [pymunk.Poly(body, [(x + ox, y + oy) for x, y in piece]) for piece in obstacle.convex_pieces()]
    elif isinstance(obstacle, CircleObstacle):
        cx, cy = obstacle.center
        shapes = [pymunk.Circle(body, obstacle.radius, offset=(cx + ox, cy + oy))]
    else:
        raise TypeError(f"unknown obstacle {obstacle!r}")
    for shape in shapes:
        shape.collision_type = CollisionType.OBSTACLE
    return shapes
