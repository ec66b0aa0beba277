"""Settling: the overlaps that pymunk leaves at a step's last substep resolved before the step ends.

Chipmunk finds an overlap after the substep that made it and pushes it out in the substeps
after: a robot that met an obstacle in the last substep ends the step up to one substep's travel
inside it, and robots that met each other up to twice that. :class:`Settler` reads how deep each
pair overlaps (from the last substep's arbiters) and moves the robots out by exactly that much,
so that at the end of every control step no robot is more than :data:`SETTLE_OBSTACLE` inside an
obstacle or past the map's edge and no two robots overlap by more than :data:`SETTLE_ROBOT`.
It also puts back a robot that robots pushed through a static obstacle
(:meth:`Settler.undo_crossings`).
"""

from __future__ import annotations

import numpy as np
import pymunk

from apf_physics.sim.contacts import body_robots, deep_planes
from apf_physics.sim.freemove import FreeMoveTest
from apf_physics.sim.proxies import ProxyPool
from apf_physics.sim.slots import Slots

SETTLE_OBSTACLE = 0.005
"""A robot ending a step farther than this inside an obstacle or the edge is pushed out [units]."""
SETTLE_ROUNDS = 6
"""Rounds of pushes and queries before a robot still overlapping is put back (:meth:`Settler.settle`)."""
SETTLE_ROBOT = 0.01
"""Two robots ending a step overlapping more than this are pushed apart [units]."""


class _Overlaps:
    """The overlaps being settled: robots against static shapes (each with where the robot was when
    it was read, its way out and depth: the shape's boundary as a plane there) and pairs of robots."""

    def __init__(self, static_robot: np.ndarray, static_normal: np.ndarray, static_depth: np.ndarray,
                 pair_robots: np.ndarray, positions: np.ndarray):
        self.static_robot, self.static_normal, self.static_depth = static_robot, static_normal, static_depth
        self.pair_robots = pair_robots
        self.anchor = positions[static_robot]

    def add(self, robot: np.ndarray, normal: np.ndarray, depth: np.ndarray, pairs: np.ndarray,
            positions: np.ndarray) -> None:
        """More overlaps, read with the robots at ``positions``."""
        self.static_robot = np.concatenate([self.static_robot, robot])
        self.static_normal = np.concatenate([self.static_normal, normal])
        self.static_depth = np.concatenate([self.static_depth, depth])
        self.anchor = np.concatenate([self.anchor, positions[robot]])
        self.pair_robots = np.concatenate([self.pair_robots, pairs])


class Settler:
    """Settles the robots that pymunk moved, in place in ``positions`` (their proxies follow).

    Args:
        space: The physics' space (shape queries about proxies).
        proxies: The proxy pool.
        slots: The physics' slots.
        free: The free-move test (its exact static geometry, for robots alone in their slots).
        positions: (N, 2) the physics' robot positions, world-local (written in place).
    """

    def __init__(self, space: pymunk.Space, proxies: ProxyPool, slots: Slots, free: FreeMoveTest,
                 positions: np.ndarray):
        self.space = space
        self.proxies = proxies
        self.slots = slots
        self.free = free
        self.positions = positions

    def settle(self, depths, undone: np.ndarray, simulated: np.ndarray, before: np.ndarray) -> None:
        """Resolve, before the step ends, the overlaps that pymunk leaves at its last substep.

        Chipmunk finds an overlap after the substep that made it and pushes it out in the
        substeps after: a robot that met an obstacle in the last substep ends the step up to
        one substep's travel inside it, and robots that met each other up to twice that. The
        arbiters of the last substep say how deep each pair overlaps and along which normal
        (:func:`~apf_physics.sim.contacts.touching_depths`); :func:`project_out` moves the
        robots out of each other and of the static shapes by exactly that much (0.001 more),
        whenever an overlap exceeds :data:`SETTLE_OBSTACLE` (obstacles, moving obstacles and
        the map's edge) or :data:`SETTLE_ROBOT` (two robots). The proxies follow. Robots alone
        in their slots (most of them) are settled one by one in plain floats by the same rule
        (:meth:`_alone`).

        ``undone``: robots put back where they started the step (:meth:`undo_crossings`): what
        they overlap there is asked of pymunk (:meth:`overlaps_at`) instead.

        A robot that pymunk wedged between two shapes nearly facing each other (a narrow V)
        would take the pushes many rounds to leave; after :data:`SETTLE_ROUNDS` it is put back
        where it started the step (``before``, of ``simulated``: where the step before left it)
        with the robots that meet it and that pymunk moved, and so again after as many more
        (:meth:`_undo_pile_up`).
        """
        if depths is None and not len(undone):
            return
        ids, normal, distance = depths if depths is not None else (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
        alone, first, planes, deep = deep_planes(ids, normal, distance, min(SETTLE_OBSTACLE, SETTLE_ROBOT),
                                                 self.proxies.sorted_ids, self.proxies.order, self.proxies.robot,
                                                 self.proxies.solo)
        if len(alone):   # robots alone in their slots (most of them): _alone
            self._alone(alone, first, planes, simulated, before)
        if not len(deep) and not len(undone):
            return
        overlaps = self._read(ids[deep], normal[deep], -distance[deep], undone)
        if overlaps is not None:
            self._push_apart(overlaps, simulated, before)

    def _read(self, ids: np.ndarray, normal: np.ndarray, depth: np.ndarray, undone: np.ndarray) -> _Overlaps | None:
        """The deep overlaps of the last substep's arbiters (``ids`` (K, 2) body ids, their normals and
        depths), and what the ``undone`` robots overlap where they were put back; None: nothing."""
        # a robot and a static shape: the robot's way out is against the normal if it is a, along it if b
        robot, _ = body_robots(ids, self.proxies.sorted_ids, self.proxies.order, self.proxies.robot)
        both = (robot[:, 0] >= 0) & (robot[:, 1] >= 0)
        first_side = robot[:, 0] >= 0
        one = ~both
        r = np.where(first_side, robot[:, 0], robot[:, 1])[one].astype(np.intp)
        out = normal[one] * np.where(first_side[one], -1.0, 1.0)[:, None]
        rest = ~np.isin(r, undone) if len(undone) else np.ones(len(r), bool)
        overlaps = _Overlaps(r[rest], out[rest], depth[one][rest], robot[both].astype(np.intp), self.positions)
        if not len(overlaps.static_robot) and not len(overlaps.pair_robots) and not len(undone):
            return None
        if len(undone):
            overlaps.add(*self.overlaps_at(undone), self.positions)
        return overlaps

    def _push_apart(self, overlaps: _Overlaps, simulated: np.ndarray, before: np.ndarray) -> None:
        """Rounds of :func:`project_out` and of asking pymunk what the pushed robots overlap now, until
        nothing does; after :data:`SETTLE_ROUNDS`, the robots still overlapping go back to where
        they started the step (``before``, of ``simulated``) with the robots that meet them and
        that pymunk moved, and are settled there; after as many more, back again
        (:meth:`_undo_pile_up`)."""
        m = self.slots.robots_per_slot
        still = np.zeros(0, np.intp)   # robots still overlapping after a round
        for round_ in range(2 * SETTLE_ROUNDS):
            if round_ == SETTLE_ROUNDS:   # still overlapping: back to the step's start, and what is there
                back = self._undo_pile_up(still, simulated, before)
                overlaps = _Overlaps(*self.overlaps_at(back), self.positions)
            involved = self._with_mates(np.unique(np.concatenate([overlaps.static_robot,
                                                                  overlaps.pair_robots.ravel()])))
            p = project_out(self.positions[involved], self.slots.radius[involved // m],
                            np.searchsorted(involved, overlaps.static_robot), overlaps.anchor, overlaps.static_normal,
                            overlaps.static_depth, self.slots.group(involved))
            moved = np.any(p != self.positions[involved], axis=1)
            robots = involved[moved]
            if not len(robots):
                return
            self._put(robots, p[moved])   # only robots that pymunk moved touch anything
            # a robot pushed out of one shape may have been pushed into another: ask pymunk again, and
            # keep the shapes already met (a robot in a corner settles against both sides at once)
            more_robot, more_normal, more_depth, more_pairs = self.overlaps_at(robots)
            if not len(more_robot) and not len(more_pairs):
                return
            still = np.unique(np.concatenate([more_robot, more_pairs.ravel()]))
            overlaps.add(more_robot, more_normal, more_depth, more_pairs, self.positions)
        self._undo_pile_up(still, simulated, before)

    def _undo_pile_up(self, still: np.ndarray, simulated: np.ndarray, before: np.ndarray) -> np.ndarray:
        """Put back where the step began the robots ``still`` overlapping and every robot that pymunk
        moved among those that meet them (for a robot alone in its slot, itself); returns them.

        A robot that others press into a narrow V leaves it only along the V, a little at each
        round of pushes, and its mates press it back in after it is put back alone; and a mate
        that pymunk moved past it would seem to have gone through it, the robot put back where
        it was. Where the step began, the pile-up stands as the step before settled it. (The few
        steps a crowd jams: before, a robot 0.025 inside a bar in 15 of 96,000 robot-steps of
        ``tools/probe_contacts.py``'s holonomic crowds, and 6 centres through another robot.)
        """
        back = self._with_mates(still)
        back = back[np.isin(back, simulated)]
        self._put(back, before[np.searchsorted(simulated, back)])
        return back

    def _put(self, robots: np.ndarray, where: np.ndarray) -> None:
        """Robots at ``where`` (world-local), their proxies to follow before pymunk next steps."""
        self.positions[robots] = where
        proxies = self.proxies.of_robot[robots]
        self.proxies.target[proxies] = where + self.slots.offset[robots // self.slots.robots_per_slot]
        self.proxies.moved[proxies] = True

    def _alone(self, robots: np.ndarray, first: np.ndarray, planes: np.ndarray, simulated: np.ndarray,
               before: np.ndarray) -> None:
        """:meth:`settle` for robots alone in their slots (a robot alone meets no robot, and there
        are a few a step), by the rule of :meth:`~apf_physics.sim.swept.SweptDistances.settle`, compiled: each
        is pushed out of the shape it overlaps most until none by more than
        :data:`SETTLE_OBSTACLE`, then the static shape nearest its centre is looked up (in the
        world's exact geometry, the shapes pymunk has); one overlapped is added, and so on; after
        :data:`SETTLE_ROUNDS` a robot still overlapping goes back to where it started the step.

        ``robots`` (R,) sorted, ``first`` (R + 1,), ``planes`` (K, 3): robot ``robots[i]``'s
        overlaps with static shapes at the last substep are ``planes[first[i]:first[i + 1]]``,
        each ``(way out x, y, depth)`` (:func:`~apf_physics.sim.contacts.deep_planes`).
        """
        slots = robots // self.slots.robots_per_slot
        p = self.free.swept.settle(self.free.map_of[robots], self.positions[robots],
                                    before[np.searchsorted(simulated, robots)], self.slots.radius[slots], first,
                                    planes, SETTLE_OBSTACLE, SETTLE_ROUNDS)
        self._put(robots, p)

    def _with_mates(self, robots: np.ndarray) -> np.ndarray:
        """``robots`` and every robot that pymunk moved this step and that meets one of them (its
        slot's robots, its crowd's), sorted: robots pushed apart are pushed among all they meet."""
        m = self.slots.robots_per_slot
        if m == 1 and not self.slots.crowd_robots:
            return robots
        held = np.flatnonzero(self.proxies.of_robot >= 0)
        slots, held_slots = robots // m, held // m
        crowds = self.slots.crowd[slots[self.slots.shared[slots]]]
        mates = np.isin(held_slots, slots) | (self.slots.shared[held_slots] & np.isin(self.slots.crowd[held_slots], crowds))
        return np.union1d(robots, held[mates])

    def overlaps_at(self, robots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the proxies of ``robots`` (robots that meet others), put where the robots are now,
        overlap by more than the settling tolerances (pymunk's shape queries): ``(robot (K,), way
        out (K, 2), depth (K,), pairs of robots (L, 2))``, as :meth:`settle` reads them from the
        arbiters."""
        static_robot, static_normal, static_depth, pairs = [], [], [], []
        proxies = self.proxies.of_robot[robots]
        bodies = [self.proxies.bodies[k] for k in proxies.tolist()]
        for body, (x, y) in zip(bodies, self.proxies.target[proxies].tolist()):
            body.position = (x, y)
            self.space.reindex_shapes_for_body(body)
        tolerance = min(SETTLE_OBSTACLE, SETTLE_ROBOT)
        for robot, body in zip(robots.tolist(), bodies):
            for info in self.space.shape_query(next(iter(body.shapes))):
                points = info.contact_point_set.points
                if not points or points[0].distance >= -tolerance:
                    continue
                other = self.proxies.of_id.get(info.shape.body.id)
                if other is None:   # a static shape (or a moving obstacle): out against the normal
                    normal = info.contact_point_set.normal
                    static_robot.append(robot)
                    static_normal.append((-normal.x, -normal.y))
                    static_depth.append(-points[0].distance)
                elif self.proxies.robot[other] >= 0:
                    pairs.append((robot, int(self.proxies.robot[other])))
        return (np.array(static_robot, np.intp), np.array(static_normal, float).reshape(-1, 2),
                np.array(static_depth, float), np.array(pairs, np.intp).reshape(-1, 2))

    def undo_crossings(self, robots: np.ndarray, before: np.ndarray) -> np.ndarray:
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
        after = self.positions[robots]
        slots = robots // self.slots.robots_per_slot
        undone = []
        for slot in np.unique(slots).tolist():
            world = self.slots.worlds[slot]
            mine = np.flatnonzero(slots == slot)
            r = world.robot_radius
            clear = world.path_clearance(before[mine], after[mine], 0.5 * r)
            crossed = mine[clear < 0.5 * r]
            if not len(crossed):
                continue
            undone.append(robots[crossed])
            self._put(robots[crossed], before[crossed])
        return np.concatenate(undone) if undone else np.zeros(0, np.intp)


def project_out(p: np.ndarray, radius: np.ndarray, static_robot: np.ndarray, anchor: np.ndarray,
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
