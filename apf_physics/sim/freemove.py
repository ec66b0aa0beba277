"""The free-move test: which robots' moves this step provably cannot touch anything, and their moves.

Such a robot moves exactly as pymunk would move a free disc (``p ← p + v·dt`` at each substep,
the same additions in the same order: :func:`move_free`) without pymunk. The test
(:meth:`FreeMoveTest.needs`) is conservative: False guarantees that the robot's disc keeps more
than :data:`CONTACT_MARGIN` from every obstacle, the map's edge and the robots it meets during
the whole move.

- Static obstacles and the map's edge: the exact least distance between the segment the
  robot's centre sweeps and its world's static shapes (:class:`~apf_physics.sim.swept.SweptDistances`,
  compiled), lowered by how far a unicycle's arc strays from the straight move.
- Robots that meet (formations, crowds): judged against what the others can do, not what they
  were told. The robots that go to pymunk are closed under "may touch one that goes to pymunk"
  (anywhere within a generous reach of its start: it may be blocked or pushed), the others
  moving straight and uniformly as commanded (:func:`close_under_touch`).
- Moving obstacles: a robot whose swept box meets the box an obstacle sweeps this step.
"""

from __future__ import annotations

import numpy as np

from apf_physics.common.compiled import kernel
from apf_physics.common.geometry import swept_distance
from apf_physics.sim.slots import Slots
from apf_physics.sim.swept import SweptDistances, _move_near
from apf_physics.world.core import World

CONTACT_MARGIN = 0.01
"""A move that keeps this much more than touching distance needs no physics [units]."""


class FreeMoveTest:
    """The free-move test of every robot of the physics' slots.

    Args:
        slots: The physics' slots (worlds, radii, crowds, steps); read, never written.
        reach: How far pymunk may take a robot in one step, its own move and pushes by others
            included (a generous bound), for robots that meet others.

    Attributes:
        swept: The static geometry of the worlds in use (also the settling's exact look-ups).
        map_of: (N,) each robot's map among ``swept``.
        keep_off: (N,) the distance each robot's move must keep from static shapes to need no physics.
        movers_needed: After :meth:`needs`: ``(world, index, slots, near)`` for each moving obstacle
            that robots come near (what the mover pool lends).
    """

    def __init__(self, slots: Slots, reach: float):
        self.slots = slots
        self.reach = float(reach)
        self.swept = SweptDistances()
        self.map_of = np.zeros(slots.num_robots, np.intp)
        self.keep_off = np.zeros(slots.num_robots)
        self.movers_needed: list = []
        self._moving_slots: list | None = None

    def assign(self, slot: int, world: World) -> None:
        """``slot`` is now in ``world``."""
        robots = self.slots.robots(np.array([slot]))
        self.map_of[robots] = self.swept.add(world)   # shared by worlds of one map
        self.keep_off[robots] = world.robot_radius + CONTACT_MARGIN
        self._moving_slots = None

    def needs(self, positions: np.ndarray, moves: np.ndarray, bend: np.ndarray | None = None,
              any_moving: bool = False) -> np.ndarray:
        """(N,) bool: robots at ``positions`` whose ``moves`` this step might bring them into contact
        with anything (see the module docstring).

        ``bend``: (N,) how far each robot's path strays from its straight move at the same moment
        (a unicycle's arc; None: every path is straight). Every clearance is lowered by it.
        ``any_moving``: some slot has been in a world with moving obstacles (they are taken where
        the slots' steps put them, :attr:`Slots.time`).
        """
        keep_off = self.keep_off if bend is None else self.keep_off + bend
        return self.close(positions, moves, self.swept.near(self.map_of, positions, moves, keep_off), bend, any_moving)

    def step(self, positions: np.ndarray, v: np.ndarray, max_speed: float, control_dt: float, substeps: int,
             offset: np.ndarray, movable: np.ndarray, move: bool) -> tuple[np.ndarray, int]:
        """The free-move test of straight moves against the static obstacles, in one compiled pass.

        Each command of ``v`` (N, 2) is first clipped to ``max_speed`` (in place); then each robot's
        move is tested as :meth:`needs` tests it before :meth:`close` (which the caller applies
        where robots meet others or moving obstacles). With ``move``, every ``movable`` robot whose
        move needs no physics is moved as :func:`move_free` moves it.

        Returns:
            (N,) bool: the moves that come near a static obstacle or the map's edge; and how many
            of them are ``movable``.
        """
        grid, shape, start, member, prim = self.swept.tables()
        needs = np.empty(len(positions), np.bool_)
        count = _free_step(positions, v, float(max_speed), float(control_dt), int(substeps), offset,
                           self.slots.robots_per_slot, self.map_of, self.keep_off, movable, bool(move), needs,
                           grid, shape, start, member, prim)
        return needs, count

    def close(self, positions: np.ndarray, moves: np.ndarray, needs: np.ndarray, bend: np.ndarray | None,
              any_moving: bool) -> np.ndarray:
        """``needs`` (the moves near a static obstacle) closed under "may touch a robot that goes to
        pymunk" among robots that meet, and with the robots near a moving obstacle added."""
        slots = self.slots
        m = slots.robots_per_slot
        if m > 1:   # robots of one slot: closed under "may touch a robot that goes to pymunk"
            p = positions.reshape(-1, m, 2)
            dp = moves.reshape(-1, m, 2)
            present = slots.present.reshape(-1, m)
            both_free, near_held = may_touch(p, dp, slots.radius[:, None, None], present, self.reach,
                                             None if bend is None else bend.reshape(-1, m))
            needs = close_under_touch(needs.reshape(-1, m), both_free, near_held).ravel()
        for group in slots.crowd_robots:   # robots of several slots that meet: the same over the crowd
            group = group[slots.present[group]]
            needs[group] = crowd_needs(positions[group], moves[group], slots.radius[group // m], needs[group],
                                       self.reach, None if bend is None else bend[group])
        if not any_moving:
            return needs
        self.movers_needed = []
        for group_slots, world, index, near in self._near_movers(positions, moves, bend):
            robots = (group_slots[:, None] * m + np.arange(m)).ravel()
            needs[robots] |= near.ravel()
            self.movers_needed.append((world, index, group_slots, near.any(axis=1)))
        return needs

    def _near_movers(self, positions: np.ndarray, moves: np.ndarray, bend: np.ndarray | None = None):
        """For each moving obstacle of each world in use: ``(slots, world, index, near (k, m))``,
        the robots of those slots whose swept disc this step comes near the obstacle's swept box."""
        slots = self.slots
        m = slots.robots_per_slot
        if self._moving_slots is None:   # slots grouped by moving world, until a slot changes world
            groups: dict[int, tuple[World, list[int]]] = {}
            for s, w in enumerate(slots.worlds):
                if w.moving:
                    groups.setdefault(id(w), (w, []))[1].append(s)
            self._moving_slots = [(w, np.array(members, np.intp)) for w, members in groups.values()]
        for world, members in self._moving_slots:
            t = slots.time[members]
            p = positions.reshape(-1, m, 2)[members]
            q = p + moves.reshape(-1, m, 2)[members]
            reach = world.robot_radius + 2 * CONTACT_MARGIN
            if bend is not None:
                reach = reach + bend.reshape(-1, m)[members][..., None]
            robot_lo, robot_hi = np.minimum(p, q) - reach, np.maximum(p, q) + reach
            for index in world.moving:
                obstacle = world.obstacles[index]
                start, end = obstacle.motion.offset(t), obstacle.motion.offset(t + 1.0)
                lo, hi = obstacle.bounds
                box_lo = (lo + np.minimum(start, end))[:, None, :]
                box_hi = (hi + np.maximum(start, end))[:, None, :]
                near = np.all((robot_hi >= box_lo) & (robot_lo <= box_hi), axis=2)
                if near.any():
                    yield members, world, index, near


def move_free(positions: np.ndarray, robots: np.ndarray, offset: np.ndarray, v: np.ndarray, control_dt: float,
              substeps: int) -> None:
    """Move ``robots`` as pymunk moves a free disc, to the bit, in place in ``positions``.

    Each robot is put where its proxy would be (its position plus its tile's ``offset``),
    advanced by its velocity times the substep's duration at each substep (chipmunk's
    ``p ← p + v·dt``, a velocity per substep changing as the physics changes a proxy's between
    substeps), and read back less the offset: a robot's path does not depend on whether it went
    to pymunk this step.

    Args:
        v: (N, 2) commands, or (N, substeps, 2) one per substep, in units per control step.
    """
    if not len(robots):
        return
    if v.ndim == 3:   # a velocity per substep: the first, then each change added (as the physics steers)
        velocity = np.empty((len(robots), substeps, 2))
        velocity[:, 0] = v[robots, 0] / control_dt
        for k in range(1, substeps):
            velocity[:, k] = velocity[:, k - 1] + (v[robots, k] - v[robots, k - 1]) / control_dt
    else:   # one for every substep
        velocity = (v[robots] / control_dt)[:, None, :]
    _free_moves(positions, robots, offset, velocity, control_dt / substeps, substeps)


@kernel
def _free_step(positions, v, max_speed, control_dt, substeps, offset, m, map_of, keep_off, movable, move, needs,
               grid, shape, start, member, prim):
    """:meth:`FreeMoveTest.step`'s loop: per robot, the clip (as numpy clips: ``v · (top / |v|)``), the
    static test (:func:`~apf_physics.sim.swept._move_near` of the segment ``p → p + v·dt``) and, with
    ``move``, :func:`_free_moves`' additions for a movable robot whose move is free. Writes ``needs``;
    returns how many movable robots need physics."""
    n = positions.shape[0]
    dt = control_dt / substeps
    count = 0
    for r in range(n):
        vx, vy = v[r, 0], v[r, 1]
        speed = np.hypot(vx, vy)
        if speed > max_speed:
            factor = max_speed / speed
            vx, vy = vx * factor, vy * factor
            v[r, 0], v[r, 1] = vx, vy
        px, py = positions[r, 0], positions[r, 1]
        needs[r] = _move_near(map_of[r], px, py, px + vx * control_dt, py + vy * control_dt, keep_off[r],
                              grid, shape, start, member, prim)
        if needs[r] and movable[r]:
            count += 1
        elif move and movable[r]:
            ox, oy = offset[r // m, 0], offset[r // m, 1]
            x, y = px + ox, py + oy
            wx, wy = vx / control_dt, vy / control_dt
            for _ in range(substeps):
                x = x + wx * dt
                y = y + wy * dt
            positions[r, 0], positions[r, 1] = x - ox, y - oy
    return count


@kernel
def _free_moves(positions, robots, offset, velocity, dt, substeps):
    """:func:`move_free`'s arithmetic: in place, robot ``robots[k]`` from its position plus
    ``offset[k]``, ``p ← p + velocity[k, s]·dt`` for each of the substeps ``s`` (``velocity``
    (K, substeps, 2), or (K, 1, 2): the same at every substep), less the offset."""
    last = velocity.shape[1] - 1
    for k in range(robots.shape[0]):
        r = robots[k]
        x, y = positions[r, 0] + offset[k, 0], positions[r, 1] + offset[k, 1]
        for s in range(substeps):
            x = x + velocity[k, min(s, last), 0] * dt
            y = y + velocity[k, min(s, last), 1] * dt
        positions[r, 0], positions[r, 1] = x - offset[k, 0], y - offset[k, 1]


def _segment_point_distance(p: np.ndarray, dp: np.ndarray) -> np.ndarray:
    """(S, m, m) least distance between robot i's straight move and robot j's start, in each slot."""
    r0 = p[:, None, :, :] - p[:, :, None, :]                      # from i's start to j's
    a = np.sum(dp * dp, axis=-1)[:, :, None]
    t = np.clip(np.sum(r0 * dp[:, :, None, :], axis=-1) / np.where(a > 0, a, 1.0), 0.0, 1.0)
    closest = r0 - t[..., None] * dp[:, :, None, :]
    return np.sqrt(np.sum(closest * closest, axis=-1))


def may_touch(p: np.ndarray, dp: np.ndarray, radius: np.ndarray, present: np.ndarray,
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
    both_free = swept_distance(p[:, :, None, :], dp[:, :, None, :], p[:, None, :, :], dp[:, None, :, :]) < touch
    near_held = _segment_point_distance(p, dp) < touch + reach
    others = present[:, None, :] & present[:, :, None] & ~np.eye(p.shape[1], dtype=bool)[None]
    return both_free & others, near_held & others


def crowd_needs(p: np.ndarray, dp: np.ndarray, radius: np.ndarray, needs: np.ndarray, reach: float,
                bend: np.ndarray | None = None) -> np.ndarray:
    """(G,) the robots of a crowd (every robot meets every other) that go to pymunk: what
    :func:`may_touch` and :func:`close_under_touch` decide over the crowd, with the same arithmetic,
    but only between robots near enough to matter (a grid of cells wider than any pair that may touch
    or come within ``reach``), so that a crowd of hundreds costs in proportion to its robots.

    Args:
        p: (G, 2) the robots' positions; dp: (G, 2) their moves; radius: (G,) their radii;
        needs: (G,) bool, the moves that need physics already; reach: as :func:`may_touch`'s;
        bend: (G,) how far each path strays from its straight move (None: not at all).
    """
    p, dp = np.ascontiguousarray(p, float), np.ascontiguousarray(dp, float)
    bend = np.zeros(len(p)) if bend is None else np.ascontiguousarray(bend, float)
    out = np.ascontiguousarray(needs, np.bool_).copy()
    if len(p) > 1:
        _crowd_needs(p, dp, np.ascontiguousarray(radius, float), float(reach), bend, out)
    return out


@kernel
def _pair_both_free(p, dp, i, j, touch):
    """``may_touch``'s ``both_free[i, j]``: the two straight, uniform moves come within ``touch``."""
    r0x, r0y = p[i, 0] - p[j, 0], p[i, 1] - p[j, 1]
    drx, dry = dp[i, 0] - dp[j, 0], dp[i, 1] - dp[j, 1]
    a = drx * drx + dry * dry
    t = 0.0
    if a > 0:
        t = -(r0x * drx + r0y * dry) / a
    t = min(max(t, 0.0), 1.0)
    cx, cy = r0x + t * drx, r0y + t * dry
    return np.sqrt(cx * cx + cy * cy) < touch


@kernel
def _pair_near_held(p, dp, i, j, within):
    """``may_touch``'s ``near_held[i, j]``: robot i's straight move comes within ``within`` of j's start."""
    r0x, r0y = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1]
    a = dp[i, 0] * dp[i, 0] + dp[i, 1] * dp[i, 1]
    t = (r0x * dp[i, 0] + r0y * dp[i, 1]) / (a if a > 0 else 1.0)
    t = min(max(t, 0.0), 1.0)
    cx, cy = r0x - t * dp[i, 0], r0y - t * dp[i, 1]
    return np.sqrt(cx * cx + cy * cy) < within


@kernel
def _crowd_needs(p, dp, radius, reach, bend, needs):
    """:func:`crowd_needs`' loops, in place in ``needs``: robots binned in cells wider than any pair that
    may matter; first the robots that may touch another moving as commanded, then every robot whose
    move comes near where a robot that goes to pymunk may be, until none is added."""
    n = p.shape[0]
    longest, widest, strayed = 0.0, 0.0, 0.0
    for i in range(n):
        longest = max(longest, np.hypot(dp[i, 0], dp[i, 1]))
        widest = max(widest, radius[i])
        strayed = max(strayed, bend[i])
    size = 2 * widest + CONTACT_MARGIN + 2 * strayed + reach + 2 * longest + 1e-9
    x0, y0 = p[:, 0].min(), p[:, 1].min()
    cols = int((p[:, 0].max() - x0) / size) + 1
    rows = int((p[:, 1].max() - y0) / size) + 1
    cell = np.empty(n, np.int64)
    for i in range(n):
        cell[i] = int((p[i, 1] - y0) / size) * cols + int((p[i, 0] - x0) / size)
    order = np.argsort(cell, kind="mergesort")
    first = np.full(rows * cols + 1, n, np.int64)
    for k in range(n - 1, -1, -1):
        first[cell[order[k]]] = k
    for c in range(rows * cols - 1, -1, -1):
        first[c] = min(first[c], first[c + 1])
    queue = np.empty(n, np.int64)
    top = 0
    for i in range(n):
        touch_i = 2 * radius[i] + CONTACT_MARGIN
        if not needs[i]:
            r, c = cell[i] // cols, cell[i] % cols
            for rr in range(max(r - 1, 0), min(r + 2, rows)):
                for cc in range(max(c - 1, 0), min(c + 2, cols)):
                    for k in range(first[rr * cols + cc], first[rr * cols + cc + 1]):
                        j = order[k]
                        if j != i and _pair_both_free(p, dp, i, j, touch_i + bend[i] + bend[j]):
                            needs[i] = True
        if needs[i]:
            queue[top] = i
            top += 1
    while top > 0:   # every robot whose move comes near a robot that goes to pymunk goes too
        top -= 1
        j = queue[top]
        r, c = cell[j] // cols, cell[j] % cols
        for rr in range(max(r - 1, 0), min(r + 2, rows)):
            for cc in range(max(c - 1, 0), min(c + 2, cols)):
                for k in range(first[rr * cols + cc], first[rr * cols + cc + 1]):
                    i = order[k]
                    if not needs[i] and i != j and _pair_near_held(
                            p, dp, i, j, 2 * radius[i] + CONTACT_MARGIN + bend[i] + bend[j] + reach):
                        needs[i] = True
                        queue[top] = i
                        top += 1


def close_under_touch(needs: np.ndarray, both_free: np.ndarray, near_held: np.ndarray) -> np.ndarray:
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
