"""Physics with pymunk: robots are discs among static obstacles and the map's walls.

The robots of many episodes ("slots") advance together: every control step takes one
velocity command per robot and returns a :class:`ContactLog` of what touched what, read
from pymunk's arbiters after every substep (:mod:`apf_physics.sim.contacts`). The physics
knows nothing of planners, observations or rewards.

**Where pymunk does the work.** A robot whose move this step provably cannot touch anything
moves exactly as pymunk would move a free disc (``p ← p + v·dt`` at each substep, the same
additions in the same order: :meth:`Physics._move_free`), without pymunk: the test is
the exact least distance between the segment its centre sweeps and its world's static shapes
and edge (:mod:`apf_physics.sim.swept`, compiled), and, for robots sharing a slot, the exact
closest approach of two linearly moving points. Every other robot
is simulated by pymunk through a *proxy*: a dynamic disc that is put in the robot's world,
moved by pymunk with the robot's velocity over fixed substeps, and read back. Proxies stay
with their robot while it keeps needing physics and are parked far away when it does not.
Robots in open space (most of them, most of the time) therefore cost pymunk nothing, and the
cost per robot-step does not grow with the number of robots.

**Tiles** (:mod:`apf_physics.sim.tiles`). Each world's walls are built once as static shapes in a
tile of the space, and its obstacles piece by piece (a grid's cells as boxes), in
:data:`~apf_physics.sim.tiles.CHUNK` squares, when a robot that needs physics first comes near: a
large map costs pymunk only where its robots go. Robots that are alone in their slot share
their world's tile: their proxies are in one collision group and never touch each other. Slots
of several robots (formations) get a tile each, so that their robots touch each other but never
another slot's.

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
from typing import Sequence

import numpy as np
import pymunk
import pymunk.batch

from apf_physics.sim.contacts import (FEW_PAIRS, MOVING, BodyLabels, CollisionType, ContactLog, Touching, body_robots,
                                  contact_log, contact_rows, contact_rows_few, deep_planes, touching_depths,
                                  touching_pair_bytes)
from apf_physics.sim.contacts import KINDS, Contact  # noqa: F401 (public here too)
from apf_physics.common.compiled import kernel
from apf_physics.errors import UserError
from apf_physics.sim.swept import Sweeps
from apf_physics.sim.tiles import Tiles, obstacle_shapes
from apf_physics.sim.tiles import CHUNK, TILE_GAP, WALL_THICKNESS  # noqa: F401 (public here too)
from apf_physics.world.core import World
from apf_physics.world.io.units import show_point

MAX_SPEED = math.sqrt(2.0)  # a diagonal unit move (±1, ±1) per control step [units per control step]
CONTACT_MARGIN = 0.01  # a move that keeps this much more than touching distance needs no physics [units]
_FEW = 4  # up to this many proxies, per-body attribute access beats pymunk.batch's fixed cost
_COUNT_AT_MOST = 8  # up to this many robots in pymunk, count touching pairs by callbacks; more: read every substep
_PROXY_GROUP = 1  # collision group of proxies of single-robot slots: they never touch each other
_SOLO_FILTER = pymunk.ShapeFilter(group=_PROXY_GROUP)   # queries about them: they are not there
SETTLE_OBSTACLE = 0.005  # a robot ending a step farther than this inside an obstacle or the edge is pushed out [units]
SETTLE_ROUNDS = 6  # rounds of pushes and queries before a robot still overlapping is put back (Physics._settle)
SETTLE_ROBOT = 0.01  # two robots ending a step overlapping more than this are pushed apart [units]
_BODY_FIELDS = pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.VELOCITY   # (or-ing pymunk's flags costs µs)


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
        if self.robots_per_slot > 1 or self._crowd_robots:
            relative = max(relative, 2 * self.max_speed)   # robots that meet close in on each other at twice the speed
        self.substeps = int(substeps) if substeps is not None else substeps_for(self._min_radius, relative)
        self.dt = self.control_dt / self.substeps
        # how far pymunk may take a robot in one step, its own move and pushes by others included (a
        # generous bound: twice the fastest move), for the free-move test of robots that meet others
        self._reach = 2 * self.max_speed * self.control_dt

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
        # Each obstacle, wall and moving obstacle has a body of its own, labelled: an arbiter's
        # body ids then say what a robot touched.
        self._labels = BodyLabels()
        self._tiles = Tiles(self.space, self._labels)
        # Moving obstacles: kinematic bodies, each built for one (world, obstacle), lent per step.
        self._mover_body: list[pymunk.Body] = []
        self._mover_key: list[tuple[int, int]] = []
        self._mover_target = np.zeros((0, 4))           # position and velocity before pymunk next steps
        self._slot_time = np.zeros(self.num_slots)
        self._positions = np.zeros((self.num_robots, 2))

        self.worlds: list[World] = [None] * self.num_slots  # type: ignore[list-item]
        self._slot_tile = np.zeros(self.num_slots, np.intp)
        self._slot_radius = np.zeros(self.num_slots)
        self._slot_moving = np.zeros(self.num_slots, bool)
        self._any_moving = False
        # per robot, for needs_physics(): its world's static geometry (exact swept distances) and
        # the distance its move must keep from it to need no physics
        self._sweeps = Sweeps()
        self._sweep_world = np.zeros(self.num_robots, np.intp)
        self._keep_off = np.zeros(self.num_robots)
        for s, world in enumerate(worlds):
            self._assign(s, world)

        # Proxies: dynamic discs lent to the robots that need physics this step.
        self._proxy_body: list[pymunk.Body] = []
        self._proxy_robot = np.zeros(0, np.intp)     # robot each proxy simulates, -1: parked
        self._proxy_dirty = np.zeros(0, bool)        # parked since pymunk last stepped; may carry solver state
        self._proxy_radius = np.zeros(0)
        self._proxy_solo = np.zeros(0, bool)          # in the collision group of proxies that never meet
        self._proxy_ids = np.zeros(0, np.uintp)      # their body ids
        self._proxy_order = np.zeros(0, np.intp)     # argsort of the ids
        self._proxy_of_id: dict[int, int] = {}        # the same as a dict
        self._proxy_target = np.zeros((0, 2))         # where a proxy is to be put before pymunk next steps
        self._proxy_parking = np.zeros((0, 2))        # where each waits when parked (_parking)
        self._proxy_moved = np.zeros(0, bool)         # ... for those that must be put there
        self._robot_proxy = np.full(self.num_robots, -1, np.intp)
        self._proxy_held = False                     # some robot holds a proxy
        self._alone = np.zeros(1, np.intp)            # the robots of a batch of one (_step_alone)
        self._buffer = pymunk.batch.Buffer()
        self._arbiters = pymunk.batch.Buffer()
        self._touching = Touching(self.space, self._arbiters)
        self._rows_dirty = True
        self._touch_free = ContactLog.nothing(self.num_robots)   # the log of a step without contacts
        self._movers_needed: list = []
        self._depths = None   # the last substep's touching pairs, normals and distances (touching_depths)

    # -- worlds and tiles ------------------------------------------------------------------
    def _lane(self, slot: int, world: World) -> int:
        if self._shared[slot]:
            return -1 - int(self.crowd[slot])    # the crowd's own tile
        return slot + 1 if self.robots_per_slot > 1 or world.moving else 0

    def _assign(self, slot: int, world: World) -> None:
        # a tile is the world's geometry: worlds that differ only in targets (several formations) share it
        key = (id(world.obstacles), self._lane(slot, world))
        if key not in self._tiles.index:
            # a chunk holds any robot's box of one step (its move, its radius and the margin around)
            reach = world.robot_radius + CONTACT_MARGIN + 0.5
            self._tiles.build(key, world, 2 * reach + self.max_speed * self.control_dt)
            self._rows_dirty = True
        self.worlds[slot] = world
        self._any_moving = self._any_moving or bool(world.moving)   # stays set: moving obstacles were met
        self._moving_slots = None
        self._slot_moving[slot] = bool(world.moving)
        self._slot_tile[slot] = self._tiles.index[key]
        self._slot_radius[slot] = world.robot_radius
        m = self.robots_per_slot
        self._sweep_world[m * slot:m * (slot + 1)] = self._sweeps.add(world)   # shared by worlds of one map
        self._keep_off[m * slot:m * (slot + 1)] = world.robot_radius + CONTACT_MARGIN

    def _ensure_obstacles(self, robots: np.ndarray, moves: np.ndarray) -> None:
        """Build the static obstacles near the moves of ``robots`` that are not built yet
        (:meth:`~apf_physics.sim.tiles.Tiles.build_near`)."""
        if self._tiles.complete:
            return   # every obstacle of every tile is built (small maps soon are)
        tiles = self._slot_tile[robots // self.robots_per_slot]
        p = self._positions[robots]
        reach = self._slot_radius[robots // self.robots_per_slot] + CONTACT_MARGIN + 0.5
        lo = np.minimum(p, p + moves[robots]) - reach[:, None]
        hi = np.maximum(p, p + moves[robots]) + reach[:, None]
        if self._tiles.build_near(tiles, lo, hi):
            self._rows_dirty = True

    def _new_mover(self, world: World, index: int) -> int:
        """A kinematic body shaped like moving obstacle ``index`` of ``world``, parked."""
        body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        shapes = obstacle_shapes(body, world.obstacles[index], (0.0, 0.0))
        for shape in shapes:
            shape.friction = 0.0
            shape.elasticity = 0.0
        k = len(self._mover_body)
        body.position = (4.0 * k, -2000.0)
        self.space.add(body, *shapes)
        self._mover_body.append(body)
        self._mover_key.append((id(world), index))
        self._mover_target = np.vstack([self._mover_target, [4.0 * k, -2000.0, 0.0, 0.0]])
        self._labels.add([(body, MOVING, index)])
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
            shape.filter = _SOLO_FILTER
        k = len(self._proxy_body)
        body.position = self._parking(k)
        self.space.add(body, shape)
        self._proxy_body.append(body)
        self._proxy_robot = np.append(self._proxy_robot, -1)
        self._proxy_dirty = np.append(self._proxy_dirty, False)
        self._proxy_radius = np.append(self._proxy_radius, radius)
        self._proxy_solo = np.append(self._proxy_solo, solo)
        self._proxy_ids = np.append(self._proxy_ids, np.uintp(body.id))
        self._proxy_order = np.argsort(self._proxy_ids)
        self._proxy_of_id[body.id] = k
        self._proxy_target = np.vstack([self._proxy_target, self._parking(k)])
        self._proxy_parking = np.vstack([self._proxy_parking, self._parking(k)])
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
        self._proxy_target[proxies] = self._proxy_parking[proxies]
        self._proxy_moved[proxies] = True
        self._robot_proxy[self._proxy_robot[proxies]] = -1
        self._proxy_robot[proxies] = -1
        self._proxy_dirty[proxies] = True

    def _lend(self, robots: np.ndarray) -> None:
        """Give each of ``robots`` (none holding one, sorted) a clean proxy of its radius and kind,
        placed where it is: the free proxies of each kind in order (:func:`_lend_free`), then new
        ones for those left, kind by kind."""
        if not len(robots):
            return
        slots = robots // self.robots_per_slot
        radius = self._slot_radius[slots]
        solo = ~self._shared[slots] & ~self._slot_moving[slots] & (self.robots_per_slot == 1)
        left = _lend_free(robots, radius, solo, self._proxy_robot, self._proxy_dirty, self._proxy_radius,
                          self._proxy_solo, self._robot_proxy)
        if len(left):   # the pool is short: new proxies, kind by kind in order (as the pool grew before)
            kinds = sorted(set(zip(radius[left].tolist(), solo[left].tolist())))
            for r, alone in kinds:
                for robot in robots[left][(radius[left] == r) & (solo[left] == alone)].tolist():
                    k = self._new_proxy(r, alone)
                    self._proxy_robot[k] = robot
                    self._robot_proxy[robot] = k
        proxies = self._robot_proxy[robots]
        self._proxy_target[proxies] = self._positions[robots] + self._tiles.offset[self._slot_tile[slots]]
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
        if self.num_robots == 1 and not self._any_moving and np.size(robots) == 1:   # a single env's resets, in floats
            (x, y), = np.asarray(positions, dtype=float).reshape(1, 2).tolist()
            if self._robot_proxy[0] >= 0:
                self._release(self._alone)
            self._positions[0] = (x, y)
            if self.present[0] and self._sweeps.near_one(int(self._sweep_world[0]), x, y, x, y,
                                                         float(self._slot_radius[0]) + 1e-6):
                self._separate(0, self._alone)
            return
        robots = np.asarray(robots, dtype=np.intp).ravel()
        self._release(robots)
        self._positions[robots] = np.asarray(positions, dtype=float).reshape(-1, 2)
        m = self.robots_per_slot
        # One exact look-up for all: a robot clear of the static obstacles and the map's edge by
        # more than its radius in a world without moving ones needs no more checks.
        slots = robots // m
        doubtful = self._sweeps.near(self._sweep_world[robots], self._positions[robots], np.zeros((len(robots), 2)),
                                     self._slot_radius[slots] + 1e-6)
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
            raise UserError(f"{world.label}: robot {int(mine[k])} placed at {show_point(world.frame, p[k])} has its "
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

    def needs_physics(self, moves: np.ndarray, bend: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: robots whose ``moves`` this step might bring them into contact with anything.

        ``bend``: (N,) how far each robot's path strays from its straight move at the same
        moment (a unicycle's arc; None: every path is straight). Every clearance is lowered by it.

        Conservative: False guarantees that the robot's disc keeps more than
        :data:`CONTACT_MARGIN` from every obstacle, the map's edge and the robots it meets
        during the whole move, so that it moves exactly as a free pymunk disc would. Against
        the robots it meets, this is judged against what they can do, not what they were told:
        the robots that go to pymunk are closed under "may touch one that goes to pymunk"
        (anywhere within a generous reach of its start: it may be blocked or pushed), and the
        others move straight and uniformly as commanded. Moving obstacles are taken where the
        slots' steps (:meth:`set_time`) put them.
        """
        # the exact least distance between each move and its world's static shapes and edge
        keep_off = self._keep_off if bend is None else self._keep_off + bend
        needs = self._sweeps.near(self._sweep_world, self._positions, moves, keep_off)
        m = self.robots_per_slot
        if m > 1:   # robots of one slot: closed under "may touch a robot that goes to pymunk"
            p = self._positions.reshape(-1, m, 2)
            dp = moves.reshape(-1, m, 2)
            present = self.present.reshape(-1, m)
            both_free, near_held = _may_touch(p, dp, self._slot_radius[:, None, None], present, self._reach,
                                              None if bend is None else bend.reshape(-1, m))
            needs = _close_under_touch(needs.reshape(-1, m), both_free, near_held).ravel()
        for group in self._crowd_robots:   # robots of several slots that meet: the same over the crowd
            group = group[self.present[group]]
            radius = self._slot_radius[group // m][None, :, None]
            both_free, near_held = _may_touch(self._positions[group][None], moves[group][None], radius,
                                              np.ones((1, len(group)), bool), self._reach,
                                              None if bend is None else bend[group][None])
            needs[group] = _close_under_touch(needs[group][None], both_free, near_held)[0]
        if not self._any_moving:
            return needs
        self._movers_needed = []
        for slots, world, index, near in self._near_movers(moves, bend):
            robots = (slots[:, None] * m + np.arange(m)).ravel()
            needs[robots] |= near.ravel()
            self._movers_needed.append((world, index, slots, near.any(axis=1)))
        return needs

    def set_time(self, steps: np.ndarray) -> None:
        """The control step each slot's episode is at (where its moving obstacles are)."""
        self._slot_time = np.asarray(steps, float).reshape(self.num_slots)

    def _near_movers(self, moves: np.ndarray, bend: np.ndarray | None = None):
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
            if bend is not None:
                reach = reach + bend.reshape(-1, m)[slots][..., None]
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
            velocities: (N, 2) commanded velocities in units per control step, held for the
                whole step; or (N, S, 2), one per substep (S = :attr:`substeps`): a unicycle
                robot driving an arc (:func:`~apf_physics.world.kinematics.substep_velocities`). Each
                is clipped to ``max_speed``.
            active: (N,) bool: the robots that take part (default all). The others are frozen
                where they are: they neither move nor touch anything (their slot's episode is over).

        Returns:
            The contacts seen during the step (read-only).
        """
        v = np.asarray(velocities, dtype=float)
        if self.num_robots == 1 and not self._any_moving and active is None and v.size == 2:
            log = self._step_alone(v)
            if log is not None:
                return log
        per_substep = v.ndim == 3
        if per_substep:
            v = v.reshape(self.num_robots, self.substeps, 2)
            speed = np.hypot(v[..., 0], v[..., 1])
            if speed.max() > self.max_speed:
                v = v * np.minimum(1.0, self.max_speed / np.maximum(speed, 1e-300))[..., None]
            # the net move, and how far the substeps' path strays from the straight one at the same
            # moment (its largest at a substep's end: the distance between two uniform motions is convex)
            moves = v.mean(axis=1) * self.control_dt
            along = np.cumsum(v, axis=1) * (self.control_dt / self.substeps)
            stray = along - (np.arange(1, self.substeps + 1) / self.substeps)[None, :, None] * moves[:, None, :]
            bend = np.hypot(stray[..., 0], stray[..., 1]).max(axis=1)
        else:
            v = v.reshape(self.num_robots, 2)
            speed = np.hypot(v[:, 0], v[:, 1])
            if speed.max() > self.max_speed:
                too_fast = speed > self.max_speed
                v = v.copy()
                v[too_fast] *= (self.max_speed / speed[too_fast])[:, None]
            moves = v * self.control_dt
            bend = None
        simulate = self.needs_physics(moves, bend) & self.present
        if active is not None:
            simulate &= active
            moves = moves * active[:, None]
        if not self._proxy_held and not simulate.any():
            self._move_free(np.flatnonzero(self.present if active is None else self.present & active), v)
            return self._touch_free
        held = self._robot_proxy >= 0
        self._release(np.flatnonzero(held & ~simulate))
        self._lend(np.flatnonzero(simulate & ~held))
        robots = np.flatnonzero(simulate)
        if len(robots):
            self._ensure_obstacles(robots, moves)
        self._lend_movers(active)
        before = self._positions[robots].copy()
        # (proxies parked this step stay dirty, not lent, until pymunk next steps with robots in it)
        pairs = self._simulate(robots, v) if len(robots) else None
        free = ~simulate & self.present
        self._move_free(np.flatnonzero(free if active is None else free & active), v)
        self._proxy_held = bool(len(robots))
        if pairs is None or not len(pairs):
            return self._touch_free
        log = self._log(pairs)
        undone = np.zeros(0, np.intp)
        pushed = log.robot[robots]   # only a robot that touched a robot can have been pushed faster than told
        if pushed.any():
            undone = self._undo_crossings(robots[pushed], before[pushed])
        self._settle(undone, robots, before)
        return log

    def _settle(self, undone: np.ndarray, simulated: np.ndarray, before: np.ndarray) -> None:
        """Resolve, before the step ends, the overlaps that pymunk leaves at its last substep.

        Chipmunk finds an overlap after the substep that made it and pushes it out in the
        substeps after: a robot that met an obstacle in the last substep ends the step up to
        one substep's travel inside it, and robots that met each other up to twice that. The
        arbiters of the last substep say how deep each pair overlaps and along which normal
        (:func:`~apf_physics.sim.contacts.touching_depths`); :func:`_project_out` moves the
        robots out of each other and of the static shapes by exactly that much (0.001 more),
        whenever an overlap exceeds :data:`SETTLE_OBSTACLE` (obstacles, moving obstacles and
        the map's edge) or :data:`SETTLE_ROBOT` (two robots). The proxies follow. Robots alone
        in their slots (most of them) are settled one by one in plain floats by the same rule
        (:meth:`_settle_alone`).

        ``undone``: robots put back where they started the step (:meth:`_undo_crossings`): what
        they overlap there is asked of pymunk (:meth:`_overlaps_at`) instead.

        A robot that pymunk wedged between two shapes nearly facing each other (a narrow V)
        would take the pushes many rounds to leave; after :data:`SETTLE_ROUNDS` it is put back
        where it started the step (``before``, of ``simulated``: where the step before left it).
        """
        if self._depths is None and not len(undone):
            return
        ids, normal, distance = self._depths if self._depths is not None else (np.zeros((0, 2)), np.zeros((0, 2)),
                                                                               np.zeros(0))
        alone, first, planes, deep = deep_planes(ids, normal, distance, min(SETTLE_OBSTACLE, SETTLE_ROBOT),
                                                 self._proxy_ids, self._proxy_order, self._proxy_robot,
                                                 self._proxy_solo)
        if len(alone):   # robots alone in their slots (most of them): _settle_alone
            self._settle_alone(alone, first, planes, simulated, before)
        if not len(deep) and not len(undone):
            return
        # a robot and a static shape: the robot's way out is against the normal if it is a, along it if b
        robot, _ = body_robots(ids[deep], self._proxy_ids, self._proxy_order, self._proxy_robot)
        normal, depth = normal[deep], -distance[deep]
        both = (robot[:, 0] >= 0) & (robot[:, 1] >= 0)
        pair_robots = robot[both].astype(np.intp)
        first_side = robot[:, 0] >= 0
        one = ~both
        r = np.where(first_side, robot[:, 0], robot[:, 1])[one].astype(np.intp)
        out = normal[one] * np.where(first_side[one], -1.0, 1.0)[:, None]
        rest = ~np.isin(r, undone) if len(undone) else np.ones(len(r), bool)
        static_robot, static_normal, static_depth = r[rest], out[rest], depth[one][rest]
        if not len(static_robot) and not len(pair_robots) and not len(undone):
            return
        if len(undone):
            more_robot, more_normal, more_depth, more_pairs = self._overlaps_at(undone)
            static_robot = np.concatenate([static_robot, more_robot])
            static_normal = np.concatenate([static_normal, more_normal])
            static_depth = np.concatenate([static_depth, more_depth])
            pair_robots = np.concatenate([pair_robots, more_pairs])
        anchor = self._positions[static_robot]
        m = self.robots_per_slot
        for round_ in range(2 * SETTLE_ROUNDS):
            if round_ == SETTLE_ROUNDS:   # still overlapping: back to the step's start, and what is there
                back = still[np.isin(still, simulated)]
                self._positions[back] = before[np.searchsorted(simulated, back)]
                self._proxy_target[self._robot_proxy[back]] = (self._positions[back]
                                                               + self._tiles.offset[self._slot_tile[back // m]])
                self._proxy_moved[self._robot_proxy[back]] = True
                static_robot, static_normal, static_depth, pair_robots = self._overlaps_at(back)
                anchor = self._positions[static_robot]
            involved = self._with_mates(np.unique(np.concatenate([static_robot, pair_robots.ravel()])))
            slots = involved // m
            group = np.where(self._shared[slots], self.crowd[slots] - self.crowd.min(), -1 - slots)   # who meets whom
            p = _project_out(self._positions[involved], self._slot_radius[slots], np.searchsorted(involved, static_robot),
                             anchor, static_normal, static_depth, group)
            moved = np.any(p != self._positions[involved], axis=1)
            robots = involved[moved]
            if not len(robots):
                return
            self._positions[robots] = p[moved]
            proxies = self._robot_proxy[robots]   # only robots that pymunk moved touch anything
            self._proxy_target[proxies] = p[moved] + self._tiles.offset[self._slot_tile[robots // m]]
            self._proxy_moved[proxies] = True
            # a robot pushed out of one shape may have been pushed into another: ask pymunk again, and
            # keep the shapes already met (a robot in a corner settles against both sides at once)
            more_robot, more_normal, more_depth, more_pairs = self._overlaps_at(robots)
            if not len(more_robot) and not len(more_pairs):
                return
            still = np.unique(np.concatenate([more_robot, more_pairs.ravel()]))
            pair_robots = np.concatenate([pair_robots, more_pairs])
            static_robot = np.concatenate([static_robot, more_robot])
            anchor = np.concatenate([anchor, self._positions[more_robot]])
            static_normal = np.concatenate([static_normal, more_normal])
            static_depth = np.concatenate([static_depth, more_depth])

    def _settle_alone(self, robots: np.ndarray, first: np.ndarray, planes: np.ndarray, simulated: np.ndarray,
                      before: np.ndarray) -> None:
        """:meth:`_settle` for robots alone in their slots (a robot alone meets no robot, and there
        are a few a step), by the rule of :meth:`~apf_physics.sim.swept.Sweeps.settle`, compiled: each
        is pushed out of the shape it overlaps most until none by more than
        :data:`SETTLE_OBSTACLE`, then the static shape nearest its centre is looked up (in the
        world's exact geometry, the shapes pymunk has); one overlapped is added, and so on; after
        :data:`SETTLE_ROUNDS` a robot still overlapping goes back to where it started the step.

        ``robots`` (R,) sorted, ``first`` (R + 1,), ``planes`` (K, 3): robot ``robots[i]``'s
        overlaps with static shapes at the last substep are ``planes[first[i]:first[i + 1]]``,
        each ``(way out x, y, depth)`` (:func:`~apf_physics.sim.contacts.deep_planes`).
        """
        slots = robots // self.robots_per_slot
        p = self._sweeps.settle(self._sweep_world[robots], self._positions[robots],
                                before[np.searchsorted(simulated, robots)], self._slot_radius[slots], first,
                                planes, SETTLE_OBSTACLE, SETTLE_ROUNDS)
        self._positions[robots] = p
        proxies = self._robot_proxy[robots]
        self._proxy_target[proxies] = p + self._tiles.offset[self._slot_tile[slots]]
        self._proxy_moved[proxies] = True

    def _with_mates(self, robots: np.ndarray) -> np.ndarray:
        """``robots`` and every robot that pymunk moved this step and that meets one of them (its
        slot's robots, its crowd's), sorted: robots pushed apart are pushed among all they meet."""
        m = self.robots_per_slot
        if m == 1 and not self._crowd_robots:
            return robots
        held = np.flatnonzero(self._robot_proxy >= 0)
        slots, held_slots = robots // m, held // m
        crowds = self.crowd[slots[self._shared[slots]]]
        mates = np.isin(held_slots, slots) | (self._shared[held_slots] & np.isin(self.crowd[held_slots], crowds))
        return np.union1d(robots, held[mates])

    def _overlaps_at(self, robots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the proxies of ``robots`` (robots that meet others), put where the robots are now,
        overlap by more than the settling tolerances (pymunk's shape queries): ``(robot (K,), way
        out (K, 2), depth (K,), pairs of robots (L, 2))``, as :meth:`_settle` reads them from the
        arbiters."""
        static_robot, static_normal, static_depth, pairs = [], [], [], []
        proxies = self._robot_proxy[robots]
        bodies = [self._proxy_body[k] for k in proxies.tolist()]
        for body, (x, y) in zip(bodies, self._proxy_target[proxies].tolist()):
            body.position = (x, y)
            self.space.reindex_shapes_for_body(body)
        tolerance = min(SETTLE_OBSTACLE, SETTLE_ROBOT)
        for robot, body in zip(robots.tolist(), bodies):
            for info in self.space.shape_query(next(iter(body.shapes))):
                points = info.contact_point_set.points
                if not points or points[0].distance >= -tolerance:
                    continue
                other = self._proxy_of_id.get(info.shape.body.id)
                if other is None:   # a static shape (or a moving obstacle): out against the normal
                    normal = info.contact_point_set.normal
                    static_robot.append(robot)
                    static_normal.append((-normal.x, -normal.y))
                    static_depth.append(-points[0].distance)
                elif self._proxy_robot[other] >= 0:
                    pairs.append((robot, int(self._proxy_robot[other])))
        return (np.array(static_robot, np.intp), np.array(static_normal, float).reshape(-1, 2),
                np.array(static_depth, float), np.array(pairs, np.intp).reshape(-1, 2))

    def _undo_crossings(self, robots: np.ndarray, before: np.ndarray) -> np.ndarray:
        """Put back any of ``robots`` whose move this step passed through a static obstacle.

        The substeps keep a robot's own move from tunnelling, but robots that touch each other
        (a formation, a crowd: ``robots`` are those that touched a robot) can push one another
        faster than they were commanded, and the
        solver's pushes are not bounded. An exact check of each moved segment against the
        static obstacles (sampled every half radius: a segment through even a zero-thickness
        wall has a sample within a quarter radius of it, which no allowed move comes near)
        finds such a crossing; the robot then stays where it was, against the obstacle.

        Returns:
            The robots put back.
        """
        after = self._positions[robots]
        slots = robots // self.robots_per_slot
        undone = []
        for slot in np.unique(slots).tolist():
            world = self.worlds[slot]
            mine = np.flatnonzero(slots == slot)
            r = world.robot_radius
            clear = world.path_clearance(before[mine], after[mine], 0.5 * r)
            crossed = mine[clear < 0.5 * r]
            if not len(crossed):
                continue
            undone.append(robots[crossed])
            self._positions[robots[crossed]] = before[crossed]
            proxies = self._robot_proxy[robots[crossed]]
            self._proxy_target[proxies] = before[crossed] + self._tiles.offset[self._slot_tile[slots[crossed]]]
            self._proxy_moved[proxies] = True
        return np.concatenate(undone) if undone else np.zeros(0, np.intp)

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
            self._mover_target[movers, :2] = start + self._tiles.offset[self._slot_tile[slots]]
            self._mover_target[movers, 2:] = (motion.offset(t + 1.0) - start) / self.control_dt

    def _simulate(self, robots: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Step pymunk with the proxies of ``robots`` at their commanded velocities (the others at rest).

        Returns:
            (K, 2) body ids of the pairs that touched at some substep (a pair once per substep).
        """
        if self._rows_dirty:
            self._index_rows()
        proxies = self._robot_proxy[robots]
        per_substep = v.ndim == 3   # a velocity per substep (unicycles driving arcs)
        commanded = (v[robots, 0] if per_substep else v[robots]) / self.control_dt
        moved = np.flatnonzero(self._proxy_moved)
        few = len(self._proxy_body) <= _FEW and not self._mover_body
        if few:   # body by body, on Python floats: the moved put where they are to be, the rest at rest
            bodies, target = self._proxy_body, self._proxy_target
            for k in moved.tolist():
                bodies[k].position = tuple(target[k].tolist())
            velocity = dict(zip(proxies.tolist(), map(tuple, commanded.tolist())))
            for k, body in enumerate(bodies):
                body.velocity = velocity.get(k, (0.0, 0.0))
        else:
            velocity = np.zeros((len(self._proxy_body), 2))
            velocity[proxies] = commanded
            # every body's position and velocity in one read and one write (static bodies are
            # rows too: they are written back as they were read)
            fields = _BODY_FIELDS
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
        touching = self._touching
        touching.count(len(robots) <= _COUNT_AT_MOST)   # robots in pymunk mostly touch something
        self._depths = None
        for k in range(self.substeps):
            if per_substep and k:   # steer: the command's change, on top of what contacts did to the velocity
                self._add_velocities(proxies, (v[robots, k] - v[robots, k - 1]) / self.control_dt)
            begun = touching.begun
            self.space.step(self.dt)
            if not touching.maybe:
                continue   # no shapes touch: no arbiters to read
            if k == self.substeps - 1:   # the last substep: how deep they touch too, for _settle
                self._depths = touching_depths(self.space, self._arbiters)
                touched.append(self._depths[0].tobytes())
            elif touching.new_pairs(k == 0, begun):
                touched.append(touching_pair_bytes(self.space, self._arbiters))
        self._proxy_dirty[:] = False
        offsets = self._tiles.offset[self._slot_tile[robots // self.robots_per_slot]]
        if few:
            for robot, k, (ox, oy) in zip(robots.tolist(), proxies.tolist(), offsets.tolist()):
                x, y = self._proxy_body[k].position
                self._positions[robot] = (x - ox, y - oy)
        else:
            buf = self._buffer
            buf.clear()
            pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.POSITION, buf)
            after = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 2)[self._row_of_proxy[proxies]]
            self._positions[robots] = after - offsets
        return np.frombuffer(b"".join(touched), np.uintp).reshape(-1, 2)

    def _step_alone(self, v: np.ndarray) -> ContactLog | None:
        """:meth:`step` for one robot moving straight among static obstacles: the array path's
        operations, in the same order, without its arrays' fixed costs (``tests/test_physics.py``
        checks that both paths give the same steps to the bit). A move that comes near nothing is
        done on Python floats; one that does goes to pymunk as the array path sends it, less the
        free-move test (done here) and the bookkeeping of the robots that do not go.

        Returns:
            The step's contacts; None (nothing done) when the robot is absent or its command
            exceeds the top speed: the array path takes it.
        """
        vx, vy = v.reshape(2).tolist()
        if not self.present[0] or np.hypot(vx, vy) > self.max_speed:
            return None
        x, y = self._positions[0].tolist()
        dt, control = self.dt, self.control_dt
        if self._sweeps.near_one(int(self._sweep_world[0]), x, y, x + vx * control, y + vy * control,
                                 float(self._keep_off[0])):
            return self._simulate_alone(v.reshape(1, 2))
        if self._proxy_held:   # it went to pymunk last step: its proxy goes back to the parking
            self._release(self._alone)
            self._proxy_held = False
        ox, oy = self._tiles.offset[self._slot_tile[0]].tolist()
        vx, vy = vx / control, vy / control
        x, y = x + ox, y + oy
        for _ in range(self.substeps):   # as _free_moves
            x, y = x + vx * dt, y + vy * dt
        self._positions[0] = (x - ox, y - oy)
        return self._touch_free

    def _simulate_alone(self, v: np.ndarray) -> ContactLog:
        """The rest of :meth:`step` for one robot alone whose move needs pymunk (``v`` (1, 2))."""
        robots = self._alone
        if self._robot_proxy[0] < 0:
            self._lend(robots)
        self._ensure_obstacles(robots, v * self.control_dt)
        before = self._positions[robots].copy()
        pairs = self._simulate(robots, v)
        self._proxy_held = True
        if not len(pairs):
            return self._touch_free
        log = self._log(pairs)
        self._settle(robots[:0], robots, before)   # (a robot alone touches no robot: none is put back)
        return log

    def _move_free(self, robots: np.ndarray, v: np.ndarray) -> None:
        """Move ``robots`` as pymunk moves a free disc, to the bit: put where the robot's proxy
        would be (its position plus its tile's offset), advanced by its velocity times the
        substep's duration at each substep (chipmunk's ``p ← p + v·dt``, a velocity per
        substep changing as :meth:`_add_velocities` changes it), read back less the offset. A
        robot's path therefore does not depend on whether it went to pymunk this step."""
        if not len(robots):
            return
        offset = self._tiles.offset[self._slot_tile[robots // self.robots_per_slot]]
        if v.ndim == 3:   # a velocity per substep: the first, then each change added (_simulate)
            velocity = np.empty((len(robots), self.substeps, 2))
            velocity[:, 0] = v[robots, 0] / self.control_dt
            for k in range(1, self.substeps):
                velocity[:, k] = velocity[:, k - 1] + (v[robots, k] - v[robots, k - 1]) / self.control_dt
        else:   # one for every substep
            velocity = (v[robots] / self.control_dt)[:, None, :]
        _free_moves(self._positions, robots, offset, velocity, self.dt, self.substeps)

    def _add_velocities(self, proxies: np.ndarray, change: np.ndarray) -> None:
        """Add ``change`` to the velocities of the bodies of ``proxies`` (between substeps), leaving
        everything else as it is. A free body then moves at its new command; one that a contact
        slowed keeps what the contact took (as a holonomic robot keeps it for the whole step)."""
        if len(proxies) <= _FEW:
            for k, (dx, dy) in zip(proxies.tolist(), change.tolist()):
                body = self._proxy_body[k]
                vx, vy = body.velocity
                body.velocity = (vx + dx, vy + dy)
            return
        fields = _BODY_FIELDS
        buf = self._buffer
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, fields, buf)
        rows = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 4).copy()
        rows[self._row_of_proxy[proxies], 2:] += change
        write = pymunk.batch.Buffer()
        write.set_float_buf(rows.reshape(-1))
        pymunk.batch.set_space_bodies(self.space, fields, write)

    def _log(self, pairs: np.ndarray) -> ContactLog:
        """The contact log of the touching body-id pairs (a pair may come several times)."""
        return contact_log(self._contact_rows_few(pairs) if len(pairs) <= FEW_PAIRS else self._contact_rows(pairs),
                           self.num_robots)

    def _contact_rows_few(self, pairs: np.ndarray) -> np.ndarray:
        """:func:`~apf_physics.sim.contacts.contact_rows_few` of the touching body-id pairs."""
        return contact_rows_few(pairs, self._labels, self._proxy_of_id, self._proxy_robot)

    def _contact_rows(self, pairs: np.ndarray) -> np.ndarray:
        """(K, 3) sorted distinct rows ``(robot, kind, other)`` of the touching body-id pairs."""
        return contact_rows(pairs, self._labels, self._proxy_ids, self._proxy_order, self._proxy_robot)


@kernel
def _lend_free(robots, radius, solo, proxy_robot, proxy_dirty, proxy_radius, proxy_solo, robot_proxy):
    """Lend ``robots`` (sorted) the parked clean proxies of their kind (radius and ``solo``), each
    kind's in order of index, writing ``proxy_robot`` and ``robot_proxy``.

    Returns:
        The indices (into ``robots``) of those left without one, in order.
    """
    left = np.empty(len(robots), np.int64)
    count = 0
    cursor = np.zeros(len(robots), np.int64)   # per robot's kind (its first robot): the next proxy to try
    kind = np.empty(len(robots), np.int64)
    for i in range(len(robots)):
        kind[i] = i
        for j in range(i):
            if radius[j] == radius[i] and solo[j] == solo[i]:
                kind[i] = kind[j]
                break
        k = cursor[kind[i]]
        while k < len(proxy_robot) and not (proxy_robot[k] < 0 and not proxy_dirty[k] and proxy_radius[k] == radius[i]
                                            and proxy_solo[k] == solo[i]):
            k += 1
        if k < len(proxy_robot):
            proxy_robot[k] = robots[i]
            robot_proxy[robots[i]] = k
            cursor[kind[i]] = k + 1
        else:
            cursor[kind[i]] = k
            left[count] = i
            count += 1
    return left[:count].copy()


@kernel
def _free_moves(positions, robots, offset, velocity, dt, substeps):
    """:meth:`Physics._move_free`'s arithmetic: in place, robot ``robots[k]`` from its position
    plus ``offset[k]``, ``p ← p + velocity[k, s]·dt`` for each of the substeps ``s`` (``velocity``
    (K, substeps, 2), or (K, 1, 2): the same at every substep), less the offset."""
    last = velocity.shape[1] - 1
    for k in range(robots.shape[0]):
        r = robots[k]
        x, y = positions[r, 0] + offset[k, 0], positions[r, 1] + offset[k, 1]
        for s in range(substeps):
            x = x + velocity[k, min(s, last), 0] * dt
            y = y + velocity[k, min(s, last), 1] * dt
        positions[r, 0], positions[r, 1] = x - offset[k, 0], y - offset[k, 1]


def _closest_approach(p: np.ndarray, dp: np.ndarray) -> np.ndarray:
    """(S, m, m) least distance between robots i and j of each slot moving by ``dp`` over the step."""
    r0 = p[:, :, None, :] - p[:, None, :, :]
    dr = dp[:, :, None, :] - dp[:, None, :, :]
    a = np.sum(dr * dr, axis=-1)
    t = np.clip(np.where(a > 0, -np.sum(r0 * dr, axis=-1) / np.where(a > 0, a, 1.0), 0.0), 0.0, 1.0)
    closest = r0 + t[..., None] * dr
    return np.sqrt(np.sum(closest * closest, axis=-1))


def _segment_point_distance(p: np.ndarray, dp: np.ndarray) -> np.ndarray:
    """(S, m, m) least distance between robot i's straight move and robot j's start, in each slot."""
    r0 = p[:, None, :, :] - p[:, :, None, :]                      # from i's start to j's
    a = np.sum(dp * dp, axis=-1)[:, :, None]
    t = np.clip(np.sum(r0 * dp[:, :, None, :], axis=-1) / np.where(a > 0, a, 1.0), 0.0, 1.0)
    closest = r0 - t[..., None] * dp[:, :, None, :]
    return np.sqrt(np.sum(closest * closest, axis=-1))


def _may_touch(p: np.ndarray, dp: np.ndarray, radius: np.ndarray, present: np.ndarray,
               reach: float, bend: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Which robots of each slot may touch which, both ``(S, m, m)`` bool (never i with itself,
    never an absent robot):

    - ``both_free[s, i, j]``: if both move as commanded (straight and uniformly), they come
      within touching distance and the margin;
    - ``near_held[s, i, j]``: robot i's commanded move comes that near anywhere robot j could
      be if pymunk moved it (within ``reach`` of its start, however it was blocked or pushed).

    ``bend`` (S, m): how far each robot's path strays from its straight move (None: not at
    all); the two robots' strays widen the touching distance.
    """
    touch = 2 * radius + CONTACT_MARGIN
    if bend is not None:
        touch = touch + bend[:, :, None] + bend[:, None, :]
    both_free = _closest_approach(p, dp) < touch
    near_held = _segment_point_distance(p, dp) < touch + reach
    others = present[:, None, :] & present[:, :, None] & ~np.eye(p.shape[1], dtype=bool)[None]
    return both_free & others, near_held & others


def _close_under_touch(needs: np.ndarray, both_free: np.ndarray, near_held: np.ndarray) -> np.ndarray:
    """(S, m) the robots that go to pymunk: those that ``needs`` already, those that may touch
    another one moving as commanded, and then every robot that may touch one of these, until
    none is added (at most m rounds). A robot left out moves exactly as commanded and nothing
    that pymunk moves can reach it."""
    needs = needs | both_free.any(axis=2)
    while True:
        more = needs | np.any(near_held & needs[:, None, :], axis=2)
        if (more == needs).all():
            return needs
        needs = more


def _project_out(p: np.ndarray, radius: np.ndarray, static_robot: np.ndarray, anchor: np.ndarray,
                 static_normal: np.ndarray, static_depth: np.ndarray, group: np.ndarray, rounds: int = 20) -> np.ndarray:
    """Robots at ``p`` moved out of the static shapes and each other that they overlap.

    Args:
        p: (n, 2) positions; ``radius`` (n,) their radii.
        static_robot, anchor, static_normal, static_depth: (K,) a robot overlapping a static shape,
            where it was then, its way out (unit) and how deep; the shape's boundary is taken as
            the plane there.
        group: (n,) robots of one group meet each other (their overlaps are measured from ``p``).

    Each round first pushes every pair of a group that overlaps by more than
    :data:`SETTLE_ROBOT` apart, half each along the line of centres (0.001 beyond touching), and
    then every robot that overlaps a shape by more than :data:`SETTLE_OBSTACLE` out of the one it
    overlaps most (0.001 beyond its boundary), until none does. A round thus ends with every
    robot on the free side of the shape it overlapped most (a robot that a pair pushed into a
    wall is pushed back, and the pair's overlap goes to the other robot in the next rounds), and
    no robot is taken farther than half its radius from where it was by pairs (what it is
    pushed into is then found by the caller's next query, before its centre could reach it). A
    robot alone in its group is settled only by its own overlaps: the same in a batch as on its
    own.
    """
    start = p
    p = p.copy()
    n = len(p)
    i = j = np.zeros(0, np.intp)
    if len(np.unique(group)) < n:   # robots that meet: the pairs of a group near enough to overlap in this call
        diff = p[:, None, :] - p[None, :, :]
        near = np.hypot(diff[..., 0], diff[..., 1]) < radius[:, None] + radius[None, :] + 2 * radius.max()
        i, j = np.nonzero(np.triu(near & (group[:, None] == group[None, :]), 1))
    for _ in range(rounds):
        moved = False
        if len(i):
            diff = p[i] - p[j]
            d = np.hypot(diff[:, 0], diff[:, 1])
            overlap = radius[i] + radius[j] - d
            apart = overlap > SETTLE_ROBOT
            if apart.any():
                half = 0.5 * (overlap[apart] + 1e-3)[:, None] * diff[apart] / np.maximum(d[apart], 1e-9)[:, None]
                push = np.zeros_like(p)
                np.add.at(push, i[apart], half)
                np.add.at(push, j[apart], -half)
                away = p + push - start
                far = np.hypot(away[:, 0], away[:, 1])
                p = start + away * np.minimum(1.0, 0.5 * radius / np.maximum(far, 1e-12))[:, None]
                moved = True
        if len(static_robot):
            depth = static_depth - np.sum(static_normal * (p[static_robot] - anchor), axis=1)
            # each robot's deepest shape: the first of its rows sorted by robot, then by depth, deepest first
            order = np.lexsort((-depth, static_robot))
            deepest = order[np.concatenate([[True], np.diff(static_robot[order]) != 0])]
            deepest = deepest[depth[deepest] > SETTLE_OBSTACLE]
            if len(deepest):
                p[static_robot[deepest]] += (depth[deepest] + 1e-3)[:, None] * static_normal[deepest]
                moved = True
        if not moved:
            break
    return p
