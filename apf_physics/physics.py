"""Physics with pymunk: robots are discs among static obstacles and the map's walls.

The robots of many episodes ("slots") advance together: every control step takes one
velocity command per robot and returns a :class:`ContactLog` of what touched what, read
from pymunk's arbiters after every substep. The physics knows nothing of planners,
observations or rewards.

**Where pymunk does the work.** A robot whose move this step provably cannot touch anything
moves exactly as pymunk would move a free disc (``p + v·dt``), without pymunk: the test is
conservative, from a raster of capped clearance (1-Lipschitz, so three samples along the
move bound it everywhere; the raster's interpolation error is subtracted) and, for robots
sharing a slot, the exact closest approach of two linearly moving points. Every other robot
is simulated by pymunk through a *proxy*: a dynamic disc that is put in the robot's world,
moved by pymunk with the robot's velocity over fixed substeps, and read back. Proxies stay
with their robot while it keeps needing physics and are parked far away when it does not.
Robots in open space (most of them, most of the time) therefore cost pymunk nothing, and the
cost per robot-step does not grow with the number of robots.

**Tiles.** Each world's walls are built once as static shapes in a tile of the space, and its
obstacles piece by piece (a grid's cells as boxes), in :data:`CHUNK` squares, when a robot that
needs physics first comes near: a large map costs pymunk only where its robots go. Robots that are alone in their slot share their world's tile: their proxies are
in one collision group and never touch each other. Slots of several robots (formations) get
a tile each, so that their robots touch each other but never another slot's.

**Tunnelling.** Chipmunk detects overlaps, not swept contacts, so a disc moving ``δ`` per
substep can sink at most ``δ`` into an obstacle before the solver pushes it out. The
substep count is chosen so that ``δ ≤ 0.9 · robot_radius`` at the fastest allowed speed: a
robot's centre therefore never enters an obstacle, however thin (a zero-radius point
obstacle or a zero-thickness wall included).

Only public pymunk API is used; ``pymunk.batch`` (reading and writing every body's
position and velocity in one call) is marked experimental by pymunk, hence ``pymunk<8``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Sequence

import numpy as np
import pymunk
import pymunk.batch

from apf_physics.errors import UserError
from apf_physics.field import Atlas
from apf_physics.obstacles import CircleObstacle, GridObstacle, PolygonObstacle
from apf_physics.world import World

WALL_THICKNESS = 1.0  # of the slabs around each map [units]
MAX_SPEED = math.sqrt(2.0)  # a diagonal unit move (±1, ±1) per control step [units per control step]
TILE_GAP = 4.0  # free space between neighbouring tiles, beyond their walls [units]
CONTACT_MARGIN = 0.01  # a move that keeps this much more than touching distance needs no physics [units]
CLEARANCE_RESOLUTION = 8  # nodes per unit of the clearance rasters that decide who needs physics
CLEARANCE_CAP = 4.0  # clearance beyond this is not measured (it exceeds any move plus a radius)
_FEW_PAIRS = 64  # up to this many touching pairs, contacts are read with dicts rather than arrays
_FEW = 4  # up to this many proxies, per-body attribute access beats pymunk.batch's fixed cost
_PROXY_GROUP = 1  # collision group of proxies of single-robot slots: they never touch each other
_THIRDS = np.array([0.0, 0.5, 1.0])[None, :, None]  # where a move's clearance is sampled
KINDS = ("obstacle", "wall", "robot", "moving_obstacle")
"""What a robot can touch; :attr:`ContactLog.pairs` holds indices into this."""
_OBSTACLE, _WALL, _ROBOT, _MOVING = range(4)


class CollisionType(IntEnum):
    ROBOT = 1
    OBSTACLE = 2
    WALL = 3


@dataclass(frozen=True)
class Contact:
    """One touch seen during a control step.

    Attributes:
        robot: Global index of the robot.
        kind: ``"obstacle"``, ``"wall"`` or ``"robot"``.
        other: Obstacle index in the robot's world, wall index (0 bottom, 1 right, 2 top, 3 left),
            or the other robot's global index.
    """

    robot: int
    kind: str
    other: int


@dataclass(frozen=True)
class ContactLog:
    """What touched what during the last control step.

    Attributes:
        obstacle: (N,) bool: the robot touched a static obstacle.
        wall: (N,) bool: the robot touched the map's edge.
        robot: (N,) bool: the robot touched another robot.
        moving: (N,) bool: the robot touched a moving obstacle (or one touched it).
        pairs: (K, 3) int: one row ``(robot, kind, other)`` per touching pair (:data:`KINDS`;
            a robot–robot touch appears once per robot), sorted.
    """

    obstacle: np.ndarray
    wall: np.ndarray
    robot: np.ndarray
    moving: np.ndarray
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.intp))

    @property
    def any(self) -> np.ndarray:
        """(N,) bool: touched anything."""
        return self.obstacle | self.wall | self.robot | self.moving

    @property
    def touched(self) -> bool:
        """Whether anything touched anything."""
        return len(self.pairs) > 0

    @property
    def contacts(self) -> list[Contact]:
        """The pairs as :class:`Contact` records."""
        return [Contact(int(r), KINDS[k], int(o)) for r, k, o in self.pairs.tolist()]


def substeps_for(radius: float, max_speed: float = MAX_SPEED) -> int:
    """The fewest substeps (a power of two) that keep a robot's centre out of every obstacle."""
    return 2 ** math.ceil(math.log2(max(1.0, max_speed / (0.9 * radius))))


class Physics:
    """Robots in slots, each slot in a world; one pymunk space for all of them.

    Args:
        worlds: The world of each slot (a slot's world can be replaced with :meth:`set_world`).
        robots_per_slot: Robots in each slot; robot ``r`` of slot ``s`` has global index
            ``s * robots_per_slot + r``.
        control_dt: Duration of one control step; a velocity command ``v`` moves a free robot by
            ``v · control_dt``.
        max_speed: Fastest allowed speed, in units per control step; commands are clipped to it.
        substeps: Substeps per control step; by default the fewest (a power of two) that keep
            tunnelling impossible for the smallest robot, against the fastest moving obstacle
            (see the module docstring).
        other_worlds: Worlds that slots may be put in later (:meth:`set_world`): counted for the
            substeps.
        crowds: Slots with the same crowd number share one tile and their robots meet (several
            formations in one world, one slot each); default: every slot on its own.

    Moving obstacles are kinematic bodies, lent like the robots' proxies to the slots whose
    robots need physics near them, and put where their route has them at the slot's step.
    A slot in a world with moving obstacles has a tile of its own (its obstacles are where
    its own episode's step puts them).
    """

    def __init__(self, worlds: Sequence[World], robots_per_slot: int = 1, control_dt: float = 1.0,
                 max_speed: float = MAX_SPEED, substeps: int | None = None, other_worlds: Sequence[World] = (),
                 crowds: Sequence[int] | None = None):
        if not worlds:
            raise ValueError("Physics needs at least one world")
        self.num_slots = len(worlds)
        self.robots_per_slot = int(robots_per_slot)
        self.num_robots = self.num_slots * self.robots_per_slot
        self.crowd = np.arange(self.num_slots) if crowds is None else np.asarray(crowds, np.intp).reshape(self.num_slots)
        numbers, size = np.unique(self.crowd, return_counts=True)
        self._shared = size[np.searchsorted(numbers, self.crowd)] > 1     # (S,) the slot meets other slots
        # robots that meet robots of other slots: one group per crowd of several slots
        m = self.robots_per_slot
        self._crowd_robots = [(np.flatnonzero(self.crowd == c)[:, None] * m + np.arange(m)).ravel()
                              for c in numbers[size > 1]]
        self.present = np.ones(self.num_robots, bool)
        """(N,) bool: robots that exist (a slot of a formation smaller than ``robots_per_slot`` has absent ones)."""
        self.control_dt = float(control_dt)
        self.max_speed = float(max_speed)
        every = list(worlds) + list(other_worlds)
        self._min_radius = min(w.robot_radius for w in every)
        obstacle_speed = max((w.obstacles[i].motion.speed for w in every for i in w.moving), default=0.0)
        relative = self.max_speed + obstacle_speed / self.control_dt
        self.substeps = int(substeps) if substeps is not None else substeps_for(self._min_radius, relative)
        self.dt = self.control_dt / self.substeps

        self.space = pymunk.Space()
        self.space.iterations = 10
        # Chipmunk tolerates 0.1 of overlap by default; a robot resting against an obstacle with
        # that much overlap would sink past its boundary on the next push. Correct overlaps fully.
        self.space.collision_slop = 0.002
        # Forget a contact as soon as it ends: a proxy that moves to another robot must not
        # inherit the warm-start impulses of the contact it had before, and the arbiters read
        # after a substep are exactly the pairs touching then.
        self.space.collision_persistence = 1

        # Static geometry: one tile per (world, lane); lane 0 is shared by single-robot slots.
        # Each obstacle and each wall of a tile has a static body of its own: an arbiter's body
        # ids then say what a robot touched.
        self._tiles: dict[tuple[int, int], int] = {}
        self._tile_offset = np.zeros((0, 2))
        self._tile_pieces: list[_Pieces] = []            # each tile's obstacles, built where robots come
        self._next_tile_x = 0.0
        self._static_ids = np.zeros(0, np.uintp)        # sorted body ids of obstacles, walls, moving obstacles
        self._static_label = np.zeros((0, 2), np.intp)  # (kind, index) of each, in that order
        self._label_of_id: dict[int, tuple[int, int]] = {}   # the same as a dict (few contacts are read by it)
        # Moving obstacles: kinematic bodies, each built for one (world, obstacle), lent per step.
        self._mover_body: list[pymunk.Body] = []
        self._mover_key: list[tuple[int, int]] = []
        self._mover_target = np.zeros((0, 4))           # position and velocity before pymunk next steps
        self._slot_time = np.zeros(self.num_slots)
        # Clearance rasters, one per distinct world, sampled together.
        self._atlas = Atlas(CLEARANCE_RESOLUTION)
        self._atlas_ids: dict[int, int] = {}
        self._positions = np.zeros((self.num_robots, 2))

        self.worlds: list[World] = [None] * self.num_slots  # type: ignore[list-item]
        self._slot_tile = np.zeros(self.num_slots, np.intp)
        self._slot_radius = np.zeros(self.num_slots)
        self._slot_moving = np.zeros(self.num_slots, bool)
        self._any_moving = False
        # per robot, for needs_physics(): its world's clearance raster (three samples each) and
        # twice the least clearance that needs no physics
        self._sample_atlas = np.zeros(3 * self.num_robots, np.intp)
        self._free_twice = np.zeros(self.num_robots)
        for s, world in enumerate(worlds):
            self._assign(s, world)

        # Proxies: dynamic discs lent to the robots that need physics this step.
        self._proxy_body: list[pymunk.Body] = []
        self._proxy_robot = np.zeros(0, np.intp)     # robot each proxy simulates, -1: parked
        self._proxy_dirty = np.zeros(0, bool)        # parked this step; may carry solver state
        self._proxy_radius = np.zeros(0)
        self._proxy_solo = np.zeros(0, bool)          # in the collision group of proxies that never meet
        self._proxy_ids = np.zeros(0, np.uintp)      # their body ids
        self._proxy_of_id: dict[int, int] = {}        # the same as a dict
        self._proxy_target = np.zeros((0, 2))         # where a proxy is to be put before pymunk next steps
        self._proxy_moved = np.zeros(0, bool)         # ... for those that must be put there
        self._robot_proxy = np.full(self.num_robots, -1, np.intp)
        self._proxy_held = False                     # some robot holds a proxy
        self._buffer = pymunk.batch.Buffer()
        self._arbiters = pymunk.batch.Buffer()
        # pairs of shapes touching now, counted by pymunk's begin/separate callbacks (each called
        # once per contact, not per substep): a substep after which none touch has no arbiters to read
        touching = self._touching = [0]

        def begin(arbiter, space, data):
            touching[0] += 1

        def separate(arbiter, space, data):
            touching[0] -= 1

        self.space.on_collision(begin=begin, separate=separate)
        self._rows_dirty = True
        nothing = np.zeros(self.num_robots, bool)
        nothing.flags.writeable = False
        self._touch_free = ContactLog(nothing, nothing, nothing, nothing)   # the log of a step without contacts
        self._movers_needed: list = []

    # -- worlds and tiles ------------------------------------------------------------------
    def _lane(self, slot: int, world: World) -> int:
        if self._shared[slot]:
            return -1 - int(self.crowd[slot])    # the crowd's own tile
        return slot + 1 if self.robots_per_slot > 1 or world.moving else 0

    def _assign(self, slot: int, world: World) -> None:
        # a tile is the world's geometry: worlds that differ only in targets (several formations) share it
        key = (id(world.obstacles), self._lane(slot, world))
        if key not in self._tiles:
            self._tiles[key] = self._build_tile(world)
        raster = world.clearance_raster(CLEARANCE_RESOLUTION, CLEARANCE_CAP)   # shared by worlds of one map
        if id(raster) not in self._atlas_ids:
            self._atlas_ids[id(raster)] = self._atlas.add(raster)
        self.worlds[slot] = world
        self._any_moving = self._any_moving or bool(world.moving)   # stays set: moving obstacles were met
        self._moving_slots = None
        self._slot_moving[slot] = bool(world.moving)
        self._slot_tile[slot] = self._tiles[key]
        self._slot_radius[slot] = world.robot_radius
        m = self.robots_per_slot
        self._sample_atlas[3 * m * slot:3 * m * (slot + 1)] = self._atlas_ids[id(raster)]
        # the raster is within 0.71 / resolution of the clearance (see World.clearance_raster)
        self._free_twice[m * slot:m * (slot + 1)] = 2 * (world.robot_radius + CONTACT_MARGIN + 0.71 / CLEARANCE_RESOLUTION)

    def _build_tile(self, world: World) -> int:
        """Add ``world``'s walls as static shapes at a fresh offset, and its obstacles to be built
        where robots come (:meth:`_ensure_obstacles`); returns the tile index."""
        tile = len(self._tile_offset)
        ox, oy = self._next_tile_x + WALL_THICKNESS, 0.0
        w, h = world.size
        self._next_tile_x += w + 2 * WALL_THICKNESS + TILE_GAP
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
            bodies.append((body, _WALL, i))
        self._label_bodies(bodies)
        self._tile_offset = np.vstack([self._tile_offset, [ox, oy]])
        # a chunk holds any robot's box of one step (its move, its radius and the margin around)
        reach = world.robot_radius + CONTACT_MARGIN + 0.5
        self._tile_pieces.append(_Pieces(world, max(CHUNK, 2 * reach + self.max_speed * self.control_dt)))
        self._rows_dirty = True
        return tile

    def _ensure_obstacles(self, robots: np.ndarray, moves: np.ndarray) -> None:
        """Build the static obstacles near the moves of ``robots`` that are not built yet.

        Each world's obstacles (a grid's cells as boxes) are cut into pieces bucketed by
        :data:`CHUNK`; the first robot that needs physics near a chunk builds its pieces. A map
        of any size thus costs pymunk only what its robots come near, and so does start-up.
        """
        if all(pieces.complete for pieces in self._tile_pieces):
            return   # every obstacle of every tile is built (small maps soon are)
        tiles = self._slot_tile[robots // self.robots_per_slot]
        p = self._positions[robots]
        reach = self._slot_radius[robots // self.robots_per_slot] + CONTACT_MARGIN + 0.5
        lo = np.minimum(p, p + moves[robots]) - reach[:, None]
        hi = np.maximum(p, p + moves[robots]) + reach[:, None]
        for tile in np.unique(tiles).tolist():
            mine = tiles == tile
            pieces = self._tile_pieces[tile]
            new = pieces.take(lo[mine], hi[mine])
            if len(new):
                self._add_pieces(tile, pieces, new)

    def _add_pieces(self, tile: int, pieces: _Pieces, new: np.ndarray) -> None:
        """Add pieces ``new`` of ``tile``'s obstacles as static shapes (an obstacle's first piece makes its body)."""
        offset = tuple(self._tile_offset[tile])
        labelled = []
        shapes = []
        for k in new.tolist():
            index = int(pieces.owner[k])
            body = pieces.bodies.get(index)
            if body is None:
                body = pieces.bodies[index] = pymunk.Body(body_type=pymunk.Body.STATIC)
                self.space.add(body)
                labelled.append((body, _OBSTACLE, index))
            shapes += _piece_shapes(body, pieces.world.obstacles[index], pieces.box(k), offset)
        for shape in shapes:
            shape.friction = 0.0
            shape.elasticity = 0.0
        self.space.add(*shapes)
        if labelled:
            self._label_bodies(labelled)
            self._rows_dirty = True

    def _label_bodies(self, bodies: list[tuple[pymunk.Body, int, int]]) -> None:
        """Record what each body is (kind, index), for reading contacts from arbiters."""
        ids = np.concatenate([self._static_ids, np.array([b.id for b, _, _ in bodies], np.uintp)])
        labels = np.concatenate([self._static_label, np.array([(k, i) for _, k, i in bodies], np.intp).reshape(-1, 2)])
        order = np.argsort(ids)
        self._static_ids, self._static_label = ids[order], labels[order]
        self._label_of_id.update((b.id, (k, i)) for b, k, i in bodies)

    def _new_mover(self, world: World, index: int) -> int:
        """A kinematic body shaped like moving obstacle ``index`` of ``world``, parked."""
        body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        shapes = _obstacle_shapes(body, world.obstacles[index], (0.0, 0.0))
        for shape in shapes:
            shape.friction = 0.0
            shape.elasticity = 0.0
        k = len(self._mover_body)
        body.position = (4.0 * k, -2000.0)
        self.space.add(body, *shapes)
        self._mover_body.append(body)
        self._mover_key.append((id(world), index))
        self._mover_target = np.vstack([self._mover_target, [4.0 * k, -2000.0, 0.0, 0.0]])
        self._label_bodies([(body, _MOVING, index)])
        self._rows_dirty = True
        return k

    def set_world(self, slot: int, world: World) -> None:
        """Put ``slot`` in ``world`` (its robots keep their coordinates until :meth:`place`)."""
        if world is self.worlds[slot]:
            return
        robots = np.arange(slot * self.robots_per_slot, (slot + 1) * self.robots_per_slot)
        self._release(robots)
        self._assign(slot, world)

    # -- proxies ---------------------------------------------------------------------------
    def _new_proxy(self, radius: float, solo: bool) -> int:
        body = pymunk.Body(1.0, math.inf)
        shape = pymunk.Circle(body, radius)
        shape.collision_type = CollisionType.ROBOT
        shape.friction = 0.0
        shape.elasticity = 0.0
        if solo:
            shape.filter = pymunk.ShapeFilter(group=_PROXY_GROUP)
        k = len(self._proxy_body)
        body.position = self._parking(k)
        self.space.add(body, shape)
        self._proxy_body.append(body)
        self._proxy_robot = np.append(self._proxy_robot, -1)
        self._proxy_dirty = np.append(self._proxy_dirty, False)
        self._proxy_radius = np.append(self._proxy_radius, radius)
        self._proxy_solo = np.append(self._proxy_solo, solo)
        self._proxy_ids = np.append(self._proxy_ids, np.uintp(body.id))
        self._proxy_of_id[body.id] = k
        self._proxy_target = np.vstack([self._proxy_target, self._parking(k)])
        self._proxy_moved = np.append(self._proxy_moved, False)
        self._rows_dirty = True
        return k

    @staticmethod
    def _parking(k: int) -> tuple[float, float]:
        """Where proxy ``k`` waits: far below every tile, 4 units from its neighbours."""
        return (4.0 * k, -1000.0)

    def _release(self, robots: np.ndarray) -> None:
        """Take the proxies of ``robots`` back to the parking (dirty until pymunk steps once more)."""
        proxies = self._robot_proxy[robots]
        proxies = proxies[proxies >= 0]
        if not len(proxies):
            return
        self._proxy_target[proxies] = [self._parking(k) for k in proxies.tolist()]
        self._proxy_moved[proxies] = True
        self._robot_proxy[self._proxy_robot[proxies]] = -1
        self._proxy_robot[proxies] = -1
        self._proxy_dirty[proxies] = True

    def _lend(self, robots: np.ndarray) -> None:
        """Give each of ``robots`` (none holding one) a clean proxy of its radius and kind, placed where it is."""
        if not len(robots):
            return
        slots = robots // self.robots_per_slot
        radius = self._slot_radius[slots]
        solo = ~self._shared[slots] & ~self._slot_moving[slots] & (self.robots_per_slot == 1)
        for r, alone in {(float(a), bool(b)) for a, b in zip(radius, solo)}:
            mine = robots[(radius == r) & (solo == alone)]
            free = np.flatnonzero((self._proxy_robot < 0) & ~self._proxy_dirty & (self._proxy_radius == r)
                                  & (self._proxy_solo == alone))
            while len(free) < len(mine):
                free = np.append(free, self._new_proxy(r, alone))
            proxies = free[:len(mine)]
            self._proxy_robot[proxies] = mine
            self._robot_proxy[mine] = proxies
            self._proxy_target[proxies] = self._positions[mine] + self._tile_offset[self._slot_tile[mine // self.robots_per_slot]]
            self._proxy_moved[proxies] = True

    def _index_rows(self) -> None:
        """Map pymunk.batch rows to proxies (rows are not in insertion order)."""
        buf = self._buffer
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.BODY_ID, buf)
        ids = np.frombuffer(buf.int_buf(), dtype=np.uintp).copy()
        index = {b.id: k for k, b in enumerate(self._proxy_body)}
        row_proxy = np.array([index.get(int(i), -1) for i in ids])
        self._proxy_rows = np.flatnonzero(row_proxy >= 0)
        self._proxy_of_row = row_proxy[self._proxy_rows]
        self._row_of_proxy = np.empty(len(self._proxy_body), np.intp)
        self._row_of_proxy[self._proxy_of_row] = self._proxy_rows
        movers = {b.id: k for k, b in enumerate(self._mover_body)}
        row_mover = np.array([movers.get(int(i), -1) for i in ids])
        self._row_of_mover = np.empty(len(self._mover_body), np.intp)
        self._row_of_mover[row_mover[row_mover >= 0]] = np.flatnonzero(row_mover >= 0)
        self._proxy_order = np.argsort(self._proxy_ids)
        self._rows_dirty = False

    # -- control ---------------------------------------------------------------------------
    def place(self, robots: Sequence[int] | np.ndarray, positions: np.ndarray) -> None:
        """Teleport robots (global indices) to world-local ``positions`` and stop them.

        Robots placed overlapping each other or an obstacle's edge are first moved apart, in
        small steps that each keep the robot's radius from every obstacle and the map's edge
        (so that nothing is crossed, as the solver's push-out could cross a thin wall).

        Raises:
            UserError: A centre inside an obstacle or outside the map, or robots that cannot be
                separated in free space.
        """
        robots = np.asarray(robots, dtype=np.intp).ravel()
        self._release(robots)
        self._positions[robots] = np.asarray(positions, dtype=float).reshape(-1, 2)
        m = self.robots_per_slot
        # One raster lookup for all: a robot clear of the static obstacles by more than its
        # radius (and the raster's error) in a world without moving ones needs no more checks.
        clearance = self._atlas.sample(self._positions[robots], self._sample_atlas[3 * robots])
        slots = robots // m
        doubtful = (clearance - 0.71 / CLEARANCE_RESOLUTION < self._slot_radius[slots] + 1e-6)
        doubtful |= self._slot_moving[slots]
        crowds = set(self.crowd[slots[doubtful]].tolist())
        if m > 1 or self._crowd_robots:
            crowds |= set(self.crowd[slots].tolist())   # robots of one crowd may overlap one another
        for crowd in sorted(crowds):
            members = np.flatnonzero(self.crowd == crowd)
            mine = (members[:, None] * m + np.arange(m)).ravel()
            self._separate(int(members[0]), mine[self.present[mine]])

    def _separate(self, slot: int, mine: np.ndarray) -> None:
        """Move robots ``mine`` (of one crowd, in ``slot``'s world) out of each other and off
        obstacles' edges without crossing anything."""
        world = self.worlds[slot]
        m = len(mine)
        p = self._positions[mine].copy()
        r, t = world.robot_radius, float(self._slot_time[slot])
        clearance = world.clearance(p, t)
        if np.any(clearance <= 0):
            k = int(np.argmin(clearance))
            raise UserError(f"{world.label}: robot {int(mine[k])} placed at {np.round(p[k], 4).tolist()} has its "
                            f"centre inside an obstacle or outside the map")
        need = 2 * r + 1e-6
        for _ in range(200):
            diff = p[:, None, :] - p[None, :, :]
            d = np.hypot(diff[..., 0], diff[..., 1]) + np.eye(m) * 1e9
            overlap = np.clip(need - d, 0.0, None)
            edge = np.clip(r + 1e-6 - clearance, 0.0, None)
            if not overlap.any() and not edge.any():
                self._positions[mine] = p
                return
            # apart along the line of centres (robots on one point: a fixed fan of directions)
            fan = np.arange(m)[:, None] - np.arange(m)[None, :]
            angle = fan * 2.399963   # the golden angle: distinct for every pair
            unit = np.where(d[..., None] > 1e-9, diff / np.maximum(d, 1e-9)[..., None],
                            np.stack([np.cos(angle), np.sin(angle)], -1))
            # a little more than the overlap (1e-3), so that it ends rather than only halves
            push = 0.5 * np.sum(np.where(overlap > 0, overlap + 1e-3, 0.0)[..., None] * unit, axis=1)
            if edge.any():   # off an obstacle's edge: up the clearance (finite differences)
                h = 1e-4
                grad = np.stack([world.clearance(p + [h, 0], t) - world.clearance(p - [h, 0], t),
                                 world.clearance(p + [0, h], t) - world.clearance(p - [0, h], t)], -1) / (2 * h)
                push += np.where(edge > 0, edge + 1e-3, 0.0)[:, None] * grad
            length = np.hypot(push[:, 0], push[:, 1])
            push *= np.minimum(1.0, 0.05 / np.maximum(length, 1e-12))[:, None]
            # never through anything: take the longest of these steps that keeps the radius all along
            bar = np.minimum(r, clearance)
            step = np.zeros_like(push)
            for scale in (0.25, 0.5, 1.0):
                ok = world.path_clearance(p, p + scale * push, 0.01, t=t, during=False) >= bar
                step[ok] = scale * push[ok]
            p = p + step
            clearance = world.clearance(p, t)   # once per move: clearance is most of the cost of placing robots
        raise UserError(f"{world.label}: robots {mine.tolist()} placed on top of each other "
                        f"could not be moved apart in free space")

    @property
    def positions(self) -> np.ndarray:
        """(N, 2) robot centres in each robot's own world coordinates."""
        return self._positions.copy()

    def needs_physics(self, moves: np.ndarray) -> np.ndarray:
        """(N,) bool: robots whose ``moves`` this step might bring them into contact with anything.

        Conservative: False guarantees that the robot's disc keeps more than
        :data:`CONTACT_MARGIN` from every obstacle, the map's edge and the robots of its slot
        during the whole move (each moving straight and uniformly), so that it moves exactly
        as a free pymunk disc would. Moving obstacles are taken where the slots' steps
        (:meth:`set_time`) put them.
        """
        # Clearance at the start, the middle and the end of each move: a 1-Lipschitz function
        # sampled at both ends of a piece of length L/2 is at least (c_a + c_b − L/2) / 2 on it,
        # so on the whole move at least (c_mid + min(c_start, c_end) − L/2) / 2.
        samples = self._positions[:, None, :] + _THIRDS * moves[:, None, :]
        c = self._atlas.sample(samples, self._sample_atlas).reshape(-1, 3)
        needs = c[:, 1] + np.minimum(c[:, 0], c[:, 2]) - 0.5 * np.hypot(moves[:, 0], moves[:, 1]) < self._free_twice
        m = self.robots_per_slot
        if m > 1:
            p = self._positions.reshape(-1, m, 2)
            dp = moves.reshape(-1, m, 2)
            close = _closest_approach(p, dp) < 2 * self._slot_radius[:, None, None] + CONTACT_MARGIN
            close &= self.present.reshape(-1, m)[:, None, :]
            close[:, np.arange(m), np.arange(m)] = False
            needs |= close.any(axis=2).ravel()
        for group in self._crowd_robots:   # robots of several slots that meet: every pair near each other
            group = group[self.present[group]]
            close = _closest_approach(self._positions[group][None], moves[group][None])[0]
            close = close < 2 * self._slot_radius[group // m][:, None] + CONTACT_MARGIN
            np.fill_diagonal(close, False)
            needs[group] |= close.any(axis=1)
        if not self._any_moving:
            return needs
        self._movers_needed = []
        for slots, world, index, near in self._near_movers(moves):
            robots = (slots[:, None] * m + np.arange(m)).ravel()
            needs[robots] |= near.ravel()
            self._movers_needed.append((world, index, slots, near.any(axis=1)))
        return needs

    def set_time(self, steps: np.ndarray) -> None:
        """The control step each slot's episode is at (where its moving obstacles are)."""
        self._slot_time = np.asarray(steps, float).reshape(self.num_slots)

    def _near_movers(self, moves: np.ndarray):
        """For each moving obstacle of each world in use: ``(slots, world, index, near (k, m))``,
        the robots of those slots whose swept disc this step comes near the obstacle's swept box."""
        if not self._any_moving:
            return
        m = self.robots_per_slot
        if self._moving_slots is None:   # slots grouped by moving world, until a slot changes world
            groups: dict[int, tuple[World, list[int]]] = {}
            for s, w in enumerate(self.worlds):
                if w.moving:
                    groups.setdefault(id(w), (w, []))[1].append(s)
            self._moving_slots = [(w, np.array(slots, np.intp)) for w, slots in groups.values()]
        for world, slots in self._moving_slots:
            t = self._slot_time[slots]
            p = self._positions.reshape(-1, m, 2)[slots]
            q = p + moves.reshape(-1, m, 2)[slots]
            reach = world.robot_radius + 2 * CONTACT_MARGIN
            robot_lo, robot_hi = np.minimum(p, q) - reach, np.maximum(p, q) + reach
            for index in world.moving:
                obstacle = world.obstacles[index]
                start, end = obstacle.motion.offset(t), obstacle.motion.offset(t + 1.0)
                lo, hi = obstacle.bounds
                box_lo = (lo + np.minimum(start, end))[:, None, :]
                box_hi = (hi + np.maximum(start, end))[:, None, :]
                near = np.all((robot_hi >= box_lo) & (robot_lo <= box_hi), axis=2)
                if near.any():
                    yield slots, world, index, near

    def step(self, velocities: np.ndarray, active: np.ndarray | None = None) -> ContactLog:
        """Advance one control step with a velocity command per robot.

        Args:
            velocities: (N, 2) commanded velocities in units per control step; each is clipped to
                ``max_speed``.
            active: (N,) bool: the robots that take part (default all). The others are frozen
                where they are: they neither move nor touch anything (their slot's episode is over).

        Returns:
            The contacts seen during the step (read-only).
        """
        v = np.asarray(velocities, dtype=float).reshape(self.num_robots, 2)
        speed = np.hypot(v[:, 0], v[:, 1])
        if speed.max() > self.max_speed:
            too_fast = speed > self.max_speed
            v = v.copy()
            v[too_fast] *= (self.max_speed / speed[too_fast])[:, None]
        moves = v * self.control_dt
        simulate = self.needs_physics(moves) & self.present
        if active is not None:
            simulate &= active
            moves = moves * active[:, None]
        if not self._proxy_held and not simulate.any():
            self._positions += moves
            return self._touch_free
        held = self._robot_proxy >= 0
        self._release(np.flatnonzero(held & ~simulate))
        self._lend(np.flatnonzero(simulate & ~held))
        robots = np.flatnonzero(simulate)
        if len(robots):
            self._ensure_obstacles(robots, moves)
        self._lend_movers(active)
        before = self._positions[robots].copy()
        pairs = self._simulate(robots, v) if len(robots) or self._proxy_dirty.any() else None
        if len(robots) and (self.robots_per_slot > 1 or self._crowd_robots):
            self._undo_crossings(robots, before)
        free = ~simulate
        self._positions[free] += moves[free]
        self._proxy_held = bool(len(robots))
        return self._touch_free if pairs is None or not len(pairs) else self._log(pairs)

    def _undo_crossings(self, robots: np.ndarray, before: np.ndarray) -> None:
        """Put back any of ``robots`` whose move this step passed through a static obstacle.

        The substeps keep a robot's own move from tunnelling, but robots that touch each other
        (a formation, a crowd) can push one another faster than they were commanded, and the
        solver's pushes are not bounded. An exact check of each moved segment against the
        static obstacles (sampled every half radius: a segment through even a zero-thickness
        wall has a sample within a quarter radius of it, which no allowed move comes near)
        finds such a crossing; the robot then stays where it was, against the obstacle.
        """
        after = self._positions[robots]
        slots = robots // self.robots_per_slot
        for slot in np.unique(slots).tolist():
            world = self.worlds[slot]
            mine = np.flatnonzero(slots == slot)
            r = world.robot_radius
            clear = world.path_clearance(before[mine], after[mine], 0.5 * r)
            crossed = mine[clear < 0.5 * r]
            if not len(crossed):
                continue
            self._positions[robots[crossed]] = before[crossed]
            proxies = self._robot_proxy[robots[crossed]]
            self._proxy_target[proxies] = before[crossed] + self._tile_offset[self._slot_tile[slots[crossed]]]
            self._proxy_moved[proxies] = True

    def _lend_movers(self, active: np.ndarray | None) -> None:
        """Put a kinematic copy of each moving obstacle that a robot needing physics comes near
        where its route has it at the slot's step, moving to where it will be at the next."""
        if not self._mover_body and not self._movers_needed:
            return
        self._mover_target[:, :2] = np.column_stack([4.0 * np.arange(len(self._mover_body)),
                                                     np.full(len(self._mover_body), -2000.0)])
        self._mover_target[:, 2:] = 0.0
        m = self.robots_per_slot
        for world, index, slots, near in self._movers_needed:
            if active is not None:
                near = near & active.reshape(-1, m)[slots].any(axis=1)
            slots = slots[near]
            if not len(slots):
                continue
            pool = [k for k, key in enumerate(self._mover_key) if key == (id(world), index)]
            while len(pool) < len(slots):
                pool.append(self._new_mover(world, index))
            movers = np.array(pool[:len(slots)])
            motion = world.obstacles[index].motion
            t = self._slot_time[slots]
            start = motion.offset(t)
            self._mover_target[movers, :2] = start + self._tile_offset[self._slot_tile[slots]]
            self._mover_target[movers, 2:] = (motion.offset(t + 1.0) - start) / self.control_dt

    def _simulate(self, robots: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Step pymunk with the proxies of ``robots`` at their commanded velocities (the others at rest).

        Returns:
            (K, 2) body ids of the pairs that touched at some substep (a pair once per substep).
        """
        if self._rows_dirty:
            self._index_rows()
        proxies = self._robot_proxy[robots]
        velocity = np.zeros((len(self._proxy_body), 2))
        velocity[proxies] = v[robots] / self.control_dt
        moved = np.flatnonzero(self._proxy_moved)
        if len(self._proxy_body) <= _FEW and not self._mover_body:
            for k in moved.tolist():
                self._proxy_body[k].position = tuple(self._proxy_target[k])
            for k, (vx, vy) in enumerate(velocity.tolist()):
                self._proxy_body[k].velocity = (vx, vy)
        else:
            # every body's position and velocity in one read and one write (static bodies are
            # rows too: they are written back as they were read)
            fields = pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.VELOCITY
            buf = self._buffer
            buf.clear()
            pymunk.batch.get_space_bodies(self.space, fields, buf)
            rows = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 4).copy()
            rows[self._row_of_proxy[moved], :2] = self._proxy_target[moved]
            rows[self._proxy_rows, 2:] = velocity[self._proxy_of_row]
            rows[self._row_of_mover] = self._mover_target
            write = pymunk.batch.Buffer()
            write.set_float_buf(rows.reshape(-1))
            pymunk.batch.set_space_bodies(self.space, fields, write)
        self._proxy_moved[:] = False
        touched = []
        arbiter_fields = pymunk.batch.ArbiterFields.BODY_A_ID | pymunk.batch.ArbiterFields.BODY_B_ID
        touching = self._touching
        for _ in range(self.substeps):
            self.space.step(self.dt)
            if not touching[0]:
                continue
            self._arbiters.clear()
            pymunk.batch.get_space_arbiters(self.space, arbiter_fields, self._arbiters)
            ids = np.frombuffer(self._arbiters.int_buf(), dtype=np.uintp)
            if len(ids):
                touched.append(ids.reshape(-1, 2).copy())
        self._proxy_dirty[:] = False
        offsets = self._tile_offset[self._slot_tile[robots // self.robots_per_slot]]
        if len(self._proxy_body) <= _FEW and not self._mover_body:
            after = np.array([tuple(self._proxy_body[k].position) for k in proxies.tolist()]).reshape(-1, 2)
        else:
            buf = self._buffer
            buf.clear()
            pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.POSITION, buf)
            after = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 2)[self._row_of_proxy[proxies]]
        self._positions[robots] = after - offsets
        return np.vstack(touched) if touched else np.zeros((0, 2), np.uintp)

    def _log(self, pairs: np.ndarray) -> ContactLog:
        """The contact log of the touching body-id pairs (a pair may come several times)."""
        table = self._contact_rows_few(pairs) if len(pairs) <= _FEW_PAIRS else self._contact_rows(pairs)
        flags = np.zeros((len(KINDS), self.num_robots), bool)
        flags[table[:, 1], table[:, 0]] = True
        return ContactLog(flags[_OBSTACLE], flags[_WALL], flags[_ROBOT], flags[_MOVING], table)

    def _contact_rows_few(self, pairs: np.ndarray) -> np.ndarray:
        """:meth:`_contact_rows` for a few pairs: dict look-ups beat the arrays' fixed costs."""
        rows = set()
        proxy_of, label_of, robot_of = self._proxy_of_id, self._label_of_id, self._proxy_robot
        for ids in pairs.tolist():
            for a, b in ((ids[0], ids[1]), (ids[1], ids[0])):   # an arbiter's bodies come in either order
                k = proxy_of.get(a)
                if k is None or robot_of[k] < 0:
                    continue
                j = proxy_of.get(b)
                if j is None:
                    rows.add((int(robot_of[k]), *label_of[b]))
                elif robot_of[j] >= 0:
                    rows.add((int(robot_of[k]), _ROBOT, int(robot_of[j])))
        return np.array(sorted(rows), np.intp).reshape(-1, 3)

    def _contact_rows(self, pairs: np.ndarray) -> np.ndarray:
        """(K, 3) sorted distinct rows ``(robot, kind, other)`` of the touching body-id pairs."""
        proxy_index = self._proxy_order[np.clip(np.searchsorted(self._proxy_ids[self._proxy_order], pairs), 0,
                                                len(self._proxy_ids) - 1)]
        is_proxy = self._proxy_ids[proxy_index] == pairs
        robot_of = np.where(is_proxy, self._proxy_robot[proxy_index], -1)
        static = np.clip(np.searchsorted(self._static_ids, pairs), 0, max(len(self._static_ids) - 1, 0))
        robots, kinds, others = [], [], []
        for a, b in ((0, 1), (1, 0)):   # an arbiter's bodies come in either order
            robot = robot_of[:, a]
            with_static = (robot >= 0) & ~is_proxy[:, b]
            label = self._static_label[static[with_static, b]]
            with_robot = (robot >= 0) & (robot_of[:, b] >= 0)
            robots += [robot[with_static], robot[with_robot]]
            kinds += [label[:, 0], np.full(int(with_robot.sum()), _ROBOT)]
            others += [label[:, 1], robot_of[with_robot, b]]
        robot, kind, other = (np.concatenate(c).astype(np.int64) for c in (robots, kinds, others))
        # rows (robot, kind, other) as one sortable key: one 1-D unique instead of a row-wise one
        span = int(other.max(initial=0)) + 1
        key = np.unique((robot * len(KINDS) + kind) * span + other)
        return np.column_stack([key // (len(KINDS) * span), key // span % len(KINDS), key % span]).astype(np.intp)


def _closest_approach(p: np.ndarray, dp: np.ndarray) -> np.ndarray:
    """(S, m, m) least distance between robots i and j of each slot moving by ``dp`` over the step."""
    r0 = p[:, :, None, :] - p[:, None, :, :]
    dr = dp[:, :, None, :] - dp[:, None, :, :]
    a = np.sum(dr * dr, axis=-1)
    t = np.clip(np.where(a > 0, -np.sum(r0 * dr, axis=-1) / np.where(a > 0, a, 1.0), 0.0), 0.0, 1.0)
    closest = r0 + t[..., None] * dr
    return np.sqrt(np.sum(closest * closest, axis=-1))


CHUNK = 4.0
"""Least side of the squares [units] by which a world's static obstacles are built into pymunk as
robots come near (larger where a robot's box of one step would not fit in one)."""


class _Pieces:
    """A world's static obstacles cut into pieces (a polygon or circle whole, a grid box by box),
    bucketed by squares of ``side`` (at least :data:`CHUNK`), and which of them are built."""

    def __init__(self, world: World, side: float):
        self.world = world
        self.side = float(side)
        owners, boxes = [], []
        for i, obstacle in enumerate(world.obstacles):
            if obstacle.motion is not None:
                continue   # moving obstacles are lent per step (_lend_movers)
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
        self.bodies: dict[int, pymunk.Body] = {}
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


def _piece_shapes(body: pymunk.Body, obstacle, box: np.ndarray | None, offset: tuple[float, float]) -> list[pymunk.Shape]:
    """The shapes of one piece: one box of a grid, or a whole polygon or circle."""
    if box is None:
        return _obstacle_shapes(body, obstacle, offset)
    (x0, y0, x1, y1), (ox, oy) = box.tolist(), offset
    shape = pymunk.Poly(body, [(x0 + ox, y0 + oy), (x1 + ox, y0 + oy), (x1 + ox, y1 + oy), (x0 + ox, y1 + oy)])
    shape.collision_type = CollisionType.OBSTACLE
    return [shape]


def _obstacle_shapes(body: pymunk.Body, obstacle, offset: tuple[float, float]) -> list[pymunk.Shape]:
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
