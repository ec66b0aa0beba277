"""Formations (SPEC §3): where followers start, and the rule by which each follower moves.

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

import numpy as np

from apf_physics.actions import ACTIONS, SAFETY
from apf_physics.errors import UserError
from apf_physics.field import repulsive, repulsive_term
from apf_physics.world import FormationSpec, World


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


def swept_distance(p: np.ndarray, dp: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """Smallest distance between two points moving linearly over one step (broadcasting)."""
    r0 = p - q
    dr = dp - dq
    a = np.sum(dr * dr, axis=-1)
    t = np.clip(np.where(a > 0, -np.sum(r0 * dr, axis=-1) / np.where(a > 0, a, 1.0), 0.0), 0.0, 1.0)
    closest = r0 + t[..., None] * dr
    return np.sqrt(np.sum(closest * closest, axis=-1))


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
        target = self.world.targets[np.argmin(np.hypot(*(self.world.targets - positions[0]).T))]
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

    def act(self, positions: np.ndarray, leader_move: np.ndarray) -> np.ndarray:
        """Moves of all followers given every robot's position and the leader's chosen move.

        Args:
            positions: ``(1 + n, 2)``, the leader first.
            leader_move: The leader's displacement this step.

        Returns:
            ``(n, 2)`` displacements.
        """
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
            u = self.potential(i, candidates, positions, anchor)
            # Safe: every point along the move keeps clear of obstacles and the edge, and
            # the swept distance to every robot stays above contact (robots ahead of this
            # one move as already decided; those behind have not moved yet).
            path = positions[i] + self.fractions[None, :, None] * ACTIONS[:, None, :]   # (9, 4, 2)
            clear = self.world.clearance(path.reshape(-1, 2)).reshape(9, -1).min(axis=1)
            margin = clear - (r + SAFETY)
            for j in range(n + 1):
                if j == i:
                    continue
                other_move = moves[j] if j < i else np.zeros(2)
                dist = swept_distance(positions[i], ACTIONS, positions[j], other_move)
                margin = np.minimum(margin, dist - self.contact)
            safe = margin >= 0
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
    target = world.targets[np.argmin(np.hypot(*(world.targets - leader).T))]
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
                            f"at {np.round(leader, 3).tolist()} (within comm_range {spec.comm_range:g})")
        good = candidates[ok]
        placed.append(good[np.argmin(np.hypot(*(good - wanted).T))])
    return np.array(placed[1:])


class FormationTeam:
    """The followers of a batch of formations, one per slot of a :class:`~apf_physics.engine.Stepper`.

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
        """(..., F) distance of each follower to the robot it follows."""
        followers = positions[..., 1:, :]
        ahead = positions[..., self.followed, :]
        return np.hypot(*(followers - ahead).transpose(-1, *range(followers.ndim - 1)))
