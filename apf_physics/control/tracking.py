"""Tracking: holonomic plans driven by unicycle robots, vectorised over robots.

Every planner of the package (``gradient``, ``escape``, ``astar``, ``dqn``) decides a
displacement per control step for a robot that can move in any direction. A unicycle robot
(:mod:`apf_physics.world.kinematics`) cannot: this module turns such plans into ``(v, ω)`` commands
within its :class:`~apf_physics.world.kinematics.UnicycleLimits`.

- :func:`pursue`: pure pursuit of one waypoint per robot. The robot drives the circular arc
  that leaves along its heading and passes through the waypoint (curvature ``2 sin α / L``
  for a waypoint at distance ``L`` and bearing ``α``), as far along it as the limits allow in
  one step and never past the waypoint; a waypoint more than ``turn_in_place`` off its heading
  is first turned to on the spot.
- :func:`track_moves`: a planner's moves ``(N, 2)`` as waypoints (where the holonomic robot
  would be after the step): the planner replans every step from where the unicycle is.
- :class:`PathFollower`: pure pursuit along whole paths ``(N, P, 2)`` with a lookahead
  distance (a path of unit moves, an A* path): what :func:`cross_track_error` measures against.
- :class:`UnicycleFollowers`: the thesis's follower rule (Model §3) for wheeled robots. The
  holonomic rule (:class:`~apf_physics.control.formation.FollowerController`) chooses each follower's
  safe neighbouring position given the leader's move (for a unicycle leader, the chord of the
  arc it drives); that position is the follower's waypoint, tracked by :func:`pursue`.
  :func:`slot_points` gives the slots of a wedge or offsets formation relative to the leader's
  actual heading θ.

Units: lengths in units, time in control steps, angles in radians (counter-clockwise), as in
:mod:`apf_physics.world.kinematics`. States are ``(N, 5)`` ``(x, y, θ, v, ω)``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from apf_physics.control.shield import SAFETY
from apf_physics.control.formation import FollowerController, link_lengths
from apf_physics.world.kinematics import UnicycleLimits, arc_displacement, arc_points, to_robot_frame
from apf_physics.world.core import FormationSpec, Moment, World

ARRIVE = 1e-3
"""A waypoint this close to the robot [units] is reached: the robot stops."""
TURN_IN_PLACE = np.pi / 4
"""A waypoint farther off the heading than this [rad] is turned to on the spot before driving."""
LOOKAHEAD = 0.75
"""Default lookahead of :class:`PathFollower` along its path [units]."""
LINK_MARGIN = 0.75
"""How far within the communication range :meth:`UnicycleFollowers.leader_cap` stops the leader [units]."""
CHECK_SAMPLES = 16
"""Points (after the start) at which :class:`UnicycleFollowers` and :func:`track_safely` check an arc."""
ALIGNED = 1e-6
"""Bearing [rad] within which :func:`track_safely` counts a robot as facing its waypoint: it drives
the straight chord (up to ``L·ALIGNED/2`` off it) rather than an arc that must be checked."""


def pursue(state: np.ndarray, waypoint: np.ndarray, limits: UnicycleLimits = UnicycleLimits(),
           turn_in_place: float = TURN_IN_PLACE, arrive: float = ARRIVE,
           speed_cap: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(v, ω)`` (N,), (N,) driving each robot toward its waypoint within ``limits``.

    The arc through the waypoint, tangent to the heading, is driven in one step by ``v = L·α /
    sin α`` (its length) and ``ω = 2α`` (its turn): both are scaled down together, keeping the
    arc, until within the speed and turn-rate limits; then the acceleration limit (against the
    state's ``v``, ``ω``) is applied to ``v`` and ``ω`` re-derived from the arc's curvature, and
    clipped last. A waypoint behind the robot (``|α| > turn_in_place``) is turned to on the
    spot; one within ``arrive`` stops the robot. Forward driving only.

    Args:
        state: (N, 5) ``(x, y, θ, v, ω)``; ``v``, ``ω`` the previous command.
        waypoint: (N, 2) where each robot should go.
        limits: The robots' limits.
        turn_in_place: Bearing [rad] beyond which the robot turns on the spot first (small values
            make it drive straight chords only, exactly the holonomic moves).
        arrive: Distance [units] within which a waypoint is reached.
        speed_cap: (N,) a lower top speed for this step [units/step] (e.g. to be able to stop
            at a path's end), or None.
    """
    state = np.asarray(state, float).reshape(-1, 5)
    local = to_robot_frame(state, np.asarray(waypoint, float).reshape(-1, 2))
    distance = np.hypot(local[:, 0], local[:, 1])
    alpha = np.arctan2(local[:, 1], local[:, 0])
    sin_a = np.sin(alpha)
    small = np.abs(alpha) < 1e-9
    length = np.where(small, distance, distance * alpha / np.where(small, 1.0, sin_a))     # arc length
    turn = 2.0 * alpha
    scale = np.minimum.reduce([np.ones_like(distance),
                               limits.max_speed / np.maximum(length, 1e-300),
                               limits.max_turn_rate / np.maximum(np.abs(turn), 1e-300)])
    v = scale * length
    curvature = np.where(distance > 0, 2.0 * sin_a / np.maximum(distance, 1e-300), 0.0)
    spin = np.abs(alpha) > turn_in_place
    v = np.where(spin | (distance <= arrive), 0.0, v)
    if speed_cap is not None:
        v = np.minimum(v, speed_cap)
    v, _ = limits.clamp(v, 0.0, state[:, 3], None)
    # on the arc through the waypoint; turning on the spot (or, when the robot cannot stop yet,
    # as sharply as it can) toward a waypoint behind it
    omega = np.where(spin, np.where(v > 0, np.sign(alpha) * limits.max_turn_rate, alpha), v * curvature)
    return limits.clamp(v, omega, None, state[:, 4])


def track_moves(state: np.ndarray, moves: np.ndarray, limits: UnicycleLimits = UnicycleLimits(),
                turn_in_place: float = TURN_IN_PLACE) -> tuple[np.ndarray, np.ndarray]:
    """``(v, ω)`` for holonomic moves ``(N, 2)`` planned from each unicycle's position: :func:`pursue`
    of ``position + move`` (a zero move stops the robot)."""
    state = np.asarray(state, float).reshape(-1, 5)
    return pursue(state, state[:, :2] + np.asarray(moves, float).reshape(-1, 2), limits, turn_in_place)


def track_safely(state: np.ndarray, moves: np.ndarray, where: Moment, limits: UnicycleLimits = UnicycleLimits(),
                 turn_in_place: float = TURN_IN_PLACE, speed_cap: np.ndarray | float | None = None,
                 samples: int = CHECK_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """``(v, ω)`` for holonomic moves ``(N, 2)``, never less safe than the straight moves themselves.

    A planner checks (or at least means) the straight move from where the robot is to
    ``position + move``. Each robot pursues that point (:func:`pursue`, as :func:`track_moves`);
    a robot that would drive a curved arc to it (its bearing more than :data:`ALIGNED` off the
    heading) does so only when the arc, sampled at ``samples`` points, keeps at least
    ``min(clearance of the straight move, robot_radius + SAFETY)`` from every obstacle and the
    map's edge at ``where`` (the moving ones where they are at this step); otherwise it turns on
    the spot to face the point (v = 0) and drives the straight move from the next step on (when
    the planner asks for it again). So every step a robot either stands (turning), or drives a
    part of the straight move its planner chose from there (a robot drives at most
    ``max_speed``: a diagonal unit move is driven 1 of its √2), or an arc as clear as that move
    or clear by the planners' margin (:data:`~apf_physics.control.shield.SAFETY`).

    The guarantee needs a robot able to stop within a step (``max_accel ≥ max_speed``, as the
    default limits) and holds for the obstacles at this step: a robot turning on the spot is
    not checked against a moving obstacle coming at it.

    Args:
        state: (N, 5) ``(x, y, θ, v, ω)``.
        moves: (N, 2) the planner's moves, from each robot's position (a zero move stops it).
        where: The world at this step.
        limits: The robots' limits.
        turn_in_place: As :func:`pursue`: beyond this bearing a robot turns on the spot anyway.
        speed_cap: As :func:`pursue` (a scalar or (N,)).
        samples: Points (after the start) at which arcs and moves are checked.
    """
    state = np.asarray(state, float).reshape(-1, 5)
    moves = np.asarray(moves, float).reshape(-1, 2)
    n = len(state)
    cap = None if speed_cap is None else np.broadcast_to(np.asarray(speed_cap, float), (n,))
    waypoint = state[:, :2] + moves
    v, omega = pursue(state, waypoint, limits, turn_in_place, speed_cap=cap)
    local = to_robot_frame(state, waypoint)
    bearing = np.abs(np.arctan2(local[:, 1], local[:, 0]))
    curved = np.flatnonzero((v > 0) & (bearing > ALIGNED) & (np.abs(omega) > 0))
    if not len(curved):
        return v, omega
    arcs = arc_points(state[curved], v[curved], omega[curved], samples)                     # (k, S + 1, 2)
    f = np.linspace(0.0, 1.0, samples + 1)
    chords = state[curved, None, :2] + f[None, :, None] * moves[curved, None, :]
    clear = where.clearance(np.concatenate([arcs, chords]).reshape(-1, 2)).reshape(2, len(curved), -1).min(axis=2)
    bar = np.minimum(clear[1], where.world.robot_radius + SAFETY)
    unsafe = curved[clear[0] < bar]
    if len(unsafe):
        v_turn, omega_turn = pursue(state[unsafe], waypoint[unsafe], limits, ALIGNED,
                                    speed_cap=None if cap is None else cap[unsafe])
        v, omega = v.copy(), omega.copy()
        v[unsafe], omega[unsafe] = v_turn, omega_turn
    return v, omega


def project_on_paths(points: np.ndarray, paths: np.ndarray, lo: np.ndarray | None = None,
                     hi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Nearest point of each robot's path polyline, optionally only within arc lengths ``[lo, hi]``.

    Args:
        points: (N, 2).
        paths: (N, P, 2) polylines (pad a shorter path by repeating its last point).
        lo, hi: (N,) the window of arc length searched (default the whole path).

    Returns:
        ``(distance (N,), arc length (N,))`` of the nearest point.
    """
    a, b = paths[:, :-1], paths[:, 1:]                                             # (N, P-1, 2)
    seg = b - a
    length = np.hypot(seg[..., 0], seg[..., 1])
    start = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(length, axis=1)[:, :-1]], axis=1)
    rel = points[:, None, :] - a
    u = np.clip(np.sum(rel * seg, axis=-1) / np.maximum(length * length, 1e-300), 0.0, 1.0)
    s = start + u * length
    if lo is not None:
        s = np.clip(s, lo[:, None], None)
    if hi is not None:
        s = np.clip(s, None, hi[:, None])
    if lo is not None or hi is not None:     # the clipped arc length's point on its own segment
        u = np.clip((s - start) / np.maximum(length, 1e-300), 0.0, 1.0)
        s = start + u * length
    near = a + u[..., None] * seg
    d = np.hypot(*(points[:, None, :] - near).transpose(2, 0, 1))
    if lo is not None or hi is not None:
        outside = (s < lo[:, None] - 1e-12) | (s > hi[:, None] + 1e-12)
        d = np.where(outside, np.inf, d)
    best = np.argmin(d, axis=1)
    rows = np.arange(len(points))
    return d[rows, best], s[rows, best]


def point_at(paths: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(N, 2) the point at arc length ``s`` (N,) along each path (clamped to its ends)."""
    seg = np.diff(paths, axis=1)
    length = np.hypot(seg[..., 0], seg[..., 1])
    cum = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(length, axis=1)], axis=1)     # (N, P)
    s = np.clip(np.asarray(s, float), 0.0, cum[:, -1])
    k = np.clip((cum[:, 1:] < s[:, None]).sum(axis=1), 0, seg.shape[1] - 1)
    rows = np.arange(len(paths))
    f = (s - cum[rows, k]) / np.maximum(length[rows, k], 1e-300)
    return paths[rows, k] + np.clip(f, 0.0, 1.0)[:, None] * seg[rows, k]


def cross_track_error(points: np.ndarray, paths: np.ndarray) -> np.ndarray:
    """(N,) distance from each robot's point to its path polyline (N, P, 2)."""
    return project_on_paths(np.asarray(points, float).reshape(-1, 2), np.asarray(paths, float))[0]


class PathFollower:
    """Pure pursuit along one path per robot, vectorised.

    Each step a robot's progress (arc length along its path) moves to its nearest point on the
    path within ``[progress, progress + 2·lookahead]`` (it never jumps back, nor to a later
    part of the path that passes close), and the robot pursues the point ``lookahead`` farther
    along (:func:`pursue`); the path's end is pursued exactly and the robot stops on it.

    Args:
        paths: (N, P, 2) polylines, each from its robot's start (pad shorter ones by repeating
            their last point).
        limits: The robots' limits.
        lookahead: Distance along the path of the pursued point [units].
        turn_in_place: As :func:`pursue`.
    """

    def __init__(self, paths: np.ndarray, limits: UnicycleLimits = UnicycleLimits(), lookahead: float = LOOKAHEAD,
                 turn_in_place: float = TURN_IN_PLACE):
        self.paths = np.asarray(paths, float)
        if self.paths.ndim != 3 or self.paths.shape[1] < 2:
            raise ValueError(f"paths must be (N, P >= 2, 2), got {self.paths.shape}")
        self.limits = limits
        self.lookahead = float(lookahead)
        self.turn_in_place = float(turn_in_place)
        seg = np.diff(self.paths, axis=1)
        self.length = np.hypot(seg[..., 0], seg[..., 1]).sum(axis=1)          # (N,)
        self.progress = np.zeros(len(self.paths))

    def carrots(self, state: np.ndarray) -> np.ndarray:
        """(N, 2) the points pursued from ``state`` (advances the progress)."""
        state = np.asarray(state, float).reshape(-1, 5)
        _, s = project_on_paths(state[:, :2], self.paths, self.progress, self.progress + 2 * self.lookahead)
        self.progress = np.maximum(self.progress, s)
        return point_at(self.paths, np.minimum(self.progress + self.lookahead, self.length))

    def commands(self, state: np.ndarray, speed_cap: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(v, ω)`` for this step (``speed_cap``: a lower top speed this step, e.g.
        :meth:`UnicycleFollowers.leader_cap`)."""
        carrots = self.carrots(state)
        remaining = np.maximum(self.length - self.progress, 0.0)
        cap = np.sqrt(2.0 * self.limits.max_accel * remaining) + ARRIVE     # can still stop at the end
        if speed_cap is not None:
            cap = np.minimum(cap, speed_cap)
        return pursue(state, carrots, self.limits, self.turn_in_place, speed_cap=cap)

    def done(self, state: np.ndarray, tolerance: float) -> np.ndarray:
        """(N,) bool: the robot is within ``tolerance`` of its path's end."""
        end = self.paths[:, -1]
        return np.hypot(*(np.asarray(state, float)[:, :2] - end).T) <= tolerance


def give_way(arcs: np.ndarray, v: np.ndarray, order: np.ndarray, contact: float,
             detours: np.ndarray | None = None, blocked: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Which robots keep their arc, take a detour, or stop, decided one robot at a time in ``order``.

    Each robot keeps its arc when at every sampled moment it stays ``contact`` (centre to centre)
    from the arcs of the robots decided before it and from the robots not decided yet where they
    stand (or, for robots already nearer at the start, no nearer than they are); otherwise it takes
    the first of its ``detours`` that does (the caller gives only detours clear of the obstacles,
    best first: what a holonomic robot's right of way does by stepping aside), else it stops where
    it is (it may still turn). Robots left out of ``order`` stand. Because every robot decided
    before another kept clear of that one standing, stopping is always safe: no two robots' arcs
    come within contact at the same moment.

    Args:
        arcs: (R, S + 1, 2) every robot's arc this step (:func:`~apf_physics.world.kinematics.arc_points`).
        v: (R,) the robots' speeds (0: standing).
        order: Robot indices, highest priority first.
        contact: The least centre distance.
        detours: (R, K, S + 1, 2) other arcs each robot may take instead, best first, NaN where none.
        blocked: (R,) bool, robots whose own arc is not to be driven (it nears an obstacle): they
            take a detour or stop as if it met another robot.

    Returns:
        ``(v, choice)``: (R,) ``v`` with the robots that stop set to 0, and (R,) what each robot
        does: -1 its arc (or standing), -2 stops, ``k`` its detour ``k``.
    """
    arcs = np.array(arcs, float)
    v = np.array(v, float)
    choice = np.full(len(arcs), -1)
    standing = np.repeat(arcs[:, :1], arcs.shape[1], axis=1)
    decided = np.zeros(len(arcs), bool)
    order = np.asarray(order, np.intp)
    listed = np.zeros(len(arcs), bool)
    listed[order] = True
    v[~listed] = 0.0
    arcs[~listed] = standing[~listed]

    def meets(arc: np.ndarray, others: np.ndarray, paths: np.ndarray) -> bool:
        if not len(others):
            return False
        d = np.hypot(*(paths - arc[None]).transpose(2, 0, 1))                           # (k, S + 1)
        bar = np.minimum(contact, d[:, 0] - 1e-9)
        return bool((d[:, 1:] < bar[:, None]).any())

    for k in order.tolist():
        others = np.flatnonzero(listed & (np.arange(len(arcs)) != k))
        paths = np.where(decided[others, None, None], arcs[others], standing[others])
        if v[k] != 0 and ((blocked is not None and blocked[k]) or meets(arcs[k], others, paths)):
            v[k] = 0.0
            arcs[k] = standing[k]
            choice[k] = -2
            for j, detour in enumerate(detours[k] if detours is not None else ()):
                if np.isfinite(detour).all() and not meets(detour, others, paths):
                    arcs[k] = detour
                    choice[k] = j
                    break
        decided[k] = True
    return v, choice


DETOURS = np.array([[0.5, 0.5], [0.5, -0.5], [0.5, 1.0], [0.5, -1.0], [-1.0, 0.0]])
"""The detours a unicycle that must give way tries (:func:`give_way`), as shares of its limits
(:meth:`~apf_physics.world.kinematics.UnicycleLimits.from_unit`): half speed turning 45° or 90° either
way, or straight back at the top reverse speed."""


def detour_arcs(states: np.ndarray, arcs: np.ndarray, limits: UnicycleLimits, where: Moment,
                samples: int = CHECK_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """:data:`DETOURS` of each robot, within its limits (against its last command), best first (ending
    nearest where its own arc ends), NaN where one comes nearer than ``robot_radius + SAFETY`` to an
    obstacle or the map's edge at ``where``.

    Returns:
        ``(detours (R, K, S + 1, 2), commands (R, K, 2))`` for :func:`give_way`.
    """
    states = np.asarray(states, float).reshape(-1, 5)
    n, k = len(states), len(DETOURS)
    v, omega = limits.from_unit(np.tile(DETOURS, (n, 1)))
    v, omega = limits.clamp(v, omega, np.repeat(states[:, 3], k), np.repeat(states[:, 4], k))
    paths = arc_points(np.repeat(states, k, axis=0), v, omega, samples).reshape(n, k, samples + 1, 2)
    clear = where.clearance(paths.reshape(-1, 2)).reshape(n, k, -1).min(axis=2)
    paths = np.where((clear >= where.world.robot_radius + SAFETY)[..., None, None], paths, np.nan)
    miss = np.hypot(*(np.nan_to_num(paths[:, :, -1], nan=1e9) - arcs[:, None, -1]).transpose(2, 0, 1))
    best = np.argsort(miss, axis=1, kind="stable")
    rows = np.arange(n)[:, None]
    return paths[rows, best], np.stack([v.reshape(n, k), omega.reshape(n, k)], axis=-1)[rows, best]


def slot_points(leader: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(N, F, 2) the slots of a wedge or offsets formation behind leaders at poses ``leader`` (N, ≥3).

    ``offsets`` (F, 2) are ``[back, left]`` relative to the leader's **heading θ** (the holonomic
    rule uses a smoothed direction of travel, which a unicycle has exactly):
    ``slot = p − back·h + left·l`` with ``h = (cos θ, sin θ)`` and ``l`` its left normal.
    """
    leader = np.asarray(leader, float)
    offsets = np.asarray(offsets, float).reshape(-1, 2)
    h = np.stack([np.cos(leader[:, 2]), np.sin(leader[:, 2])], axis=-1)[:, None, :]
    left = np.stack([-h[..., 1], h[..., 0]], axis=-1)
    return leader[:, None, :2] - offsets[None, :, :1] * h + offsets[None, :, 1:] * left


class UnicycleFollowers:
    """The followers of one formation of unicycle robots (Model §3 for wheeled robots).

    Each step: the leader's command ``(v, ω)`` gives its move (the chord of its arc,
    :func:`~apf_physics.world.kinematics.arc_displacement`); the thesis's holonomic rule
    (:class:`~apf_physics.control.formation.FollowerController`: each follower's best safe neighbouring
    position in its own field, anchored ``spacing`` back along the trail of the robot it follows,
    or at its slot) gives each follower's **waypoint**; :func:`pursue` drives to it. The rule's
    moves are checked for safety as straight moves; with ``turn_in_place`` small the followers
    drive exactly those (turning first), with the default they drive arcs through the same
    points (up to ``L/2·tan(α/2)`` off the chord).

    Args:
        world: The world.
        spec: The formation.
        limits: The followers' limits.
        turn_in_place: As :func:`pursue`.
    """

    def __init__(self, world: World, spec: FormationSpec, limits: UnicycleLimits = UnicycleLimits(),
                 turn_in_place: float = TURN_IN_PLACE):
        self.controller = FollowerController(world, spec)
        self.limits = limits
        self.turn_in_place = float(turn_in_place)

    def reset(self, states: np.ndarray) -> None:
        """Start a run with robots at ``states`` (m, 5), the leader first."""
        self.controller.reset(np.asarray(states, float)[:, :2])

    def leader_cap(self, states: np.ndarray) -> float:
        """The leader's top speed this step [units/step] so that its followers keep up: full speed
        while every link is at least :data:`LINK_MARGIN` + 1 within the communication range, down
        to 0 at :data:`LINK_MARGIN` within it (a unicycle follower turning on the spot falls behind).

        Except when every follower is within :data:`SETTLED` of where the rule pulls it (its
        anchor): the rule moves a follower by unit moves only, so it would not move before the
        leader does, and a formation whose links are long by design (an offsets slot 2 back with a
        range of 3) would wait for ever; then the leader may go :data:`SETTLED`, as long as
        every link stays :data:`SETTLED` / 2 within the range."""
        states = np.asarray(states, float).reshape(-1, 5)
        spec = self.controller.spec
        links = link_lengths(states[:, :2], spec.followed)
        longest = float(links.max(initial=0.0))
        room = float(np.clip(spec.comm_range - LINK_MARGIN - longest, 0.0, self.limits.max_speed))
        if room < self.SETTLED and len(links):
            anchors = self.controller.anchors(states[:, :2], self.controller.heading)
            if np.hypot(*(states[1:, :2] - anchors).T).max() < self.SETTLED:
                room = max(room, float(np.clip(spec.comm_range - self.SETTLED / 2 - longest, 0.0, self.SETTLED)))
        return room

    SETTLED = 0.5
    """:meth:`leader_cap`: a follower this near its anchor [units] is where the rule wants it."""

    def waypoints(self, states: np.ndarray, leader_v: float, leader_omega: float) -> np.ndarray:
        """(F, 2) where each follower should be after this step (advances the rule's trails)."""
        states = np.asarray(states, float).reshape(-1, 5)
        leader_move = arc_displacement(states[0, 2], leader_v, leader_omega)
        moves = self.controller.act(states[:, :2], leader_move)
        return states[1:, :2] + moves

    def _close_in(self, states: np.ndarray, waypoints: np.ndarray, leader_v: float, leader_omega: float) -> np.ndarray:
        """(F, 2) ``waypoints`` with each follower that the rule keeps where it is sent instead to
        its anchor when that is less than a unit away and in clear sight (``robot_radius + SAFETY``
        along the way): the rule's unit moves overshoot an anchor that near, so the follower would
        not move, and a leader waiting for it (:meth:`leader_cap`) would wait for ever; a unicycle
        can drive part of a unit."""
        positions = states[:, :2]
        staying = np.hypot(*(waypoints - positions[1:]).T) < ARRIVE
        if not staying.any():
            return waypoints
        ahead = np.vstack([positions[:1] + arc_displacement(states[0, 2], leader_v, leader_omega), waypoints])
        anchors = self.controller.anchors(ahead, self.controller.heading)
        gap = np.hypot(*(anchors - positions[1:]).T)
        near = np.flatnonzero(staying & (gap > ARRIVE) & (gap < 1.0))
        if not len(near):
            return waypoints
        world = self.controller.world
        sight = world.path_clearance(positions[1:][near], anchors[near], 0.1)
        now = world.clearance(positions[1:][near])
        ok = near[sight >= np.minimum(world.robot_radius + SAFETY, now)]
        waypoints = waypoints.copy()
        waypoints[ok] = anchors[ok]
        return waypoints

    def _keep_apart(self, v_all: np.ndarray, arcs: np.ndarray, standing: np.ndarray, first: int) -> bool:
        """In chain order from robot ``first``, stop (v = 0, in place in ``v_all`` and ``arcs``) each
        robot whose arc comes within contact of the arcs of the robots before it or of the robots
        after it where they stand, or within its radius of an obstacle; returns whether any stopped."""
        world = self.controller.world
        stopped = False
        for i in range(first, len(arcs)):
            others = np.concatenate([arcs[:i], standing[i + 1:]])                       # (m - 1, S + 1, 2)
            close = self._too_close(arcs[i], others)
            clear = world.clearance(arcs[i]).min()
            if v_all[i] != 0 and (close or clear < world.robot_radius):
                v_all[i] = 0.0
                arcs[i] = standing[i]
                stopped = True
        return stopped

    def _too_close(self, arc: np.ndarray, others: np.ndarray) -> bool:
        """Whether ``arc`` (S + 1, 2) comes within contact of any of ``others`` (k, S + 1, 2) at the same
        moments, or, for robots already that close at the start, closer than they are (so that
        robots placed exactly at contact distance can still move apart)."""
        if not len(others):
            return False
        d = np.hypot(*(others - arc[None]).transpose(2, 0, 1))                         # (k, S + 1)
        bar = np.minimum(self.controller.contact, d[:, 0] - 1e-9)
        return bool((d[:, 1:] < bar[:, None]).any())

    CLOSING = 0.75
    """:meth:`drive`: a line follower does not drive nearer than this share of ``spacing`` to the
    robot it follows (where that one ends the step), unless it is already nearer."""

    def drive(self, states: np.ndarray, leader_v: float, leader_omega: float) -> tuple[np.ndarray, np.ndarray]:
        """``(v, ω)`` (m,), (m,) of every robot this step, the leader's command given (it may be
        stopped here): what a rollout of unicycle formations drives.

        The rule decides each follower's move knowing the moves of those ahead of it; a unicycle
        may not make its move (it turns first, or drives an arc). So, in chain order, each
        follower's arc (sampled at :data:`CHECK_SAMPLES` points) is checked against the arcs of
        the robots ahead (final) and the start positions of those behind, and against the
        obstacles; a follower whose arc comes closer than the rule's contact distance (or than its
        radius to an obstacle) only turns this step. Besides, in a line, a follower whose robot ahead does not make its
        move (it turns on the spot first) does not close in on it below :data:`CLOSING` ·
        ``spacing`` (the rule placed it assuming that move; the robots behind would bunch up and
        block one another); and the leader, which its planner steers without regard to its
        followers, is checked too: when its arc comes within contact of a follower's (a follower
        turning on the spot, or stopped), the leader only turns this step and the followers are
        checked again against it standing. So no two robots' arcs come within contact at the
        same moment (at :data:`CHECK_SAMPLES` points of the step). A follower the rule keeps where
        it is while its anchor is less than a unit away drives to the anchor (:meth:`_close_in`).
        """
        states = np.asarray(states, float).reshape(-1, 5)
        waypoints = self._close_in(states, self.waypoints(states, leader_v, leader_omega), leader_v, leader_omega)
        v, omega = pursue(states[1:], waypoints, self.limits, self.turn_in_place)
        v_all = np.concatenate([[float(leader_v)], v])
        omega_all = np.concatenate([[float(leader_omega)], omega])
        arcs = arc_points(states, v_all, omega_all, CHECK_SAMPLES)
        standing = np.repeat(states[:, None, :2], CHECK_SAMPLES + 1, axis=1)
        if self.controller.offsets is None:
            spacing = self.controller.spec.spacing
            for i, ahead in enumerate(self.controller.spec.followed, start=1):
                end = arcs[ahead, -1]
                now, then = np.hypot(*(states[i, :2] - end)), np.hypot(*(arcs[i, -1] - end))
                if v_all[i] > 0 and then < min(self.CLOSING * spacing, now):
                    v_all[i] = 0.0
                    arcs[i] = standing[i]
        self._keep_apart(v_all, arcs, standing, 1)
        if v_all[0] != 0 and self._too_close(arcs[0], arcs[1:]):
            v_all[0] = 0.0
            arcs[0] = standing[0]
            self._keep_apart(v_all, arcs, standing, 1)
        return v_all, omega_all


def leader_caps(states: np.ndarray, moving: np.ndarray, followers: Sequence[UnicycleFollowers],
                limits: UnicycleLimits) -> np.ndarray:
    """(S,) the fastest each moving slot's leader may go so that its followers keep up
    (:meth:`UnicycleFollowers.leader_cap`); the top speed for slots not moving."""
    return np.array([followers[s].leader_cap(states[s]) if moving[s] else limits.max_speed for s in range(len(states))])


def team_drive(states: np.ndarray, v: np.ndarray, omega: np.ndarray, moving: np.ndarray,
               followers: Sequence[UnicycleFollowers] = ()) -> np.ndarray:
    """(S, m, 2) every unicycle's ``(v, ω)``: each leader's given command, its followers' by their
    rule (:meth:`UnicycleFollowers.drive`, which may stop a leader about to meet a follower); the
    one place where a team's commands are put together, for ``eval``'s rollouts and the environments."""
    n, m = states.shape[:2]
    commands = np.zeros((n, m, 2))
    commands[:, 0, 0], commands[:, 0, 1] = v, omega
    if followers:
        for s in np.flatnonzero(moving).tolist():
            commands[s, :, 0], commands[s, :, 1] = followers[s].drive(states[s], float(v[s]), float(omega[s]))
    return commands
