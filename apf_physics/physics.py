"""Physics with pymunk: robots are dynamic discs among static obstacles and the map's walls.

Several worlds ("slots") can share one pymunk space, tiled side by side, so that a whole
batch of environments advances with one ``space.step`` per substep. Every control step
takes one velocity command per robot and advances ``substeps`` fixed substeps; contacts
are recorded by collision callbacks into a :class:`ContactLog` that the caller reads after
the step. The physics knows nothing of planners or rewards.

Tunnelling: Chipmunk detects overlaps, not swept contacts, so a disc moving ``δ`` per
substep can sink at most ``δ`` into an obstacle before the solver pushes it out. The
substep count is chosen so that ``δ ≤ 0.9 · robot_radius`` at the fastest allowed
speed: a robot's centre therefore never enters an obstacle, however thin (a zero-radius
point obstacle or a zero-thickness wall included).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Sequence

import numpy as np
import pymunk
import pymunk.batch
from pymunk._chipmunk_cffi import lib as _cp

from apf_physics.world import CircleObstacle, PolygonObstacle, World

_FEW = 4  # up to this many robots, per-body attribute access beats pymunk.batch's fixed cost
WALL_THICKNESS = 1.0  # of the slabs around each map [units]
MAX_SPEED = math.sqrt(2.0)  # a diagonal unit move (±1, ±1) per control step [units per control step]


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


@dataclass
class ContactLog:
    """Contacts of the last control step, per robot."""

    obstacle: np.ndarray          # (N,) bool: touched an obstacle
    wall: np.ndarray              # (N,) bool: touched the map's edge
    robot: np.ndarray             # (N,) bool: touched another robot
    contacts: list[Contact] = field(default_factory=list)

    @property
    def any(self) -> np.ndarray:
        """(N,) bool: touched anything."""
        return self.obstacle | self.wall | self.robot


def triangulate(vertices: np.ndarray) -> list[np.ndarray]:
    """Split a simple counter-clockwise polygon into convex pieces (ear clipping; convex stays whole)."""
    n = len(vertices)
    edges = np.roll(vertices, -1, axis=0) - vertices
    turn = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    if np.all(turn >= -1e-12):
        return [vertices]
    idx = list(range(n))
    pieces = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10 * n * n:
        guard += 1
        m = len(idx)
        for k in range(m):
            i0, i1, i2 = idx[(k - 1) % m], idx[k], idx[(k + 1) % m]
            a, b, c = vertices[i0], vertices[i1], vertices[i2]
            if cross(a, b, c) <= 1e-12:
                continue  # reflex or degenerate corner
            ear = True
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                p = vertices[j]
                if cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0:
                    ear = False
                    break
            if ear:
                pieces.append(np.array([a, b, c]))
                idx.pop(k)
                break
        else:  # numerically stuck: fall back to a fan of what is left
            break
    if len(idx) >= 3:
        rest = vertices[idx]
        pieces.extend(np.array([rest[0], rest[i], rest[i + 1]]) for i in range(1, len(rest) - 1))
    return pieces


class Physics:
    """One pymunk space holding ``len(worlds)`` slots, each a world with its robots.

    Args:
        worlds: The world of each slot (a slot's world can be replaced later with :meth:`set_world`).
        robots_per_slot: Robots in each slot; robot ``r`` of slot ``s`` has global index
            ``s * robots_per_slot + r``.
        control_dt: Duration of one control step; a velocity command ``v`` moves a free robot by
            ``v · control_dt``.
        max_speed: Fastest allowed speed, in units per control step; commands are clipped to it.
        substeps: Substeps per control step; by default the fewest (a power of two) that keep
            tunnelling impossible (see the module docstring).
        pitch: Spacing of the tiles; by default the largest world plus a margin. Worlds swapped
            in later must fit in it.
    """

    def __init__(self, worlds: Sequence[World], robots_per_slot: int = 1, control_dt: float = 1.0,
                 max_speed: float = MAX_SPEED, substeps: int | None = None, pitch: float | None = None):
        if not worlds:
            raise ValueError("Physics needs at least one world")
        self.num_slots = len(worlds)
        self.robots_per_slot = int(robots_per_slot)
        self.num_robots = self.num_slots * self.robots_per_slot
        self.control_dt = float(control_dt)
        self.max_speed = float(max_speed)
        radius = min(w.robot_radius for w in worlds)
        if substeps is None:
            substeps = 2 ** math.ceil(math.log2(max(1.0, self.max_speed / (0.9 * radius))))
        self.substeps = int(substeps)
        self.dt = self.control_dt / self.substeps
        if pitch is None:
            pitch = max(max(w.size) for w in worlds) + 2 * WALL_THICKNESS + 2.0
        self.pitch = float(pitch)
        cols = math.ceil(math.sqrt(self.num_slots))
        slots = np.arange(self.num_slots)
        self.offsets = np.column_stack([(slots % cols) * self.pitch, (slots // cols) * self.pitch]).astype(float)
        self._robot_offsets = np.repeat(self.offsets, self.robots_per_slot, axis=0)

        self.space = pymunk.Space()
        self.space.iterations = 10
        # Chipmunk tolerates 0.1 of overlap by default; a robot resting against an obstacle with
        # that much overlap would sink past its boundary on the next push. Correct overlaps fully.
        self.space.collision_slop = 0.002
        # Forget a contact as soon as it ends: a teleported robot must not inherit the warm-start
        # impulses of the contact it had before (runs would then depend on how a reset was timed).
        self.space.collision_persistence = 1
        self.worlds: list[World] = list(worlds)
        self._slot_shapes: list[list[pymunk.Shape]] = [[] for _ in range(self.num_slots)]
        self._shape_label: dict[pymunk.Shape, tuple[str, int]] = {}
        self.bodies: list[pymunk.Body] = []
        for s, world in enumerate(self.worlds):
            self._add_static(s, world)
            for r in range(self.robots_per_slot):
                body, shape = self._new_robot(world.robot_radius)
                body.position = tuple(self.offsets[s] + 1.0 + r)  # placed properly by place()
                self.space.add(body, shape)
                self._shape_label[shape] = ("robot", len(self.bodies))
                self.bodies.append(body)

        self._contacts: set[tuple[int, str, int]] = set()
        # Pairs touching now. Callbacks fire only when a touch begins or ends (not every
        # substep), so a resting contact costs no Python; the log of a step is every pair
        # that touched at some point of it.
        self._touching: set[tuple[int, str, int]] = set()
        for other in (CollisionType.OBSTACLE, CollisionType.WALL, CollisionType.ROBOT):
            self.space.on_collision(CollisionType.ROBOT, other, begin=self._begin, separate=self._separate)

        # A spatial hash beats the default bounding-box tree for many small discs moving among
        # tiled static shapes (tools/bench_env.py: ~1.8x faster steps at N = 256).
        shapes = len(self.space.shapes)
        if self.num_robots > 16:
            self.space.use_spatial_hash(4.0, max(1000, 10 * shapes))

        self._buffer = pymunk.batch.Buffer()
        self._index_bodies()

    # -- construction --------------------------------------------------------------------
    def _add_static(self, slot: int, world: World) -> None:
        static = self.space.static_body
        ox, oy = self.offsets[slot]
        w, h = world.size
        if w > self.pitch - 2 * WALL_THICKNESS - 1.0 or h > self.pitch - 2 * WALL_THICKNESS - 1.0:
            raise ValueError(f"world {world.name!r} ({w:g} x {h:g}) does not fit the tile pitch {self.pitch:g}")
        shapes: list[pymunk.Shape] = []
        for i, obstacle in enumerate(world.obstacles):
            if isinstance(obstacle, PolygonObstacle):
                for piece in triangulate(obstacle.vertices):
                    shapes.append(pymunk.Poly(static, [(x + ox, y + oy) for x, y in piece]))
                    self._shape_label[shapes[-1]] = ("obstacle", i)
            elif isinstance(obstacle, CircleObstacle):
                cx, cy = obstacle.center
                shapes.append(pymunk.Circle(static, obstacle.radius, offset=(cx + ox, cy + oy)))
                self._shape_label[shapes[-1]] = ("obstacle", i)
        for shape in shapes:
            shape.collision_type = CollisionType.OBSTACLE
        # Walls are solid slabs just outside the map (a zero-thickness segment could be crossed
        # by a robot squeezed against it): bottom, right, top, left.
        t = WALL_THICKNESS
        slabs = [(ox - t, oy - t, ox + w + t, oy), (ox + w, oy - t, ox + w + t, oy + h + t),
                 (ox - t, oy + h, ox + w + t, oy + h + t), (ox - t, oy - t, ox, oy + h + t)]
        for i, (x0, y0, x1, y1) in enumerate(slabs):
            wall = pymunk.Poly(static, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
            wall.collision_type = CollisionType.WALL
            self._shape_label[wall] = ("wall", i)
            shapes.append(wall)
        for shape in shapes:
            shape.friction = 0.0
            shape.elasticity = 0.0
        self.space.add(*shapes)
        self._slot_shapes[slot] = shapes

    def set_world(self, slot: int, world: World) -> None:
        """Replace the obstacles and walls of ``slot`` with those of ``world`` (robots stay put)."""
        if world is self.worlds[slot]:
            return
        old = self._slot_shapes[slot]
        self.space.remove(*old)
        for shape in old:
            del self._shape_label[shape]
        self.worlds[slot] = world
        self._add_static(slot, world)
        for r in range(self.robots_per_slot):
            shape = next(iter(self.bodies[slot * self.robots_per_slot + r].shapes))
            if shape.radius != world.robot_radius:
                shape.unsafe_set_radius(world.robot_radius)
        self._index_bodies()

    def _index_bodies(self) -> None:
        """Map pymunk.batch rows to our robots (rows are not in insertion order)."""
        buf = self._buffer
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.BODY_ID, buf)
        ids = np.frombuffer(buf.int_buf(), dtype=np.uintp).copy()
        index = {b.id: i for i, b in enumerate(self.bodies)}
        self._row_robot = np.array([index.get(int(i), -1) for i in ids])
        self._robot_rows = np.flatnonzero(self._row_robot >= 0)
        self._robot_of_row = self._row_robot[self._robot_rows]
        self._velocity_rows = np.zeros((len(ids), 2))
        self._velocity_buffer = pymunk.batch.Buffer()  # shares memory with _velocity_rows
        self._velocity_buffer.set_float_buf(self._velocity_rows.reshape(-1))

    # -- control --------------------------------------------------------------------------
    def _pair(self, arbiter: pymunk.Arbiter) -> tuple[int, str, int] | None:
        a, b = arbiter.shapes
        if a not in self._shape_label or b not in self._shape_label:
            return None  # a shape being removed
        _, robot = self._shape_label[a]
        kind, other = self._shape_label[b]
        return robot, kind, other

    def _begin(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data) -> None:
        pair = self._pair(arbiter)
        if pair is not None:
            self._touching.add(pair)
            self._contacts.add(pair)

    def _separate(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data) -> None:
        pair = self._pair(arbiter)
        if pair is not None:
            self._touching.discard(pair)

    def place(self, robots: Sequence[int] | np.ndarray, positions: np.ndarray) -> None:
        """Teleport robots (global indices) to world-local ``positions`` and stop them."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        robots = np.asarray(robots).ravel()
        moved = set(int(r) for r in robots)
        self._touching = {c for c in self._touching if c[0] not in moved and not (c[1] == "robot" and c[2] in moved)}
        for r, p in zip(robots, positions):
            body = self.bodies[int(r)]
            body.position = (float(p[0] + self._robot_offsets[r, 0]), float(p[1] + self._robot_offsets[r, 1]))
            body.velocity = (0.0, 0.0)
            # Chipmunk keeps a hidden bias velocity from the last contact's position correction
            # and adds it in the next step; a moved robot would carry it along (and runs would
            # depend on when a reset came). Integrating zero time clears it and moves nothing.
            _cp.cpBodyUpdatePosition(body._body, 0.0)
            self.space.reindex_shapes_for_body(body)

    @staticmethod
    def _new_robot(radius: float) -> tuple[pymunk.Body, pymunk.Circle]:
        body = pymunk.Body(1.0, math.inf)
        shape = pymunk.Circle(body, radius)
        shape.collision_type = CollisionType.ROBOT
        shape.friction = 0.0
        shape.elasticity = 0.0
        return body, shape

    @property
    def positions(self) -> np.ndarray:
        """(N, 2) robot centres in each robot's own world coordinates."""
        if self.num_robots <= _FEW:
            return np.array([tuple(b.position) for b in self.bodies]) - self._robot_offsets
        buf = self._buffer
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.POSITION, buf)
        rows = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 2)
        out = np.empty((self.num_robots, 2))
        out[self._robot_of_row] = rows[self._robot_rows]
        return out - self._robot_offsets

    def step(self, velocities: np.ndarray) -> ContactLog:
        """Advance one control step with a velocity command per robot.

        Args:
            velocities: (N, 2) commanded velocities in units per control step; each is clipped to
                ``max_speed``. Rows of robots that should not move must be zero.

        Returns:
            The contacts seen during the step.
        """
        v = np.asarray(velocities, dtype=float).reshape(self.num_robots, 2)
        speed = np.hypot(v[:, 0], v[:, 1])
        too_fast = speed > self.max_speed
        if np.any(too_fast):
            v = v.copy()
            v[too_fast] *= (self.max_speed / speed[too_fast])[:, None]
        if self.num_robots <= _FEW:
            for body, velocity in zip(self.bodies, (v / self.control_dt).tolist()):
                body.velocity = velocity
        else:
            self._velocity_rows[self._robot_rows] = v[self._robot_of_row] / self.control_dt
            pymunk.batch.set_space_bodies(self.space, pymunk.batch.BodyFields.VELOCITY, self._velocity_buffer)

        self._contacts = set(self._touching)
        # Substeps call Chipmunk directly: pymunk's Space.step adds Python bookkeeping (deferred
        # adds/removes, post-step callbacks) that nothing here uses, and it cost 3x the step itself.
        space = self.space
        space._locked = True
        try:
            cp_step, handle, dt = _cp.cpSpaceStep, space._space, self.dt
            for _ in range(self.substeps):
                cp_step(handle, dt)
        finally:
            space._locked = False
        obstacle = np.zeros(self.num_robots, bool)
        wall = np.zeros(self.num_robots, bool)
        robot = np.zeros(self.num_robots, bool)
        if not self._contacts:
            return ContactLog(obstacle, wall, robot, [])
        for r, kind, other in self._contacts:
            if kind == "obstacle":
                obstacle[r] = True
            elif kind == "wall":
                wall[r] = True
            else:
                robot[r] = robot[other] = True
        return ContactLog(obstacle, wall, robot, [Contact(*c) for c in sorted(self._contacts)])
