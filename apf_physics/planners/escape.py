"""Gradient descent with a boundary-following escape from local minima (Bug2-like).

The classical hand-made remedy for APF traps, so that results can show what learning adds
over it. Two modes per robot:

- **descend**: the gradient-descent step of :class:`GradientPlanner` (a unit step along
  ``−∇U``, backtracked to half and quarter steps).
- **follow**: when descent is trapped (no step lowers U, U made no progress over a window,
  the robot hardly moved over a few steps, or the step would come too close to an
  obstacle), the robot follows the boundary of the obstacles that trap it, at a fixed
  distance (``follow_clearance``), in one turning direction (chosen at the first trap: the
  side facing the target; kept after). It goes back to descent once it is closer to the
  target than the closest point where it was ever trapped, by ``leave_margin``, and a
  descent step is possible there.

Why boundary following rather than a random walk: an APF trap sits in front of an obstacle
(or in a concave pocket) that lies between the robot and the target; walking along that
obstacle's boundary gets around it in a number of steps proportional to its perimeter,
whereas a random walk needs a number of steps that grows with the square of the distance
it must diffuse, and in a concave pocket it falls back into the same minimum. The
remaining failure mode of boundary following, leaving too early and falling back into the
same minimum, is handled like Bug algorithms handle it: a return to an earlier trap point
doubles ``leave_margin`` for that robot, and a full loop around the boundary without
leaving reverses the turning direction.

Every move is checked before it is made: the segment to the next position must keep a
clearance of at least ``robot_radius + safety_margin``; otherwise the direction is turned
away from the obstacle, then the step shortened, and as a last resort the robot stays.
"""

from __future__ import annotations

import numpy as np

from apf_physics.planners.base import Planner
from apf_physics.planners.gradient import GradientPlanner
from apf_physics.world.core import Moment, World

_DESCEND, _FOLLOW = 0, 1


def _rotate(v: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """Rotate (N, 2) vectors counter-clockwise by ``angle`` radians (scalar or (N,))."""
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


class EscapePlanner(Planner):
    """Gradient descent that escapes local minima by following obstacle boundaries.

    See the module docstring for the modes and the reasoning behind them.

    Attributes:
        safety_margin: Clearance kept beyond the robot's radius on every move [units].
        follow_clearance: Distance kept from the followed boundary [units].
        join_distance: Another obstacle (or the map's edge) closer than this joins the followed
            boundary [units].
        leave_margin: How much closer to the target than the best trap point the robot must be
            before it returns to descent; doubled on each return to an earlier trap [units].
        window: Descent steps over which U must drop by ``min_drop`` (else: trapped).
        min_drop: See ``window``.
        creep_steps: Descent steps over which the robot must move ``creep_distance`` (else:
            trapped), unless it is within 2 units of a target.
        creep_distance: See ``creep_steps`` [units].
    """

    name = "escape"
    trap_rule = "oscillation"
    safety_margin = 0.1
    follow_clearance = 0.8
    join_distance = 0.6
    leave_margin = 1.0
    window = 8
    min_drop = 1e-3
    creep_steps = 5
    creep_distance = 1.5
    _turns = np.deg2rad([0, 20, 40, 60, 80, 100, 120, 150, 180])  # toward the free side
    _lengths = (1.0, 0.5, 0.25)

    def reset(self, world: World, positions: np.ndarray) -> None:
        super().reset(world, positions)
        n = len(positions)
        self._descent = GradientPlanner()
        self._now = world.at(0.0)
        self._descent.reset(world, positions)
        self.mode = np.full(n, _DESCEND)
        self._side = np.ones(n)                       # +1: obstacle on the left of the travel, −1: right
        self._best_trap = np.full(n, np.inf)          # closest distance to the target at a trap
        self._margin = np.full(n, float(self.leave_margin))
        self._traps: list[list[np.ndarray]] = [[] for _ in range(n)]
        self._follow_set = np.zeros((n, len(world.obstacles) + 4), bool)  # bodies followed
        self._track: list[list[np.ndarray]] = [[] for _ in range(n)]  # positions while following
        self._history: list[list] = [[] for _ in range(n)]  # (U, position) along the current descent


    def _safe(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return self._now.path_clearance(a, b, 0.1) >= self.world.robot_radius + self.safety_margin

    # -- descent ----------------------------------------------------------------------------
    def _descend(self, positions: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Descent steps for robots ``idx`` and whether each is usable (lowers U, safe)."""
        mask = np.zeros(len(positions), bool)
        mask[idx] = True
        step = self._descent.act(positions, mask, self._now)[idx]
        ok = ~self._descent.stuck()[idx]
        ok &= np.hypot(step[:, 0], step[:, 1]) > 1e-9
        ok[ok] &= self._safe(positions[idx[ok]], positions[idx[ok]] + step[ok])
        return step, ok

    # -- boundary following -----------------------------------------------------------------
    def _fit_bodies(self) -> None:
        """Keep the followed-body marks in step with this step's bodies: among other formations
        (``rollout_formations``) the crowd's discs near a robot come and go, so their number changes;
        the world's own obstacles and the map's edges keep their marks, the crowd's are cleared."""
        bodies = len(self._now.obstacles) + 4
        sets = self._follow_set
        if sets.shape[1] == bodies:
            return
        own = len(self.world.obstacles)
        fitted = np.zeros((len(sets), bodies), bool)
        fitted[:, :own] = sets[:, :own]
        fitted[:, -4:] = sets[:, -4:]
        self._follow_set = fitted

    def _body_distances(self, points: np.ndarray) -> np.ndarray:
        """(P, B) distance from each point to each body: every obstacle (and other robot), then the
        map's four edges. Static obstacles come from the world's index: those farther than its
        reach read the reach (none is followed from so far)."""
        world = self.world
        moved = self._now.obstacles
        out = np.full((len(points), len(moved) + 4), world.reach)
        who, owner, d, _ = world.shapes.pairs(points, with_nearest=False)
        out[who, world.static_numbers[owner]] = d
        for i in list(world.moving) + list(range(len(world.obstacles), len(moved))):   # moving ones, the crowd
            out[:, i] = moved[i].signed_distance(points)[0]
        w, h = world.size
        out[:, -4:] = np.column_stack([points[:, 0], w - points[:, 0], points[:, 1], h - points[:, 1]])
        return out

    def _followed(self, points: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance to the bodies each robot follows, and its gradient direction (away from them).

        A body that comes closer than the followed ones and closer than ``join_distance`` joins
        them: it now blocks the way and the robot follows the union's boundary. Bodies that are
        merely near stay out, so that the robot passes through gaps it fits in and does not
        wander off its obstacle to circle another one nearby (or the whole map's edge).
        """
        h = 0.05
        offsets = np.array([[0, 0], [h, 0], [-h, 0], [0, h], [0, -h]])
        d = self._body_distances((points[:, None, :] + offsets[None]).reshape(-1, 2)).reshape(len(points), 5, -1)
        here = d[:, 0, :]
        sets = self._follow_set[idx]
        followed = np.where(sets, here, np.inf).min(axis=1)
        sets |= here < np.minimum(followed, self.join_distance)[:, None]
        self._follow_set[idx] = sets
        dist = np.where(sets[:, None, :], d, np.inf).min(axis=2)                  # (K, 5)
        with np.errstate(invalid="ignore"):   # no followed body near (inf - inf): the fallback normal below
            grad = np.column_stack([dist[:, 1] - dist[:, 2], dist[:, 3] - dist[:, 4]]) / (2 * h)
        norm = np.hypot(grad[:, 0], grad[:, 1])
        fallback = np.tile([1.0, 0.0], (len(points), 1))
        normal = np.where(norm[:, None] > 1e-9, grad / np.where(norm > 1e-9, norm, 1.0)[:, None], fallback)
        return dist[:, 0], normal

    def _start_following(self, positions: np.ndarray, idx: np.ndarray) -> None:
        p = positions[idx]
        d = self._body_distances(p)
        # Follow the bodies that form the trap: those about as near as the nearest one.
        self._follow_set[idx] = d <= d.min(axis=1, keepdims=True) + 1.0
        _, normal = self._followed(p, idx)
        to_target = self.world.nearest_target(p) - p
        dist = self.world.distance_to_target(p)
        tangent = _rotate(normal, np.pi / 2)  # side +1: the obstacle on the left
        for k, i in enumerate(idx):
            if any(np.hypot(*(p[k] - q)) < 1.5 for q in self._traps[i]):
                # Left too early and fell back into the same minimum: go further next time.
                self._margin[i] *= 2.0
            if not self._traps[i]:
                # The turning direction is chosen once, at the first trap (the side whose
                # tangent points more toward the target), and kept: choosing again at each
                # new trap can send the robot back the way it came.
                self._side[i] = 1.0 if np.dot(tangent[k], to_target[k]) >= 0 else -1.0
            self._traps[i].append(p[k].copy())
            self._best_trap[i] = min(self._best_trap[i], dist[k])
            self._track[i] = []
        self.mode[idx] = _FOLLOW

    def _follow(self, positions: np.ndarray, idx: np.ndarray) -> np.ndarray:
        p = positions[idx]
        clearance, normal = self._followed(p, idx)
        side = self._side[idx]
        tangent = _rotate(normal, side * np.pi / 2)
        # Steer back to the followed clearance: toward the obstacle when too far, away when too close.
        correction = np.clip(self.follow_clearance - clearance, -1.0, 1.0)
        heading = tangent + 1.5 * correction[:, None] * normal
        heading /= np.hypot(heading[:, 0], heading[:, 1])[:, None]
        # Candidate moves, in order of preference: the heading turned progressively toward the
        # free side (away from the obstacle), each at decreasing lengths.
        na, nl = len(self._turns), len(self._lengths)
        turns = -side[:, None] * self._turns[None, :]                               # (K, A)
        dirs = _rotate(np.repeat(heading, na, axis=0), turns.ravel()).reshape(len(idx), na, 2)
        lengths = np.asarray(self._lengths)
        moves = dirs[:, None, :, :] * lengths[None, :, None, None]                  # (K, L, A, 2)
        ends = p[:, None, None, :] + moves
        starts = np.broadcast_to(p[:, None, None, :], ends.shape)
        ok = self._safe(starts.reshape(-1, 2), ends.reshape(-1, 2)).reshape(len(idx), nl, na)
        step = np.zeros((len(idx), 2))
        for k in range(len(idx)):
            found = np.argwhere(ok[k])
            if len(found):
                li, ai = found[0]
                step[k] = moves[k, li, ai]
        return step

    # -- the policy -------------------------------------------------------------------------
    def act(self, positions: np.ndarray, active: np.ndarray, moment: Moment | None = None) -> np.ndarray:
        positions = np.asarray(positions, float).reshape(-1, 2)
        self._now = self._moment(moment)   # the world at this step, for every query of the step
        self._fit_bodies()
        step = np.zeros_like(positions)
        u = self._now.potential(positions)

        # Followers that are now closer to the target than their best trap leave the boundary
        # if descent can move from here.
        following = np.flatnonzero(active & (self.mode == _FOLLOW))
        if len(following):
            closer = self.world.distance_to_target(positions[following]) < self._best_trap[following] - self._margin[following]
            candidates = following[closer]
            if len(candidates):
                _, ok = self._descend(positions, candidates)
                leaving = candidates[ok]
                self.mode[leaving] = _DESCEND
                for i in leaving:
                    self._history[i] = []

        descending = np.flatnonzero(active & (self.mode == _DESCEND))
        if len(descending):
            move, ok = self._descend(positions, descending)
            far = self.world.distance_to_target(positions[descending]) > 2.0
            for k, i in enumerate(descending):
                hist = self._history[i]
                hist.append((u[i], positions[i].copy()))
                if len(hist) > self.window and (min(h[0] for h in hist[-self.window:])
                                                > min(h[0] for h in hist[:-self.window]) - self.min_drop):
                    ok[k] = False  # U no longer drops
                if far[k] and len(hist) > self.creep_steps and (
                        np.hypot(*(hist[-1][1] - hist[-1 - self.creep_steps][1])) < self.creep_distance):
                    # Zigzagging along an obstacle with shortened steps: U still drops a
                    # little each step, but the robot hardly moves.
                    ok[k] = False
            step[descending[ok]] = move[ok]
            trapped = descending[~ok]
            if len(trapped):
                self._start_following(positions, trapped)

        following = np.flatnonzero(active & (self.mode == _FOLLOW))
        if len(following):
            p = positions[following]
            # Back on its own track without having left the boundary: a full loop. Turn the
            # other way.
            for k, i in enumerate(following):
                track = self._track[i]
                if len(track) > 15 and np.min(np.hypot(*(np.asarray(track[:-15]) - p[k]).T)) < 0.75:
                    self._side[i] = -self._side[i]
                    track.clear()
                track.append(p[k].copy())
            step[following] = self._follow(positions, following)
        return step
