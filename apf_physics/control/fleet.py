"""A fleet: many robots on one map, each to its own goal, with no two ever touching.

The robots of a fleet stand on a **lattice**: nodes one step apart (the centres of a MovingAI
map's cells at one cell per step), and each control step every robot makes one of the nine unit
moves (:data:`~apf_physics.world.kinematics.ACTIONS`) from node to node, or stays. A planner
scores each robot's moves toward its own goal (its action values, e.g. the map network's
learned values for that goal); :func:`fleet_moves` then picks every robot's move so that no two
robots touch, by **priority inheritance with backtracking** (PIBT: Okumura et al., AIJ 2022):

- robots decide one at a time, the highest priority first; each takes its best-valued move
  whose node nobody has taken and that its shield admits (below);
- a robot whose best node holds a robot that has not decided yet lends it its priority: that
  robot must move out first (anywhere but back into the node of the robot that pushed it); when
  it cannot, the pusher tries its next move;
- a robot with no admitted move stays.

Priorities (:class:`Priorities`) grow with the steps a robot has spent since it was given its
goal and fall back when it arrives, so every robot comes to the top in turn and a robot on its
goal gives way to the others: PIBT's rule against deadlocks, and how robots swap places in a
corridor (the one with priority pushes the other ahead of it, round a side aisle, back).

**The shield among robots.** A move is admitted only when the robot's disc, swept along it,
keeps ``2·radius + SAFETY`` from every other robot's disc over the whole step, each other robot
along its **predicted motion**: the move already decided for it, or standing where it is for a
robot that has not decided yet (the robot being pushed out of the node excepted: it moves
before the step ends, and is checked against this move when it decides). Moves against the
static obstacles are admitted by the one-step shield (:func:`~apf_physics.control.shield.move_clearance`,
computed once per lattice). Staying is always admitted: every move decided before a robot's was
checked against it standing. So no two robots can touch, whatever the planner scored: the
physics then moves every robot exactly as commanded (no contact, nothing for pymunk to resolve).
A horizon of one step is enough because staying is always admitted next step (the shield over
time of :mod:`~apf_physics.control.shield` looks further ahead for obstacles that cannot stop).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Callable, Hashable

import numpy as np

from apf_physics.common.compiled import kernel
from apf_physics.control.shield import ACTIONS, SAFETY, move_clearance
from apf_physics.errors import UserError
from apf_physics.world import field as apf
from apf_physics.world.core import Fleet, World
from apf_physics.world.io.units import show_length, show_point
from apf_physics.world.search import node_distances

GOAL_TABLE_BUDGET = 256 * 2**20
"""Bytes of per-goal tables a planner keeps for a fleet (:class:`GoalTables`): a table is one float32
per lattice node (223 kB on MovingAI's 340 × 164 warehouse: about 1,200 goals)."""
STAY = 8
"""Index of staying among :data:`~apf_physics.world.kinematics.ACTIONS`."""
ON_NODE = 1e-6
"""A position this close to a node [units] stands on it."""
_OFFSETS = ACTIONS.astype(np.intp)   # (9, 2) moves as node steps (dx, dy)


@dataclass(frozen=True, eq=False)
class Lattice:
    """The nodes a fleet's robots stand on: one step apart, through ``origin``, over the map.

    Node ``[r, c]`` (flat index ``r·cols + c``) is at ``origin + (c, r)``. Build with :meth:`of`
    (cached with the world's static obstacles: every target of a map shares it).

    Attributes:
        world: The map (its static obstacles).
        origin: Node ``[0, 0]``, in ``[0, 1)²``.
        shape: ``(rows, cols)``.
        free: (rows·cols,) bool: a robot fits on the node (``radius + SAFETY`` clear of everything).
        room: (rows·cols, 9) float32: each move's clearance beyond ``radius + SAFETY`` (negative:
            the one-step shield refuses it; the map network's ``room`` input).
        ok: (rows·cols, 9) bool: the move is admitted by the one-step shield and ends on a free node
            (staying: on a free node).
    """

    world: World
    origin: tuple[float, float]
    shape: tuple[int, int]
    free: np.ndarray
    room: np.ndarray
    ok: np.ndarray

    @classmethod
    def of(cls, world: World, origin: np.ndarray | tuple[float, float] = (0.5, 0.5)) -> "Lattice":
        """The lattice of ``world`` through ``origin`` (taken modulo one step)."""
        o = tuple(float(v) for v in np.mod(np.asarray(origin, float).reshape(2), 1.0).round(9) % 1.0)
        return world.cached(("fleet_lattice", o), lambda: cls._build(world, o), static=True)

    @classmethod
    def _build(cls, world: World, origin: tuple[float, float]) -> "Lattice":
        cols = int(np.floor(world.size[0] - origin[0] + ON_NODE)) + 1
        rows = int(np.floor(world.size[1] - origin[1] + ON_NODE)) + 1
        xs, ys = np.meshgrid(origin[0] + np.arange(cols), origin[1] + np.arange(rows))
        points = np.column_stack([xs.ravel(), ys.ravel()])
        bar = world.robot_radius + SAFETY
        free = world.static_clearance(points) >= bar
        room = np.full((len(points), len(ACTIONS)), -np.inf, np.float32)
        at = np.flatnonzero(free)
        for chunk in np.array_split(at, max(1, len(at) // 4096)):
            room[chunk] = move_clearance(world, points[chunk], ACTIONS) - bar
        r, c = np.divmod(np.arange(len(points)), cols)
        ok = room >= 0
        for m, (dx, dy) in enumerate(_OFFSETS):
            inside = (c + dx >= 0) & (c + dx < cols) & (r + dy >= 0) & (r + dy < rows)
            ends = np.where(inside, (r + dy) * cols + c + dx, 0)
            ok[:, m] &= inside & free[ends] & free
        return cls(world, origin, (rows, cols), free, room, ok)

    @property
    def count(self) -> int:
        """Nodes, free or not."""
        return self.shape[0] * self.shape[1]

    @property
    def offsets(self) -> np.ndarray:
        """(9,) each move's change of flat node index."""
        return _OFFSETS[:, 1] * self.shape[1] + _OFFSETS[:, 0]

    def points(self, nodes: np.ndarray) -> np.ndarray:
        """(k, 2) the positions of flat ``nodes``."""
        r, c = np.divmod(np.asarray(nodes, np.intp), self.shape[1])
        return np.column_stack([self.origin[0] + c, self.origin[1] + r]).astype(float)

    def nearest(self, points: np.ndarray) -> np.ndarray:
        """(k,) the flat index of the node nearest each point (clipped to the lattice)."""
        p = np.asarray(points, float).reshape(-1, 2) - np.asarray(self.origin)
        c = np.clip(np.rint(p[:, 0]).astype(np.intp), 0, self.shape[1] - 1)
        r = np.clip(np.rint(p[:, 1]).astype(np.intp), 0, self.shape[0] - 1)
        return r * self.shape[1] + c

    def on_node(self, points: np.ndarray) -> np.ndarray:
        """(k,) bool: each point stands on a node (within :data:`ON_NODE`)."""
        points = np.asarray(points, float).reshape(-1, 2)
        return np.max(np.abs(self.points(self.nearest(points)) - points), axis=1) <= ON_NODE

    @property
    def lengths(self) -> np.ndarray:
        """(9,) each move's length."""
        return np.hypot(*ACTIONS.T)

    @property
    def repulsion(self) -> np.ndarray:
        """(rows·cols,) ``U_rep`` of the static obstacles at every node (0 at nodes that are not free); cached."""
        def build() -> np.ndarray:
            out = np.zeros(self.count)
            at = np.flatnonzero(self.free)
            out[at] = apf.repulsive(self.points(at), self.world.shapes, self.world.field)
            return out
        return self.world.cached(("fleet_repulsion", self.origin), build, static=True)

    def potential(self, nodes: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """U at flat ``nodes`` (N, K) in the field of each row's own target, the node ``goals[i]``
        (Model eq. 11 with one target: ``U_att + U_bh`` of it, ``U_rep`` of the static obstacles)."""
        nodes = np.asarray(nodes, np.intp)
        params = self.world.field
        d = np.hypot(*(self.points(nodes.ravel()) - np.repeat(self.points(goals), nodes.shape[1], axis=0)).T)
        well = np.clip(params.ps - d, 0.0, None)
        u = 0.5 * params.katt * d * d - 0.5 * params.kstr * well * well + self.repulsion[nodes.ravel()]
        return u.reshape(nodes.shape)

    def ends(self, nodes: np.ndarray) -> np.ndarray:
        """(N, 9) the node each move of robots at ``nodes`` ends on (the robot's own node where the move
        leaves the lattice: such moves are never admitted)."""
        nodes = np.asarray(nodes, np.intp)
        ends = nodes[:, None] + self.offsets[None, :]
        return np.where(self.ok[nodes] | (np.arange(len(ACTIONS)) == STAY)[None], ends, nodes[:, None])

    def distances(self, goal: int) -> np.ndarray:
        """(rows·cols,) float32 the length of the shortest way from every node to the node ``goal`` over
        admitted moves (octile on a grid map: no corner is cut), inf where none leads."""
        return node_distances(self.ok, self.offsets, self.lengths, int(goal)).astype(np.float32)

    def regions(self) -> np.ndarray:
        """(rows·cols,) the connected region of each free node over admitted moves (−1: not free); cached."""
        def build() -> np.ndarray:
            return _label_regions(self.ok, self.offsets)
        return self.world.cached(("fleet_regions", self.origin), build, static=True)


@kernel
def _label_regions(ok, offsets):
    """Connected regions of the nodes over the moves ``ok`` admits (a flood fill per region)."""
    n = ok.shape[0]
    label = np.full(n, -1, np.int64)
    stack = np.empty(n, np.int64)
    regions = 0
    for seed in range(n):
        if label[seed] >= 0 or not ok[seed, 8]:
            continue
        label[seed] = regions
        top = 0
        stack[top] = seed
        top += 1
        while top > 0:
            top -= 1
            u = stack[top]
            for m in range(8):
                if ok[u, m]:
                    v = u + offsets[m]
                    if label[v] < 0:
                        label[v] = regions
                        stack[top] = v
                        top += 1
        regions += 1
    return label


class Priorities:
    """PIBT's priorities: each robot's steps since it was given its goal, reset when it arrives.

    A fraction unique to each robot (drawn once from ``seed``) breaks ties, so the order is strict
    and the same on every run.
    """

    def __init__(self, count: int, seed: int = 0):
        self.tiebreak = np.random.default_rng(seed).permutation(count) / max(count, 1)
        self.value = self.tiebreak.copy()

    def update(self, at_goal: np.ndarray) -> None:
        """After a step: robots ``at_goal`` (bool, (N,)) drop to their tie-break, the others gain one."""
        self.value = np.where(at_goal, self.tiebreak, self.value + 1.0)

    def order(self) -> np.ndarray:
        """Robot indices, the highest priority first."""
        return np.argsort(-self.value, kind="stable")


def preferences(values: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(N, 9) each robot's admitted moves, the best-valued first, then −1s.

    Args:
        values: (N, 9) the planner's value of each move (higher is better; ties keep the order of
            :data:`~apf_physics.world.kinematics.ACTIONS`).
        ok: (N, 9) bool, the moves the lattice admits from each robot's node (staying always is).
    """
    ok = ok.copy()
    ok[:, STAY] = True
    ranked = np.argsort(np.where(ok, -np.asarray(values, float), np.inf), axis=1, kind="stable")
    return np.where(np.take_along_axis(ok, ranked, axis=1), ranked, -1).astype(np.intp)


def fleet_moves(lattice: Lattice, nodes: np.ndarray, prefs: np.ndarray, order: np.ndarray,
                pinned: np.ndarray | None = None, contact: float | None = None,
                movers: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(N,) every robot's move (an index of :data:`~apf_physics.world.kinematics.ACTIONS`) this step:
    priority inheritance with backtracking under the shield among robots (see the module docstring).

    Args:
        lattice: The fleet's lattice.
        nodes: (N,) each robot's node (distinct).
        prefs: (N, 9) each robot's moves in its order of preference (:func:`preferences`).
        order: Robot indices, the highest priority first.
        pinned: (N,) bool: robots that stay whatever happens (their episode has ended in a collision).
        contact: The least distance between two robots' centres (default ``2·radius + SAFETY``).
        movers: ``(positions (K, 2), moves (K, 2))`` of other robots whose moves this step are decided
            already (formations' robots among the fleet): every move is checked against them too.
    """
    nodes = np.ascontiguousarray(nodes, np.int64)
    n = len(nodes)
    if contact is None:
        contact = 2 * lattice.world.robot_radius + SAFETY
    pinned = np.zeros(n, np.bool_) if pinned is None else np.ascontiguousarray(pinned, np.bool_)
    if movers is None:
        movers = (np.zeros((0, 2)), np.zeros((0, 2)))
    at = np.ascontiguousarray(np.asarray(movers[0], float).reshape(-1, 2) - np.asarray(lattice.origin))  # in nodes
    return _pibt(nodes, np.ascontiguousarray(prefs, np.int64), np.ascontiguousarray(order, np.int64), pinned,
                 lattice.shape[1], lattice.count, np.ascontiguousarray(_OFFSETS, np.int64), float(contact),
                 at, np.ascontiguousarray(np.asarray(movers[1], float).reshape(-1, 2)))


@kernel
def _closest_squared(px, py, vx, vy):
    """The least squared distance from the origin of a point that starts at ``(px, py)`` and moves
    by ``(vx, vy)`` over the step (two centres moving uniformly, in the frame of one of them)."""
    a = vx * vx + vy * vy
    t = 0.0
    if a > 0:
        t = min(1.0, max(0.0, -(px * vx + py * vy) / a))
    qx, qy = px + t * vx, py + t * vy
    return qx * qx + qy * qy


@kernel
def _clear(i, m, skip, nodes, chosen, occupant, cols, steps, contact, movers, mover_moves):
    """Whether robot ``i``'s move ``m`` keeps ``contact`` from every robot within two nodes, each
    along its decided move or standing (``skip``: the undecided robot it pushes out, or −1), and from
    every mover (positions in node coordinates) along its move."""
    u = nodes[i]
    r0, c0 = u // cols, u % cols
    for k in range(movers.shape[0]):
        px, py = movers[k, 0] - c0, movers[k, 1] - r0
        vx, vy = mover_moves[k, 0] - float(steps[m, 0]), mover_moves[k, 1] - float(steps[m, 1])
        if _closest_squared(px, py, vx, vy) < contact * contact:
            return False
    rows = occupant.shape[0] // cols
    dx, dy = float(steps[m, 0]), float(steps[m, 1])
    for dr in range(-2, 3):
        for dc in range(-2, 3):
            r, c = r0 + dr, c0 + dc
            if (dr == 0 and dc == 0) or r < 0 or r >= rows or c < 0 or c >= cols:
                continue
            k = occupant[r * cols + c]
            if k < 0 or k == skip:
                continue
            kx, ky = 0.0, 0.0
            if chosen[k] >= 0:
                kx, ky = float(steps[chosen[k], 0]), float(steps[chosen[k], 1])
            # the least distance between the two centres over the step, both moving uniformly
            if _closest_squared(float(-dc), float(-dr), dx - kx, dy - ky) < contact * contact:
                return False
    return True


@kernel
def _pibt(nodes, prefs, order, pinned, cols, count, steps, contact, movers, mover_moves):
    """PIBT over one step, iteratively (a stack of robots being pushed); see :func:`fleet_moves`."""
    n = nodes.shape[0]
    occupant = np.full(count, -1, np.int64)
    reserved = np.full(count, -1, np.int64)
    chosen = np.full(n, -1, np.int64)
    target = np.full(n, -1, np.int64)
    cursor = np.zeros(n, np.int64)
    offsets = steps[:, 1] * cols + steps[:, 0]
    for i in range(n):
        occupant[nodes[i]] = i
    for i in range(n):
        if pinned[i]:
            chosen[i] = 8
            target[i] = nodes[i]
            reserved[nodes[i]] = i
    stack = np.empty(n, np.int64)
    for first in order:
        if chosen[first] >= 0:
            continue
        depth = 1
        stack[0] = first
        result = -1      # what the frame just popped returned: -1 nothing, 0 failed, 1 succeeded
        while depth > 0:
            i = stack[depth - 1]
            if result == 1:
                depth -= 1
                continue
            result = -1
            pushed = False
            while cursor[i] < prefs.shape[1]:
                m = prefs[i, cursor[i]]
                cursor[i] += 1
                if m < 0:
                    break
                v = nodes[i] + offsets[m]
                if reserved[v] >= 0:
                    continue
                j = occupant[v]
                if j == i:
                    j = -1
                if j >= 0 and chosen[j] >= 0 and target[j] == nodes[i]:
                    continue          # a swap: the robot there moves into this one's node
                undecided = j >= 0 and chosen[j] < 0
                if not _clear(i, m, j if undecided else -1, nodes, chosen, occupant, cols, steps, contact, movers,
                              mover_moves):
                    continue
                chosen[i] = m
                target[i] = v
                reserved[v] = i
                if undecided:
                    stack[depth] = j
                    depth += 1
                    pushed = True
                else:
                    result = 1
                break
            if pushed:
                continue
            if result == 1:
                depth -= 1
                continue
            chosen[i] = 8            # nothing admitted: stay (and let the pusher try its next move)
            target[i] = nodes[i]
            reserved[nodes[i]] = i
            depth -= 1
            result = 0
    return chosen


@dataclass(frozen=True)
class FleetNodes:
    """A fleet placed on its lattice (:func:`place_fleet`).

    Attributes:
        lattice: The lattice the robots stand on.
        starts: (N,) each robot's start node.
        goals: (N,) each robot's goal node (the node nearest its target).
    """

    lattice: Lattice
    starts: np.ndarray
    goals: np.ndarray


def place_fleet(world: World, fleet: Fleet, distinct_goals: bool = True) -> FleetNodes:
    """The lattice through the first robot's start, and every robot's start and goal node on it.

    Raises:
        UserError: A start off the lattice or not on a free node, two robots starting on one node,
            a target with no free node within the goal tolerance, or cut off from the robot's start,
            two robots with one goal node (``distinct_goals``), or robots too large for one step
            between neighbours.
    """
    where = world.label
    frame = world.frame
    if world.moving:
        raise UserError(f"{where}: a fleet runs among static obstacles only (the world has moving ones)")
    if 2 * world.robot_radius + SAFETY >= 1.0:
        raise UserError(f"{where}: robot radius {show_length(frame, world.robot_radius)} is too large for a fleet: "
                        f"neighbouring robots stand one step ({show_length(frame, 1.0)}) apart")
    lattice = Lattice.of(world, fleet.starts[0])
    starts = lattice.nearest(fleet.starts)
    off = np.flatnonzero(~lattice.on_node(fleet.starts))
    if len(off):
        i = int(off[0])
        raise UserError(f"{where}: {fleet.labels[i]}: start {show_point(frame, fleet.starts[i], 6)} is off the fleet's "
                        f"lattice (nodes one step apart through the first robot's start; the nearest node is "
                        f"{show_point(frame, lattice.points(starts[i:i + 1])[0], 6)})")
    _refuse(where, fleet, ~lattice.free[starts], "start {p} is inside an obstacle, or nearer one (or the map's "
                                                 "edge) than the robot radius and the safety margin", frame)
    _refuse_shared(where, fleet, starts, "start", frame, lattice)
    goals = lattice.nearest(fleet.targets)
    far = np.hypot(*(lattice.points(goals) - fleet.targets).T) > world.goal_tolerance
    _refuse(where, fleet, far | ~lattice.free[goals], "target {t} has no free node of the fleet's lattice within "
                                                      f"the goal tolerance {show_length(frame, world.goal_tolerance)}",
            frame)
    regions = lattice.regions()
    _refuse(where, fleet, regions[starts] != regions[goals], "target {t} cannot be reached from its start {p}", frame)
    if distinct_goals:
        _refuse_shared(where, fleet, goals, "goal", frame, lattice)
    return FleetNodes(lattice, starts, goals)


def _refuse(where: str, fleet: Fleet, bad: np.ndarray, message: str, frame=None) -> None:
    """Raise for the first robot marked ``bad``, ``message`` naming its start ``{p}`` and target ``{t}``
    (in the world file's units)."""
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise UserError(f"{where}: {fleet.labels[i]}: " + message.format(
            p=show_point(frame, fleet.starts[i], 6), t=show_point(frame, fleet.targets[i], 6)))


def _refuse_shared(where: str, fleet: Fleet, nodes: np.ndarray, what: str, frame, lattice: Lattice) -> None:
    """Raise when two robots share a start (or goal) node."""
    _, first, counts = np.unique(nodes, return_index=True, return_counts=True)
    if (counts > 1).any():
        node = nodes[first[np.flatnonzero(counts > 1)[0]]]
        i, j = np.flatnonzero(nodes == node)[:2].tolist()
        raise UserError(f"{where}: {fleet.labels[j]}: its {what} is {fleet.labels[i]}'s (two robots on one cell, "
                        f"{show_point(frame, lattice.points([node])[0], 6)})")


class GoalStream:
    """Each robot's stream of goals in lifelong runs: free nodes of its region, drawn from a generator of
    its own (seeded by ``seed`` and the robot's index), so every planner meets the same goals."""

    def __init__(self, lattice: Lattice, starts: np.ndarray, seed: int):
        regions = lattice.regions()
        self.region = regions[starts]
        self.nodes = {int(r): np.flatnonzero(regions == r) for r in np.unique(self.region)}
        self.rngs = [np.random.default_rng([int(seed), i]) for i in range(len(starts))]

    def next(self, robot: int, now: int) -> int:
        """Robot ``robot``'s next goal, other than ``now`` (where it stands)."""
        choices = self.nodes[int(self.region[robot])]
        while True:
            goal = int(choices[self.rngs[robot].integers(len(choices))])
            if goal != now or len(choices) == 1:
                return goal


class GoalTables:
    """Per-goal tables of a fleet on one lattice (values or distances at every node), least recently
    used dropped beyond a memory budget.

    Args:
        lattice: The lattice the tables are over.
        budget: Most bytes kept; a table is rebuilt when asked for again after it was dropped.

    Attributes:
        built: Tables built so far (rebuilt ones included).
        peak: The most bytes held at once.
    """

    def __init__(self, lattice: Lattice, budget: int):
        self.lattice = lattice
        self.budget = int(budget)
        self._tables: OrderedDict[Hashable, Any] = OrderedDict()
        self._bytes: dict[Hashable, int] = {}
        self.held = 0
        self.built = 0
        self.peak = 0

    def __len__(self) -> int:
        return len(self._tables)

    def get(self, key: Hashable, build: Callable[[], np.ndarray]) -> np.ndarray:
        """The table of ``key``: kept, or ``build()`` (dropping the least recently used beyond the budget)."""
        if key in self._tables:
            self._tables.move_to_end(key)
            return self._tables[key]
        table = build()
        self.built += 1
        size = int(table.nbytes)
        while self._tables and self.held + size > self.budget:
            old, _ = self._tables.popitem(last=False)
            self.held -= self._bytes.pop(old)
        self._tables[key] = table
        self._bytes[key] = size
        self.held += size
        self.peak = max(self.peak, self.held)
        return table


def goal_columns(tables: GoalTables, nodes: np.ndarray, goals: np.ndarray,
                 build: Callable[[int], np.ndarray]) -> np.ndarray:
    """(N, 9) each robot's per-goal table read where each of its moves ends: ``table[ends]`` with the
    table of its goal node (``build(goal)``, kept in ``tables``; robots sharing a goal share it)."""
    nodes, goals = np.asarray(nodes, np.intp), np.asarray(goals, np.intp)
    ends = tables.lattice.ends(nodes)
    out = np.empty(ends.shape)
    order = np.argsort(goals, kind="stable")
    firsts = np.flatnonzero(np.r_[True, goals[order][1:] != goals[order][:-1]])
    for rows in np.split(order, firsts[1:]):
        goal = int(goals[rows[0]])
        table = tables.get(goal, lambda: build(goal))
        out[rows] = table[ends[rows]]
    return out
