"""Formations (Model §3): where followers start, and the rule by which each follower moves.

Follower i moves by its own potential field: attraction to its anchor (in a line, the point ``spacing`` back along the
path of the robot it follows, so that the chain retraces a path known to be free; for other
shapes, its slot relative to the leader's heading), repulsion from the obstacles, and
repulsion from the other robots, except the one it follows (as the thesis assigns them:
follower 1 is repelled by follower 2, follower 2 by the leader). Each control step it
takes the best of its nine neighbouring moves; when the best would make it collide (with
the robot it follows, another robot's move this step, an obstacle or the map's edge) it
takes the next best, and so on (the thesis's "second best" rule, carried on until a safe
move is found). Followers decide in chain order, each knowing the moves already chosen
ahead of it, so that all robots then move at the same time without touching.

This is a policy: it produces displacements; the physics knows nothing of it. It lives
beside the engine rather than with the planners because every formation runs it, whoever
steers the leader (a planner, a Gymnasium agent).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from apf_physics.control.shield import ACTIONS, SAFETY
from apf_physics.errors import UserError
from apf_physics.world.field import repulsive, repulsive_term
from apf_physics.common.geometry import near_any, swept_distance
from apf_physics.world.core import FormationSpec, World
from apf_physics.world.io.units import show_length, show_point


def formation_spec(world: World) -> FormationSpec:
    """The world's formation, or the thesis's default line of two followers."""
    return world.formation if world.formation is not None else FormationSpec()


def formation_offsets(spec: FormationSpec) -> np.ndarray | None:
    """``(n, 2)`` slot offsets ``[back, left]`` relative to the leader's heading, or None for a line."""
    n = spec.followers
    if spec.shape == "line":
        return None
    if spec.shape == "wedge":
        rows = (np.arange(n) // 2 + 1) * spec.spacing
        side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
        return np.column_stack([rows, side * rows])
    return np.asarray(spec.offsets, dtype=float).reshape(n, 2)


def link_lengths(positions: np.ndarray, followed: Sequence[int]) -> np.ndarray:
    """(..., F) the distance of each follower to the robot it follows (its link, Model §3).

    Args:
        positions: (..., m, 2) a formation's robots, the leader first (m = 1 + F).
        followed: For each follower, the robot it follows (:attr:`FormationSpec.followed`).
    """
    positions = np.asarray(positions, float)
    d = positions[..., 1:, :] - positions[..., np.asarray(followed, np.intp), :]
    return np.hypot(d[..., 0], d[..., 1])


def links_in_range(positions: np.ndarray, followed: Sequence[int], comm_range: float) -> np.ndarray:
    """(..., F) bool: each link within the communication range (:func:`link_lengths` ≤ ``comm_range``)."""
    return link_lengths(positions, followed) <= comm_range


def formation_success(reached: bool, positions: np.ndarray, followed: Sequence[int], comm_range: float) -> bool:
    """A formation's success (Model §3): its leader reached the target and, where the robots
    stand (``positions``, (m, 2)), every follower is within ``comm_range`` of the robot it follows."""
    return bool(reached) and bool(np.all(links_in_range(positions, followed, comm_range)))


ROUNDING = 1e-9
"""A safety margin short by less than this is rounding, and safe (:meth:`FollowerController.act`)."""


class FollowerController:
    """Moves of the followers of one formation.

    Args:
        world: The world (obstacles, field parameters).
        spec: The formation.
        katt: Attraction gain towards the anchor (default: the world's ``katt``).
        robot_repulsion_range: Surface distance under which another robot repels [units].
    """

    def __init__(self, world: World, spec: FormationSpec, katt: float | None = None,
                 robot_repulsion_range: float | None = None):
        self.world = world
        self.spec = spec
        self.katt = world.field.katt if katt is None else katt
        self.krep = world.field.krep
        self.u_max = world.field.u_max
        self.robot_range = 0.5 * spec.spacing if robot_repulsion_range is None else robot_repulsion_range
        # Obstacles repel followers over a short range only: the trail they retrace is already
        # clear, and a wide repulsion (Table 2/4's p0 = 3) would push them off it and behind.
        self.obstacle_field = replace(world.field, p0=min(world.field.p0, 0.5))
        self.offsets = formation_offsets(spec)
        r = world.robot_radius
        self.contact = 2 * r + SAFETY
        self.fractions = np.array([0.25, 0.5, 0.75, 1.0])

    HEADING_SMOOTHING = 0.8  # share of the previous heading kept each step (slots swing less)

    def reset(self, positions: np.ndarray) -> None:
        """Start a new run with robots at ``positions`` (leader first)."""
        positions = np.asarray(positions, dtype=float)
        self.trails = [[p.copy()] for p in positions]
        target = self.world.nearest_target(positions[0])[0]
        to_target = target - positions[0]
        self.heading = to_target / max(np.hypot(*to_target), 1e-12)

    def _trail_point(self, robot: int, head: np.ndarray, back: float) -> np.ndarray:
        """The point ``back`` units along ``robot``'s trail behind ``head`` (its next position)."""
        points = [head] + self.trails[robot][::-1]
        remaining = back
        for a, b in zip(points[:-1], points[1:]):
            seg = float(np.hypot(*(b - a)))
            if seg >= remaining:
                return a + (b - a) * (remaining / seg)
            remaining -= seg
        return points[-1]

    def anchors(self, positions: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """Where each follower is pulled to: ``spacing`` back along the trail of the robot it
        follows (line), or its slot relative to the leader's heading."""
        if self.offsets is None:
            return np.array([self._trail_point(i, positions[i], self.spec.spacing) for i in range(len(positions) - 1)])
        h = heading / max(np.hypot(*heading), 1e-12)
        left = np.array([-h[1], h[0]])
        return positions[0] - self.offsets[:, :1] * h + self.offsets[:, 1:] * left

    def _clear_line(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True when a robot could move straight from ``a`` to ``b`` without nearing an obstacle."""
        return bool(self.world.path_clearance(a[None], b[None], 0.25)[0] >= self.world.robot_radius + SAFETY)

    def potential(self, follower: int, points: np.ndarray, positions: np.ndarray, anchor: np.ndarray) -> np.ndarray:
        """Follower ``follower`` (1-based robot index)'s field at candidate ``points``."""
        d = np.hypot(*(points - anchor).T)
        u = 0.5 * self.katt * d * d
        u += repulsive(points, self.world.obstacles, self.obstacle_field)
        followed = follower - 1 if self.offsets is None else None
        for j in range(len(positions)):
            if j == follower or j == followed:
                continue
            surface = np.hypot(*(points - positions[j]).T) - 2 * self.world.robot_radius
            u += repulsive_term(surface, self.krep, self.robot_range, self.u_max)
        return u

    def act(self, positions: np.ndarray, leader_move: np.ndarray, world: World | None = None) -> np.ndarray:
        """Moves of all followers given every robot's position and the leader's chosen move.

        Args:
            positions: ``(1 + n, 2)``, the leader first.
            leader_move: The leader's displacement this step.
            world: The world as it stands now (default the controller's), e.g. with the
                robots of other formations in it (:meth:`World.among`): moves must keep clear
                of them too.

        Returns:
            ``(n, 2)`` displacements.
        """
        world = world if world is not None else self.world
        n = len(positions) - 1
        moves = np.zeros((n + 1, 2))
        moves[0] = leader_move
        speed = np.hypot(*leader_move)
        if speed > 0:
            h = self.HEADING_SMOOTHING * self.heading + (1 - self.HEADING_SMOOTHING) * leader_move / speed
            self.heading = h / max(np.hypot(*h), 1e-12)
        heading = self.heading
        r = self.world.robot_radius
        for i in range(1, n + 1):
            # Pulled towards where the robots ahead will be after this step (their moves are
            # already decided), so that the chain keeps up with a leader moving diagonally.
            ahead = positions + moves
            anchor = self.anchors(ahead, heading)[i - 1]
            if self.offsets is not None and not self._clear_line(positions[i], anchor):
                # The slot is behind an obstacle: fall in behind the leader on its trail
                # (known to be free) until the slot is in clear sight again.
                anchor = self._trail_point(0, ahead[0], float(np.hypot(*self.offsets[i - 1])))
            candidates = positions[i] + ACTIONS                           # (9, 2)
            # other robots where they will be: ahead in the order, after their decided move
            u = self.potential(i, candidates, ahead, anchor)
            # Safe: every point along the move keeps clear of obstacles and the edge, and
            # the swept distance to every robot stays above contact (robots ahead of this
            # one move as already decided; those behind have not moved yet).
            path = positions[i] + self.fractions[None, :, None] * ACTIONS[:, None, :]   # (9, 4, 2)
            clear = world.clearance(path.reshape(-1, 2)).reshape(9, -1).min(axis=1)
            margin = clear - (r + SAFETY)
            for j in range(n + 1):
                if j == i:
                    continue
                other_move = moves[j] if j < i else np.zeros(2)
                dist = swept_distance(positions[i], ACTIONS, positions[j], other_move)
                margin = np.minimum(margin, dist - self.contact)
            # a margin within rounding of zero is safe: robots placed exactly the safe distance apart
            # and moving alike keep it, whatever rounding the physics leaves in their positions
            safe = margin >= -ROUNDING
            order = np.argsort(u, kind="stable")
            safe_order = order[safe[order]]
            if len(safe_order):
                moves[i] = ACTIONS[safe_order[0]]
            else:  # nothing is safe: keep as much room as possible from everything
                moves[i] = ACTIONS[int(np.argmax(margin))]
        for trail, p, move in zip(self.trails, positions, moves):
            trail.append(p + move)
        return moves[1:]


def initial_followers(world: World, spec: FormationSpec, leader: np.ndarray) -> np.ndarray:
    """Free start positions behind the leader (away from the nearest target), one per follower.

    Each follower takes the free position nearest to where the formation wants it (``spacing``
    behind the robot it follows, or its slot), among positions within ``comm_range`` of the
    robot it follows and clear of the robots already placed.

    Raises:
        UserError: No free position within range fits a follower.
    """
    leader = np.asarray(leader, dtype=float)
    target = world.nearest_target(leader)[0]
    back = leader - target
    back = back / np.hypot(*back) if np.hypot(*back) > 0 else np.array([-1.0, 0.0])
    left = np.array([-back[1], back[0]])
    offsets = formation_offsets(spec)
    r = world.robot_radius
    placed = [leader]
    angles = np.deg2rad(np.arange(0, 360, 10))
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    for i in range(spec.followers):
        anchor = placed[-1] if offsets is None else leader
        if offsets is None:
            wanted = anchor + spec.spacing * back
        else:  # offsets are [back, left] relative to the heading (towards the target)
            wanted = leader + offsets[i, 0] * back - offsets[i, 1] * left
        radii = np.linspace(2 * r + SAFETY, spec.comm_range, 12)
        candidates = np.vstack([wanted[None], (anchor + radii[:, None, None] * ring[None]).reshape(-1, 2)])
        ok = world.is_free(candidates, r + SAFETY)
        ok &= np.hypot(*(candidates - anchor).T) <= spec.comm_range
        for q in placed:
            ok &= np.hypot(*(candidates - q).T) >= 2 * r + SAFETY
        if not ok.any():
            raise UserError(f"{world.source or world.name}: no free position for follower {i + 1} near the leader "
                            f"at {show_point(world.frame, leader, 3)} (within comm_range "
                            f"{show_length(world.frame, spec.comm_range)})")
        good = candidates[ok]
        placed.append(good[np.argmin(np.hypot(*(good - wanted).T))])
    return np.array(placed[1:], float).reshape(-1, 2)   # (0, 2) for a robot alone


class FormationTeam:
    """The followers of a batch of formations, one per slot of a :class:`~apf_physics.sim.engine.Stepper`.

    Whoever steers the leaders (a planner in ``eval``, an agent in ``Formation-v0``), the
    followers are moved the same way: this object turns the leaders' moves into every
    robot's command, with one :class:`FollowerController` per slot.

    Args:
        spec: The formation (the same in every slot).
        num_slots: Number of formations.
    """

    def __init__(self, spec: FormationSpec, num_slots: int):
        self.spec = spec
        self.robots = spec.followers + 1
        self.followed = spec.followed
        self.controllers: list[FollowerController | None] = [None] * int(num_slots)

    def starts(self, world: World, leaders: np.ndarray) -> np.ndarray:
        """(k, m, 2) positions of whole formations whose leaders start at ``leaders`` (k, 2).

        Raises:
            UserError: No free position within range fits a follower.
        """
        leaders = np.asarray(leaders, float).reshape(-1, 2)
        return np.stack([np.vstack([p, initial_followers(world, self.spec, p)]) for p in leaders])

    def reset(self, slots: np.ndarray, worlds: list[World], positions: np.ndarray) -> None:
        """Start formations in ``slots`` (in ``worlds``) at ``positions`` (k, m, 2)."""
        for slot, world, robots in zip(np.asarray(slots).tolist(), worlds, positions):
            controller = FollowerController(world, self.spec)
            controller.reset(robots)
            self.controllers[slot] = controller

    def commands(self, positions: np.ndarray, leader_moves: np.ndarray, active: np.ndarray) -> np.ndarray:
        """(S, m, 2) every robot's move: the leaders' as given, the followers' by their rule (0 where inactive)."""
        out = np.zeros(positions.shape)
        for slot in np.flatnonzero(active).tolist():
            out[slot, 0] = leader_moves[slot]
            out[slot, 1:] = self.controllers[slot].act(positions[slot], leader_moves[slot])
        return out

    def links(self, positions: np.ndarray) -> np.ndarray:
        """(..., F) distance of each follower to the robot it follows (:func:`link_lengths`)."""
        return link_lengths(positions, self.followed)


def right_of_way(world: World, positions: np.ndarray, moves: np.ndarray, order: np.ndarray, t: float = 0.0,
                 keep: np.ndarray | None = None, exists: np.ndarray | None = None) -> np.ndarray:
    """Moves of robots that must not touch one another, decided one robot at a time in ``order``.

    Each robot keeps its proposed move when its disc sweeps clear (by :data:`SAFETY`) of the
    moves already decided and of the robots not decided yet where they stand; otherwise it
    takes the nearest of the nine moves that does and keeps clear of the obstacles, or stays.
    Because every robot decided before another keeps clear of that one standing still,
    staying is always safe: no two robots ever touch, whatever the planners proposed.

    Args:
        world: The world (obstacles at step ``t``).
        positions: (R, 2) robot centres.
        moves: (R, 2) proposed moves.
        order: Robot indices, highest priority first (robots left out stay).
        t: The step.
        keep: (R,) bool, robots whose proposal is kept without checks (default none).
        exists: (R,) bool, the robots that exist (default all); the others are ignored.

    Returns:
        (R, 2) the moves.
    """
    contact = 2 * world.robot_radius + SAFETY
    out = np.zeros_like(moves)
    decided = np.zeros(len(positions), bool)
    exists = np.ones(len(positions), bool) if exists is None else np.asarray(exists, bool)
    for k in np.asarray(order).tolist():
        others = np.flatnonzero(exists & (np.arange(len(positions)) != k))
        if keep is not None and keep[k]:
            out[k], decided[k] = moves[k], True
            continue
        # the proposal first, then the nine moves from the nearest to the proposal
        candidates = np.vstack([moves[k], ACTIONS[np.argsort(np.hypot(*(ACTIONS - moves[k]).T), kind="stable")]])
        other_moves = np.where(decided[others, None], out[others], 0.0)
        gap = swept_distance(positions[k][None, None], candidates[:, None], positions[others][None],
                             other_moves[None]) if len(others) else np.full((len(candidates), 1), np.inf)
        clear_of_robots = np.all(gap >= contact, axis=1)
        path = positions[k] + np.array([0.25, 0.5, 0.75, 1.0])[None, :, None] * candidates[1:, None, :]
        room = world.clearance(path.reshape(-1, 2), t).reshape(len(candidates) - 1, -1).min(axis=1)
        clear_of_obstacles = np.concatenate([[True], room >= world.robot_radius + SAFETY])
        ok = np.flatnonzero(clear_of_robots & clear_of_obstacles)
        out[k] = candidates[ok[0]] if len(ok) else 0.0
        decided[k] = True
    return out


class Formations:
    """Several formations in one world, each to its own target, as one crowd of stepper slots.

    Formation ``f`` is slot ``f``; its robots are the first ``1 + followers`` of the slot's
    ``robots`` (the others are absent). Each formation's followers follow by their own rule,
    keeping clear of the other formations' robots as they stand; then every move goes
    through :func:`right_of_way`, in priority order (formation order, each leader before
    its followers), so no two robots ever touch. Giving way can hold a follower back: a
    leader whose follower has fallen more than :attr:`slack` of the communication range
    behind waits for it. A formation whose leader makes no progress
    for :attr:`window` steps while another formation's robot is near is in a deadlock: it
    takes the first place in the order for :attr:`boost` steps (the others give way); each
    such event is counted in :attr:`deadlocks`.

    Args:
        world: A world with ``formations``.
    """

    window = 20      # steps without progress (and someone near) that make a deadlock
    progress = 0.5   # the distance to the target a leader must gain within the window [units]
    near = 3.0       # another formation's robot this close to the leader [units]
    boost = 15       # steps a deadlocked formation goes first
    slack = 0.8      # share of comm_range beyond which a leader waits for its followers

    def __init__(self, world: World):
        self.world = world
        self.tasks = world.formations
        self.count = len(self.tasks)
        self.worlds = [world.formation_world(f) for f in range(self.count)]
        self.sizes = [task.spec.followers + 1 for task in self.tasks]
        self.robots = max(self.sizes)
        self.present = np.zeros((self.count, self.robots), bool)
        for f, size in enumerate(self.sizes):
            self.present[f, :size] = True
        self.followed = [task.spec.followed for task in self.tasks]

    def starts(self) -> np.ndarray:
        """(F, m, 2) every robot's start: each leader at its start, its followers behind it, clear of the others
        (and of the bystanders).

        Raises:
            UserError: A follower finds no free position near its leader.
        """
        out = np.zeros((self.count, self.robots, 2))
        placed = np.concatenate([np.array([task.start for task in self.tasks]).reshape(-1, 2), self.bystanders])
        for f, task in enumerate(self.tasks):
            others = np.delete(placed, f, axis=0)
            followers = initial_followers(self.worlds[f].among(others), task.spec, task.start)
            out[f, 0], out[f, 1:self.sizes[f]] = task.start, followers
            out[f, self.sizes[f]:] = task.start          # absent robots: anywhere (they never take part)
            placed = np.vstack([placed, followers])
        return out

    def reset(self, positions: np.ndarray) -> None:
        """Start every formation at ``positions`` (F, m, 2)."""
        self.controllers = []
        for f in range(self.count):
            controller = FollowerController(self.worlds[f], self.tasks[f].spec)
            controller.reset(positions[f, :self.sizes[f]])
            self.controllers.append(controller)
        self.best = np.array([float(w.distance_to_target(p[None, 0])[0]) for w, p in zip(self.worlds, positions)])
        self.since = np.zeros(self.count, np.intp)
        self.first_until = np.full(self.count, -1)
        self.deadlocks = np.zeros(self.count, np.intp)

    reach = 12.0     # other robots farther than this from all of a formation's robots do not count for it

    bystanders: np.ndarray = np.zeros((0, 2))
    """(B, 2) robots of no formation (a fleet's, :mod:`apf_physics.control.fleet`), where they stand this
    step: every formation keeps clear of them as of the others' robots, and they are not moved here."""

    def others(self, positions: np.ndarray, f: int) -> np.ndarray:
        """(K, 2) the robots of every formation but ``f``, and the bystanders."""
        mask = self.present.copy()
        mask[f] = False
        return np.concatenate([positions[mask], self.bystanders]) if len(self.bystanders) else positions[mask]

    def view(self, positions: np.ndarray, f: int) -> World:
        """Formation ``f``'s world with the other formations' robots near it in it, as they stand.

        Near: within :attr:`reach` (beyond any field's repulsion range plus an observation
        window and a step) of one of its robots, found through a spatial hash, so that a
        leader's field costs as much among 16 formations as among 2.
        """
        others = self.others(positions, f)
        return self.worlds[f].among(others[near_any(others, positions[f, :self.sizes[f]], self.reach)])

    def commands(self, positions: np.ndarray, leader_moves: np.ndarray, active: np.ndarray, step: int) -> np.ndarray:
        """(F, m, 2) every robot's move: leaders as proposed, followers by their rule, all given right of way."""
        proposed = np.zeros(positions.shape)
        links = self.links(positions)
        for f in np.flatnonzero(active).tolist():
            behind = len(links[f]) and links[f].max() > self.slack * self.tasks[f].spec.comm_range
            proposed[f, 0] = 0.0 if behind else leader_moves[f]
            size = self.sizes[f]
            proposed[f, 1:size] = self.controllers[f].act(positions[f, :size], leader_moves[f], self.view(positions, f))
        order = sorted(range(self.count), key=lambda f: (self.first_until[f] < step, f))
        robots = np.array([f * self.robots + r for f in order if active[f] for r in range(self.sizes[f])], np.intp)
        # the bystanders take part as robots that stand (left out of the order)
        stand = self.bystanders
        flat = right_of_way(self.world, np.concatenate([positions.reshape(-1, 2), stand]),
                            np.concatenate([proposed.reshape(-1, 2), np.zeros_like(stand)]), robots, step,
                            exists=np.concatenate([self.present.ravel(), np.ones(len(stand), bool)]))
        return flat[:positions.shape[0] * positions.shape[1]].reshape(positions.shape)

    def watch(self, positions: np.ndarray, active: np.ndarray, step: int) -> None:
        """After a step: note each leader's progress; a stalled leader with company is in a deadlock."""
        for f in np.flatnonzero(active).tolist():
            distance = float(self.worlds[f].distance_to_target(positions[f, :1])[0])
            if distance < self.best[f] - self.progress:
                self.best[f], self.since[f] = distance, 0
                continue
            self.since[f] += 1
            company = self.others(positions, f)
            crowded = len(company) and np.min(np.hypot(*(company - positions[f, 0]).T)) < self.near
            if self.since[f] >= self.window and crowded and self.first_until[f] < step:
                self.deadlocks[f] += 1
                self.first_until[f] = step + self.boost
                self.since[f] = 0

    def links(self, positions: np.ndarray) -> list[np.ndarray]:
        """Per formation, the distance of each follower to the robot it follows (:func:`link_lengths`)."""
        return [link_lengths(positions[f, :self.sizes[f]], self.followed[f]) for f in range(self.count)]
