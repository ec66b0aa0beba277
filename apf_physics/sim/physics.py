"""Physics with pymunk: robots are discs among static obstacles and the map's walls.

The robots of many episodes ("slots", :mod:`apf_physics.sim.slots`) advance together: every
control step takes one velocity command per robot and returns a :class:`ContactLog` of what
touched what, read from pymunk's arbiters after every substep (:mod:`apf_physics.sim.contacts`).
The physics knows nothing of planners, observations or rewards.

A step, in order, each part in a module of its own:

1. **The free-move test** (:mod:`apf_physics.sim.freemove`): a robot whose move this step provably
   cannot touch anything moves exactly as pymunk would move a free disc, without pymunk.
2. **Proxies** (:mod:`apf_physics.sim.proxies`): every other robot borrows a dynamic disc, and the
   moving obstacles near such robots are lent as kinematic copies (:mod:`apf_physics.sim.movers`);
   the static obstacles near them are built into the space if they are not yet
   (:mod:`apf_physics.sim.tiles`). Robots in open space (most of them, most of the time) cost
   pymunk nothing, and the cost per robot-step does not grow with the number of robots.
3. **Stepping**: pymunk moves the proxies over fixed substeps (:meth:`Physics._simulate`).
4. **Settling** (:mod:`apf_physics.sim.settle`): the overlaps the last substep leaves are pushed
   out before the step ends; a robot pushed through a wall by others is put back.

Robots are placed by :mod:`apf_physics.sim.placement` (moved apart and off edges without crossing
anything).

**Tunnelling.** Chipmunk detects overlaps, not swept contacts, so a disc moving ``δ`` per
substep can sink at most ``δ`` into an obstacle before the solver pushes it out. The
substep count (:func:`~apf_physics.world.kinematics.physics_substeps`) is chosen so that
``δ ≤ 0.9 · robot_radius`` at the fastest a robot can move, and no body is let go faster: a
unicycle's velocity, changed at every substep to follow its arc, is capped at the top speed
(:meth:`~apf_physics.sim.bodies.SpaceBodies.add_velocities`), since a contact that took part of
the command would otherwise leave it up to twice as fast. A robot's centre therefore never
enters an obstacle, however thin (a zero-radius point obstacle or a zero-thickness wall included).

Only public pymunk API is used; ``pymunk.batch`` (reading and writing every body's
position and velocity in one call) is marked experimental by pymunk, hence ``pymunk<8``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pymunk
import pymunk.batch

from apf_physics.sim.bodies import SpaceBodies
from apf_physics.sim.contacts import (BodyLabels, ContactLog, Touching, contact_log, touching_depths,
                                      touching_pair_bytes)
from apf_physics.sim.freemove import CONTACT_MARGIN, FreeMoveTest, move_free
from apf_physics.sim.movers import MoverPool
from apf_physics.sim.placement import separate
from apf_physics.sim.proxies import ProxyPool
from apf_physics.sim.settle import Settler
from apf_physics.sim.slots import Slots
from apf_physics.sim.tiles import ANY_OBSTACLE, Tiles
from apf_physics.errors import UserError
from apf_physics.world.core import World
from apf_physics.world.kinematics import HOLONOMIC_SPEED, MAX_SUBSTEPS, physics_substeps, substeps_for

MAX_SPEED = HOLONOMIC_SPEED  # a diagonal unit move (±1, ±1) per control step [units per control step]
HASH_CELLS = (256, 1 << 15)
"""The fewest and the most cells of pymunk's spatial hash (:func:`hash_cells`)."""
NAMED_WITHIN = 0.05
"""A touched obstacle is one within the robot's radius and this much of where the step leaves it [units]."""
_COUNT_AT_MOST = 8  # up to this many robots in pymunk, count touching pairs by callbacks; more: read every substep

__all__ = ["CONTACT_MARGIN", "MAX_SPEED", "ContactLog", "Physics", "substeps_for"]


def hash_cells(pieces: int) -> int:
    """Cells of pymunk's spatial hash for a space of ``pieces`` static pieces (obstacles, a grid's
    boxes, walls): two per piece, within :data:`HASH_CELLS`.

    Chipmunk clears the whole table of its moving shapes at every substep, so every cell costs
    every substep (10,000 cells: about 10 µs, where 256 cells take 2 µs, the rest of a substep
    of one robot against a wall); too few cells and the static pieces crowd its buckets. Among
    3,573 boxes, one, two and four cells a piece cost chipmunk about the same; four a little more
    (``tools/bench_obstacles.py``). The count depends on the worlds
    alone, never on the number of robots: a robot alone and the same robot among a batch meet
    their obstacles in the same order.
    """
    return int(min(max(HASH_CELLS[0], 2 * pieces), HASH_CELLS[1]))


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
        self.slots = Slots(len(worlds), robots_per_slot, crowds)
        self.num_slots = self.slots.count
        self.robots_per_slot = self.slots.robots_per_slot
        self.num_robots = self.slots.num_robots
        self.crowd = self.slots.crowd
        self.present = self.slots.present
        """(N,) bool: robots that exist (a slot of a formation smaller than ``robots_per_slot`` has absent ones)."""
        self.control_dt = float(control_dt)
        self.max_speed = float(max_speed)
        every = list(worlds) + list(other_worlds)
        min_radius = min(w.robot_radius for w in every)
        obstacle_speed = max((w.obstacles[i].motion.speed for w in every for i in w.moving), default=0.0)
        if substeps is None:
            substeps = physics_substeps(min_radius, self.max_speed, obstacle_speed / self.control_dt,
                                        robots_meet=self.slots.meet)
            if substeps > MAX_SUBSTEPS:
                raise UserError(f"a robot of radius {min_radius:g} at up to {self.max_speed:g} units per step "
                                f"needs {substeps:,} physics substeps per step, over the limit of {MAX_SUBSTEPS}: "
                                f"a larger robot or a lower top speed")
        self.substeps = int(substeps)
        self.dt = self.control_dt / self.substeps

        self.space = pymunk.Space()
        self.space.iterations = 10
        # A spatial hash of cells about a robot's size: among thousands of small obstacles it finds a
        # robot's candidates faster than the default bounding-box tree (tools/bench_obstacles.py)
        # (sized to the static pieces once the tiles are made: _fit_hash)
        self.hash_dim = min(max(4.0 * min_radius, 0.5), 16.0)
        """Side of the spatial hash's cells [units]."""
        self.hash_cells = 0
        """Cells of pymunk's spatial hash (:func:`hash_cells` of the tiles' static pieces)."""
        # Chipmunk tolerates 0.1 of overlap by default; a robot resting against an obstacle with
        # that much overlap would sink past its boundary on the next push. Correct overlaps fully.
        self.space.collision_slop = 0.002
        # Forget a contact as soon as it ends: a proxy that moves to another robot must not
        # inherit the warm-start impulses of the contact it had before, and the arbiters read
        # after a substep are exactly the pairs touching then.
        self.space.collision_persistence = 1

        # Static geometry: one tile per (world, lane); lane 0 is shared by single-robot slots.
        # Each obstacle, wall and moving obstacle has a body of its own, labelled: an arbiter's
        # body ids then say what a robot touched.
        self._labels = BodyLabels()
        self._tiles = Tiles(self.space, self._labels)
        self._positions = np.zeros((self.num_robots, 2))
        self.worlds = self.slots.worlds
        self._any_moving = False
        # how far pymunk may take a robot in one step, its own move and pushes by others included (a
        # generous bound: twice the fastest move), for the free-move test of robots that meet others
        self.free = FreeMoveTest(self.slots, 2 * self.max_speed * self.control_dt)
        self.proxies = ProxyPool(self.space, self.num_robots)
        self.movers = MoverPool(self.space, self._labels)
        self.settler = Settler(self.space, self.proxies, self.slots, self.free, self._positions)
        self.bodies = SpaceBodies(self.space, self.proxies, self.movers)
        for s, world in enumerate(worlds):
            self._assign(s, world)
        self._fit_hash()

        self._arbiters = pymunk.batch.Buffer()
        self._touching = Touching(self.space, self._arbiters)
        self.count_at_most = _COUNT_AT_MOST
        """With at most this many robots in pymunk a step counts the contacts that begin and end (and
        reads the arbiters only after substeps in which shapes touch); with more it reads them after
        every substep (:class:`~apf_physics.sim.contacts.Touching`). Either way, the same contacts."""
        self._touch_free = ContactLog.nothing(self.num_robots)   # the log of a step without contacts
        self._depths = None   # the last substep's touching pairs, normals and distances (touching_depths)

    # -- worlds and tiles ------------------------------------------------------------------
    def _lane(self, slot: int, world: World) -> int:
        if self.slots.shared[slot]:
            return -1 - int(self.crowd[slot])    # the crowd's own tile
        return slot + 1 if self.robots_per_slot > 1 or world.moving else 0

    def _assign(self, slot: int, world: World) -> None:
        # a tile is the world's geometry: worlds that differ only in targets (several formations) share it
        key = (id(world.obstacles), self._lane(slot, world))
        if key not in self._tiles.index:
            # a chunk holds any robot's box of one step (its move, its radius and the margin around)
            reach = world.robot_radius + CONTACT_MARGIN + 0.5
            self._tiles.build(key, world, 2 * reach + self.max_speed * self.control_dt)
            self.bodies.tiles_grew = True
            if self.hash_cells:   # a tile made after the start (set_world)
                self._fit_hash()
        slots = self.slots
        slots.worlds[slot] = world
        self._any_moving = self._any_moving or bool(world.moving)   # stays set: moving obstacles were met
        slots.moving[slot] = bool(world.moving)
        slots.tile[slot] = self._tiles.index[key]
        slots.offset[slot] = self._tiles.offset[slots.tile[slot]]
        slots.radius[slot] = world.robot_radius
        self.free.assign(slot, world)

    def _fit_hash(self) -> None:
        """Size pymunk's spatial hash to the static pieces of every tile (:func:`hash_cells`); it
        only grows (re-hashing every shape)."""
        cells = hash_cells(self._tiles.piece_count)
        if cells > self.hash_cells:
            self.space.use_spatial_hash(self.hash_dim, cells)
            self.hash_cells = cells

    def _ensure_obstacles(self, robots: np.ndarray, v: np.ndarray) -> None:
        """Build the static obstacles near the moves of ``robots`` (commands ``v``, (N, 2) or one
        per substep) that are not built yet (:meth:`~apf_physics.sim.tiles.Tiles.build_near`)."""
        if self._tiles.complete:
            return   # every obstacle of every tile is built (small maps soon are)
        moves = (v.mean(axis=1) if v.ndim == 3 else v) * self.control_dt
        slots = robots // self.robots_per_slot
        p = self._positions[robots]
        reach = self.slots.radius[slots] + CONTACT_MARGIN + 0.5
        lo = np.minimum(p, p + moves[robots]) - reach[:, None]
        hi = np.maximum(p, p + moves[robots]) + reach[:, None]
        self._tiles.build_near(self.slots.tile[slots], lo, hi)

    def set_world(self, slot: int, world: World) -> None:
        """Put ``slot`` in ``world`` (its robots keep their coordinates until :meth:`place`)."""
        if world is self.worlds[slot]:
            return
        self.proxies.release(self.slots.robots(np.array([slot])))
        self._assign(slot, world)

    def _lend(self, robots: np.ndarray) -> None:
        """Lend proxies to ``robots`` (none holding one, sorted), placed where they are."""
        if not len(robots):
            return
        slots = robots // self.robots_per_slot
        self.proxies.lend(robots, self.slots.radius[slots], self.slots.solo(slots),
                          self._positions[robots] + self.slots.offset[slots])

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
        self.proxies.release(robots)
        self._positions[robots] = np.asarray(positions, dtype=float).reshape(-1, 2)
        m = self.robots_per_slot
        # One exact look-up for all: a robot clear of the static obstacles and the map's edge by
        # more than its radius in a world without moving ones needs no more checks.
        slots = robots // m
        doubtful = self.free.swept.near(self.free.map_of[robots], self._positions[robots],
                                         np.zeros((len(robots), 2)), self.slots.radius[slots] + 1e-6)
        doubtful |= self.slots.moving[slots]
        crowds = set(self.crowd[slots[doubtful]].tolist())
        if self.slots.meet:
            crowds |= set(self.crowd[slots].tolist())   # robots of one crowd may overlap one another
        for crowd in sorted(crowds):
            members = np.flatnonzero(self.crowd == crowd)
            mine = self.slots.robots(members)
            self._separate(int(members[0]), mine[self.present[mine]])

    def _separate(self, slot: int, mine: np.ndarray) -> None:
        """Robots ``mine`` (of one crowd, in ``slot``'s world) moved apart and off edges (:func:`separate`)."""
        self._positions[mine] = separate(self.worlds[slot], self._positions[mine], float(self.slots.time[slot]), mine)

    @property
    def positions(self) -> np.ndarray:
        """(N, 2) robot centres in each robot's own world coordinates."""
        return self._positions.copy()

    @property
    def in_pymunk(self) -> np.ndarray:
        """(N,) bool: robots that pymunk moved at the last step (they hold a proxy)."""
        return self.proxies.of_robot >= 0

    def needs_physics(self, moves: np.ndarray, bend: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: robots whose ``moves`` this step might bring them into contact with anything
        (:meth:`~apf_physics.sim.freemove.FreeMoveTest.needs`).

        ``bend``: (N,) how far each robot's path strays from its straight move at the same
        moment (a unicycle's arc; None: every path is straight). Every clearance is lowered by it.
        Moving obstacles are taken where the slots' steps (:meth:`set_time`) put them.
        """
        return self.free.needs(self._positions, moves, bend, self._any_moving)

    def set_time(self, steps: np.ndarray) -> None:
        """The control step each slot's episode is at (where its moving obstacles are)."""
        self.slots.time[:] = np.asarray(steps, float).reshape(self.num_slots)

    def step(self, velocities: np.ndarray, active: np.ndarray | None = None) -> ContactLog:
        """Advance one control step with a velocity command per robot.

        Args:
            velocities: (N, 2) commanded velocities in units per control step, held for the
                whole step; or (N, S, 2), one per substep (S = :attr:`substeps`): a unicycle
                robot driving an arc (:func:`~apf_physics.world.kinematics.substep_velocities`). Each
                is clipped to ``max_speed``.
            active: (N,) bool: the robots that take part (default all). The others are frozen
                where they are: they neither move nor touch anything (their slot's episode is over).

        Returns:
            The contacts seen during the step (read-only).
        """
        v = np.array(velocities, dtype=float)   # a copy: clipped in place
        movable = self.present if active is None else self.present & active
        if v.ndim == 3 or v.size != 2 * self.num_robots:   # a velocity per substep: unicycles driving arcs
            v = v.reshape(self.num_robots, self.substeps, 2)
            speed = np.hypot(v[..., 0], v[..., 1])
            if speed.max() > self.max_speed:
                v = v * np.minimum(1.0, self.max_speed / np.maximum(speed, 1e-300))[..., None]
            # the net move, and how far the substeps' path strays from the straight one at the same
            # moment (its largest at a substep's end: the distance between two uniform motions is convex)
            moves = v.mean(axis=1) * self.control_dt
            along = np.cumsum(v, axis=1) * (self.control_dt / self.substeps)
            stray = along - (np.arange(1, self.substeps + 1) / self.substeps)[None, :, None] * moves[:, None, :]
            simulate = self.needs_physics(moves, np.hypot(stray[..., 0], stray[..., 1]).max(axis=1))
            moved_free = False
        else:
            v = v.reshape(self.num_robots, 2)
            # one compiled pass: each command clipped to the top speed, the free-move test against the
            # static obstacles, and (where no robot meets another or a moving obstacle, so that the
            # test is final) the free robots moved
            moved_free = not self.slots.meet and not self._any_moving
            simulate, count = self.free.step(self._positions, v, self.max_speed, self.control_dt, self.substeps,
                                             self.slots.offset, movable, move=moved_free)
            if moved_free and not count and not self.proxies.lent:
                return self._touch_free   # nobody near anything: every robot moved, by the compiled pass
            if not moved_free:
                simulate = self.free.close(self._positions, v * self.control_dt, simulate, None, self._any_moving)
        simulate &= movable
        if not self.proxies.held and not np.count_nonzero(simulate):
            if not moved_free:
                self._move_free(np.flatnonzero(movable), v)
            return self._touch_free
        held = self.proxies.of_robot >= 0
        self.proxies.release(np.flatnonzero(held & ~simulate))
        self._lend(np.flatnonzero(simulate & ~held))
        robots = np.flatnonzero(simulate)
        if len(robots):
            self._ensure_obstacles(robots, v)
        if self._any_moving:
            self.movers.lend(self.free.movers_needed, self.slots.time, self.slots.offset, self.control_dt,
                             None if active is None else active.reshape(-1, self.robots_per_slot).any(axis=1))
        before = self._positions[robots].copy()
        # (proxies parked this step stay dirty, not lent, until pymunk next steps with robots in it)
        pairs = self._simulate(robots, v) if len(robots) else None
        if not moved_free:
            self._move_free(np.flatnonzero(movable & ~simulate), v)
        self.proxies.held = bool(len(robots))
        if pairs is None or not len(pairs):
            return self._touch_free
        log = self._log(pairs)
        undone = np.zeros(0, np.intp)
        pushed = log.robot[robots]   # only a robot that touched a robot can have been pushed faster than told
        if np.count_nonzero(pushed):
            undone = self.settler.undo_crossings(robots[pushed], before[pushed])
        self.settler.settle(self._depths, undone, robots, before)
        return log

    def _simulate(self, robots: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Step pymunk with the proxies of ``robots`` at their commanded velocities (the others at rest).

        Returns:
            (K, 2) body ids of the pairs that touched at some substep (a pair once per substep).
        """
        proxies = self.proxies.of_robot[robots]
        per_substep = v.ndim == 3   # a velocity per substep (unicycles driving arcs)
        self.bodies.write(proxies, (v[robots, 0] if per_substep else v[robots]) / self.control_dt)
        touched = []
        touching = self._touching
        touching.count(len(robots) <= self.count_at_most)   # robots in pymunk mostly touch something
        self._depths = None
        for k in range(self.substeps):
            if per_substep and k:   # steer: the command's change, on top of what contacts did to the velocity
                self.bodies.add_velocities(proxies, (v[robots, k] - v[robots, k - 1]) / self.control_dt,
                                           self.max_speed / self.control_dt)
            begun = touching.begun
            self.space.step(self.dt)
            if not touching.maybe:
                continue   # no shapes touch: no arbiters to read
            if k == self.substeps - 1:   # the last substep: how deep they touch too, for settling
                self._depths = touching_depths(self.space, self._arbiters)
                touched.append(self._depths[0].tobytes())
            elif touching.new_pairs(k == 0, begun):
                touched.append(touching_pair_bytes(self.space, self._arbiters))
        self.proxies.dirty[:] = False
        self._positions[robots] = self.bodies.positions(proxies) - self.slots.offset[robots // self.robots_per_slot]
        return np.frombuffer(b"".join(touched), np.uintp).reshape(-1, 2)

    def _move_free(self, robots: np.ndarray, v: np.ndarray) -> None:
        """Move ``robots`` as pymunk moves a free disc, to the bit (:func:`~apf_physics.sim.freemove.move_free`)."""
        move_free(self._positions, robots, self.slots.offset[robots // self.robots_per_slot], v, self.control_dt,
                  self.substeps)

    def _log(self, pairs: np.ndarray) -> ContactLog:
        """The contact log of the touching body-id pairs (a pair may come several times)."""
        return contact_log(pairs, self._labels, self.proxies.sorted_ids, self.proxies.order, self.proxies.robot,
                           self.num_robots, self._namer)

    def _namer(self):
        """Names the obstacles of a log's rows from where the robots stand now (the end of its step)."""
        positions = self._positions.copy()
        return lambda rows: self._name_obstacles(rows, positions)

    def _name_obstacles(self, rows: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """``rows`` with each touch of a tile's obstacles (:data:`~apf_physics.sim.tiles.ANY_OBSTACLE`)
        made a touch of every static obstacle of the robot's world that its disc is against where
        the step left it (within its radius and :data:`NAMED_WITHIN`), else of the nearest."""
        named = [rows[rows[:, 2] != ANY_OBSTACLE]]
        unknown = rows[rows[:, 2] == ANY_OBSTACLE]
        robots = unknown[:, 0]
        worlds = [self.worlds[s] for s in (robots // self.robots_per_slot).tolist()]
        for world in {id(w): w for w in worlds}.values():   # one query per world for all its robots
            mine = np.array([w is world for w in worlds])
            who, shape, d, _ = world.shapes.pairs(positions[robots[mine]], with_nearest=False)
            against = d <= world.robot_radius + NAMED_WITHIN
            nearest = np.full(int(mine.sum()), -1, np.intp)   # each robot's nearest shape, for those against none
            order = np.lexsort((d, who))
            first = order[np.r_[True, who[order][1:] != who[order][:-1]]] if len(who) else order
            nearest[who[first]] = shape[first]
            lonely = np.setdiff1d(np.arange(len(nearest)), who[against])
            k = np.concatenate([who[against], lonely])
            index = np.concatenate([shape[against], nearest[lonely]])
            known = index >= 0
            index[known] = world.static_numbers[index[known]]
            rows_of = unknown[mine][k]
            rows_of[:, 2] = np.where(known, index, ANY_OBSTACLE)   # (none within reach: unnamed)
            named.append(rows_of)
        return np.unique(np.concatenate(named), axis=0)
