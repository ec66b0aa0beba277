"""How a robot moves: the holonomic robot's moves (Model §2, Table 1), and unicycle (differential-drive)
kinematics, a robot with a heading driven by ``(v, ω)``.

Units and conventions (as everywhere in the package, docs/model.md): lengths in **units**
(one unit is today's robot travel per control step), time in **control steps**, angles in
**radians**, counter-clockwise positive, heading θ = 0 along +x. A state is ``(x, y, θ, v, ω)``:
the robot's centre, its heading, and the speed and turn rate it was last commanded
[units/step, rad/step].

A command ``(v, ω)`` is held for one control step (as a holonomic robot's velocity is today).
:meth:`UnicycleLimits.clamp` bounds it by the robot's speed, turn rate and acceleration (the
change from the previous step's command); the robot then drives an **exact arc** (a straight
segment when ω = 0):

    x' = x + v/ω (sin(θ + ω·dt) − sin θ),   y' = y − v/ω (cos(θ + ω·dt) − cos θ),   θ' = θ + ω·dt

(:func:`integrate`; the ω → 0 limit is taken by a series, so there is no division by a small ω).
The physics moves discs by a velocity per substep: :func:`substep_velocities` gives, for S
substeps, the velocity that carries the disc from one point of the arc to the next (the
chord), so that the disc ends every substep exactly on the arc and is swept along it. A
chord is never longer than its arc (``|v|·dt/S``), so the substep count that keeps a
holonomic robot of the same top speed from tunnelling (``physics.substeps_for``) keeps a
turning one from tunnelling too.

Actions: the discrete set :data:`UNICYCLE_ACTIONS` (nine, like Table 1, ``stop`` last) and the
continuous ``Box(-1, 1, (2,))`` of Gymnasium's continuous-control convention, mapped to
``(v, ω)`` by :meth:`UnicycleLimits.from_unit` and, for a holonomic robot, to a displacement by
:func:`holonomic_from_unit` (the box's corners and edge midpoints are Table 1's nine moves).
Everything is vectorised over robots: arrays of shape ``(N,)`` or ``(N, 2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

# -- a holonomic robot's moves (Model §2, thesis Table 1) ------------------------------------

ACTION_NAMES = ("up", "down", "left", "right", "left-up", "left-down", "right-up", "right-down", "stay")
ACTIONS = np.array(
    [(0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (-1, -1), (1, 1), (1, -1), (0, 0)], dtype=float
)  # displacement per control step, world units

FINE_ACTIONS = np.vstack([ACTIONS[:8], 0.5 * ACTIONS[:8], ACTIONS[8:]])
"""The nine moves and the eight half-length ones (stay last): a robot can thread a passage
narrower than a unit lattice allows."""
MOVE_SETS = {"unit": ACTIONS, "fine": FINE_ACTIONS}
"""Move sets of planners, by name."""
NODE_MOVES = "nodes"
"""The moves of a map network that plans on a node graph: to every free node within one step
(:func:`~apf_physics.sim.nodegraph.node_moves`), different for each robot's position."""
MOVE_KINDS = (*MOVE_SETS, NODE_MOVES)
"""Every name a map network's moves may have."""


# -- unicycles ---------------------------------------------------------------------------------

KINEMATICS = ("holonomic", "unicycle")
"""The robot kinds: ``holonomic`` (the thesis's robot: any velocity, no heading) and ``unicycle``."""
LIMIT_KEYS = ("max_speed", "max_reverse", "max_turn_rate", "max_accel", "max_turn_accel")
"""The fields of :class:`UnicycleLimits`, as a world file's ``robot:`` and the env options name them."""

HOLONOMIC_SPEED = math.sqrt(2.0)
"""The holonomic robot's top speed [units/step]: a diagonal unit move (±1, ±1)."""
MAX_UNICYCLE_SPEED = 4.0
"""Highest ``max_speed`` and ``max_reverse`` [units/step]: four times the holonomic robot's unit
move (a faster robot crosses the planners' observation window in a step or two)."""
MAX_UNICYCLE_ACCEL = 2 * MAX_UNICYCLE_SPEED
"""Highest ``max_accel`` [units/step²]: from full reverse to full speed in one step."""
MAX_TURN_RATE = 2 * math.pi
"""Highest ``max_turn_rate`` [rad/step]: a whole turn in one step."""
MAX_TURN_ACCEL = 2 * MAX_TURN_RATE
"""Highest ``max_turn_accel`` [rad/step²]: from a whole turn one way to a whole turn the other."""
LIMIT_BOUNDS = {"max_speed": MAX_UNICYCLE_SPEED, "max_reverse": MAX_UNICYCLE_SPEED, "max_accel": MAX_UNICYCLE_ACCEL,
                "max_turn_rate": MAX_TURN_RATE, "max_turn_accel": MAX_TURN_ACCEL}
"""The upper bound of each of :data:`LIMIT_KEYS` (lengths in units, so in steps once a world file's
units are converted)."""

MAX_SUBSTEPS = 256
"""Most physics substeps per control step a world may need (:func:`physics_substeps`): the cost
of a step grows with them, and the arrays of a unicycle's arc with them."""
SUBSTEP_TRAVEL = 0.9
"""How far a robot's centre may move in one substep, as a share of its radius: a disc that
sinks at most this deep into an obstacle before the solver pushes it out never has its centre
inside it, however thin the obstacle."""


def substeps_for(radius: float, max_speed: float = math.sqrt(2.0)) -> int:
    """The fewest substeps (a power of two) that keep the centre of a robot of ``radius`` moving
    at up to ``max_speed`` [units per control step] out of every obstacle: at most
    :data:`SUBSTEP_TRAVEL` radii per substep."""
    return 2 ** math.ceil(math.log2(max(1.0, max_speed / (SUBSTEP_TRAVEL * radius))))


def physics_substeps(radius: float, top_speed: float, obstacle_speed: float = 0.0, robots_meet: bool = False) -> int:
    """The physics' substeps per control step: :func:`substeps_for` the fastest a robot's disc
    closes in on anything.

    Args:
        radius: The smallest robot's radius [units].
        top_speed: The fastest a robot moves [units per control step]. Contacts never make a
            robot faster: the physics caps a body pushed above it.
        obstacle_speed: The fastest moving obstacle [units per control step].
        robots_meet: Robots meet each other (formations, crowds): two close in on each other at
            twice the top speed.
    """
    relative = top_speed + obstacle_speed
    if robots_meet:
        relative = max(relative, 2 * top_speed)
    return substeps_for(radius, relative)


SMALL_TURN = 1e-6
"""Below this ``|ω·dt|`` [rad] the arc is computed from its Taylor series (exact to rounding)."""

UNICYCLE_ACTION_NAMES = ("forward", "forward-left", "forward-right", "slow-left", "slow-right",
                         "turn-left", "turn-right", "back", "stop")
UNICYCLE_ACTIONS = np.array([(1.0, 0.0), (1.0, 0.5), (1.0, -0.5), (0.5, 1.0), (0.5, -1.0),
                             (0.0, 1.0), (0.0, -1.0), (-1.0, 0.0), (0.0, 0.0)])
"""The discrete actions of a unicycle robot, in the order of :data:`UNICYCLE_ACTION_NAMES`, as
``(v, ω)`` in the unit box (``v`` as a share of the top speed forward, or of the top reverse
speed backward; ``ω`` of the top turn rate; positive ω turns left):

====  =============  ==========  ============================================
 #    name           (v, ω)      with the default limits, per control step
====  =============  ==========  ============================================
 0    forward        (1, 0)      1 unit straight ahead
 1    forward-left   (1, ½)      1 unit along an arc turning 45° left
 2    forward-right  (1, −½)     1 unit along an arc turning 45° right
 3    slow-left      (½, 1)      ½ unit along an arc turning 90° left
 4    slow-right     (½, −1)     ½ unit along an arc turning 90° right
 5    turn-left      (0, 1)      turn 90° left on the spot
 6    turn-right     (0, −1)     turn 90° right on the spot
 7    back           (−1, 0)     ½ unit straight back (the top reverse speed)
 8    stop           (0, 0)      stand still
====  =============  ==========  ============================================

The acceleration limits apply (with the defaults they never bind between these actions)."""


@dataclass(frozen=True)
class UnicycleLimits:
    """What a unicycle robot can do (defaults: today's robot, one unit per control step at most).

    Attributes:
        max_speed: Top forward speed [units/step] (today's unit move: 1).
        max_reverse: Top backward speed [units/step], ≥ 0.
        max_turn_rate: Top turn rate |ω| [rad/step].
        max_accel: Largest change of ``v`` from one control step to the next [units/step²].
        max_turn_accel: Largest change of ``ω`` from one control step to the next [rad/step²].
    """

    max_speed: float = 1.0
    max_reverse: float = 0.5
    max_turn_rate: float = np.pi / 2
    max_accel: float = 1.0
    max_turn_accel: float = np.pi

    def __post_init__(self):
        for name in LIMIT_KEYS:
            value = getattr(self, name)
            if not math.isfinite(value) or not (value >= 0 if name == "max_reverse" else value > 0):
                raise ValueError(f"unicycle limit {name} must be {'>= 0' if name == 'max_reverse' else 'positive'} "
                                 f"and finite, got {value}")

    def out_of_bounds(self, unit: float = 1.0) -> list[tuple[str, float, float]]:
        """``(name, value, bound)`` of each limit above its :data:`LIMIT_BOUNDS` (lengths read in
        ``unit`` per unit: a world file's limits with ``unit`` its ``robot.step``)."""
        out = []
        for name, bound in LIMIT_BOUNDS.items():
            value = getattr(self, name)
            scale = unit if name in ("max_speed", "max_reverse", "max_accel") else 1.0
            if value > bound * scale:
                out.append((name, value, bound * scale))
        return out

    def scaled(self, unit: float) -> UnicycleLimits:
        """These limits with lengths divided by ``unit`` (a world file's units to steps; rates of turn unchanged)."""
        return replace(self, max_speed=self.max_speed / unit, max_reverse=self.max_reverse / unit,
                       max_accel=self.max_accel / unit)

    @property
    def top_speed(self) -> float:
        """The fastest the robot moves, forward or back [units/step] (what the physics' substeps are chosen for)."""
        return max(self.max_speed, self.max_reverse)

    def clamp(self, v: np.ndarray, omega: np.ndarray, v_prev: np.ndarray | float | None = None,
              omega_prev: np.ndarray | float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(v, ω)`` within the speed and turn-rate limits and, given the previous step's
        command, within the acceleration limits (each clipped on its own).

        Args:
            v, omega: (N,) commanded speed [units/step] and turn rate [rad/step].
            v_prev, omega_prev: (N,) last step's command (None: no acceleration limit).
        """
        v = np.clip(np.asarray(v, float), -self.max_reverse, self.max_speed)
        omega = np.clip(np.asarray(omega, float), -self.max_turn_rate, self.max_turn_rate)
        if v_prev is not None:
            v = np.clip(v, np.asarray(v_prev, float) - self.max_accel, np.asarray(v_prev, float) + self.max_accel)
        if omega_prev is not None:
            omega = np.clip(omega, np.asarray(omega_prev, float) - self.max_turn_accel,
                            np.asarray(omega_prev, float) + self.max_turn_accel)
        return v, omega

    def from_unit(self, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(v, ω)`` of actions in the unit box ``(N, 2)`` (a ``Box(-1, 1, (2,))`` action, or
        :data:`UNICYCLE_ACTIONS`): ``v = a₀·max_speed`` forward, ``a₀·max_reverse`` backward,
        ``ω = a₁·max_turn_rate``. Values outside the box are clipped to it."""
        a = np.clip(np.asarray(action, float).reshape(-1, 2), -1.0, 1.0)
        v = np.where(a[:, 0] >= 0, a[:, 0] * self.max_speed, a[:, 0] * self.max_reverse)
        return v, a[:, 1] * self.max_turn_rate

    def to_unit(self, v: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """(N, 2) the unit-box action of ``(v, ω)`` (inverse of :meth:`from_unit` within the limits)."""
        v = np.asarray(v, float)
        back = self.max_reverse if self.max_reverse > 0 else 1.0
        a0 = np.where(v >= 0, v / self.max_speed, v / back)
        return np.clip(np.column_stack([a0, np.asarray(omega, float) / self.max_turn_rate]), -1.0, 1.0)

    def discrete(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(v, ω)`` of discrete actions ``index`` (N,) of :data:`UNICYCLE_ACTIONS`."""
        return self.from_unit(UNICYCLE_ACTIONS[np.asarray(index, np.intp).reshape(-1)])


def holonomic_from_unit(action: np.ndarray, max_speed: float = 1.0) -> np.ndarray:
    """(N, 2) displacements per control step of holonomic actions in ``Box(-1, 1, (2,))``.

    Each axis is scaled by ``max_speed`` on its own (values outside the box are clipped), so the
    box's corners and edge midpoints are exactly Table 1's nine moves (a diagonal move is √2
    long, as today) and a discrete policy's moves are continuous actions too.
    """
    return np.clip(np.asarray(action, float).reshape(-1, 2), -1.0, 1.0) * float(max_speed)


def holonomic_to_unit(move: np.ndarray, max_speed: float = 1.0) -> np.ndarray:
    """(N, 2) the ``Box(-1, 1, (2,))`` action of displacements (inverse of :func:`holonomic_from_unit`, clipped)."""
    return np.clip(np.asarray(move, float).reshape(-1, 2) / float(max_speed), -1.0, 1.0)


def _arc_factors(turn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sin φ / φ, (1 − cos φ) / φ)`` for turn angles ``φ``, exact near 0 (series)."""
    small = np.abs(turn) < SMALL_TURN
    safe = np.where(small, 1.0, turn)
    t2 = turn * turn
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, turn / 2.0 - turn * t2 / 24.0, (1.0 - np.cos(safe)) / safe)
    return a, b


def arc_displacement(theta: np.ndarray, v: np.ndarray, omega: np.ndarray, dt: np.ndarray | float = 1.0) -> np.ndarray:
    """(N, 2) displacement of a unicycle at heading ``θ`` driving ``(v, ω)`` for ``dt`` steps (the exact arc).

    ``Δx = v·dt (cos θ · sin φ/φ − sin θ · (1 − cos φ)/φ)``, ``Δy = v·dt (sin θ · sin φ/φ +
    cos θ · (1 − cos φ)/φ)`` with ``φ = ω·dt``: the closed form of the module docstring,
    rewritten so that ω = 0 is no special case.
    """
    theta, v, omega = (np.asarray(a, float) for a in (theta, v, omega))
    turn = omega * dt
    a, b = _arc_factors(turn)
    length = v * dt
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([length * (c * a - s * b), length * (s * a + c * b)], axis=-1)


def integrate(state: np.ndarray, v: np.ndarray, omega: np.ndarray, dt: float = 1.0) -> np.ndarray:
    """(N, 5) states after driving ``(v, ω)`` (already within the limits) for ``dt`` control steps.

    Args:
        state: (N, 5) ``(x, y, θ, v, ω)``.
        v, omega: (N,) the command [units/step, rad/step].

    Returns:
        (N, 5): the pose at the end of the arc, θ wrapped to ``[-π, π)``, and the command as
        the new ``(v, ω)``.
    """
    state = np.asarray(state, float).reshape(-1, 5)
    v = np.broadcast_to(np.asarray(v, float), (len(state),))
    omega = np.broadcast_to(np.asarray(omega, float), (len(state),))
    out = np.empty_like(state)
    out[:, :2] = state[:, :2] + arc_displacement(state[:, 2], v, omega, dt)
    out[:, 2] = wrap_angle(state[:, 2] + omega * dt)
    out[:, 3] = v
    out[:, 4] = omega
    return out


def arc_points(state: np.ndarray, v: np.ndarray, omega: np.ndarray, substeps: int, dt: float = 1.0) -> np.ndarray:
    """(N, S + 1, 2) the robot's centre at the start and at the end of each of ``substeps`` equal
    parts of the arc driven over ``dt`` (exact points of the arc)."""
    state = np.asarray(state, float).reshape(-1, 5)
    fractions = np.arange(substeps + 1) / substeps * dt                      # (S + 1,)
    shift = arc_displacement(state[:, 2, None], np.asarray(v, float).reshape(-1, 1),
                             np.asarray(omega, float).reshape(-1, 1), fractions[None, :])
    return state[:, None, :2] + shift


def substep_velocities(state: np.ndarray, v: np.ndarray, omega: np.ndarray, substeps: int,
                       dt: float = 1.0) -> np.ndarray:
    """(N, S, 2) the velocity [units/step] to give a disc in each of ``substeps`` substeps of one
    control step so that it follows the arc of ``(v, ω)`` exactly.

    Substep ``k`` lasts ``dt/S``; its velocity is the chord from the arc's point at ``k/S`` to
    the one at ``(k+1)/S`` divided by that time, so a free disc moved ``p += velocity·dt/S``
    (pymunk's integration with no force) is on the arc after every substep, and its speed is at
    most ``|v|``. A pure turn (v = 0) gives zero velocities: θ changes, the disc does not move.
    """
    points = arc_points(state, v, omega, substeps, dt)
    return np.diff(points, axis=1) * (substeps / dt)


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``[-π, π)`` [rad]."""
    return (np.asarray(angle, float) + np.pi) % (2 * np.pi) - np.pi


def heading_vectors(theta: np.ndarray) -> np.ndarray:
    """(N, 2) unit vectors along headings ``θ`` (for drawing the heading in videos, and for the robot's frame)."""
    theta = np.asarray(theta, float)
    return np.stack([np.cos(theta), np.sin(theta)], axis=-1)


def to_robot_frame(state: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points`` in each robot's frame (x ahead, y to its left).

    Args:
        state: (N, ≥3) poses ``(x, y, θ, ...)``.
        points: (N, 2) one point per robot, or (N, M, 2) several.
    """
    state = np.asarray(state, float)
    points = np.asarray(points, float)
    many = points.ndim == 3
    origin = state[:, None, :2] if many else state[:, :2]
    c, s = np.cos(state[:, 2]), np.sin(state[:, 2])
    if many:
        c, s = c[:, None], s[:, None]
    d = points - origin
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)


def distance_bearing(state: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,), (N,): distance [units] and bearing [rad, in ``[-π, π)``, left positive] of ``target``
    (N, 2) from each robot: what the lidar observation carries with its ranges."""
    local = to_robot_frame(state, np.asarray(target, float).reshape(-1, 2))
    return np.hypot(local[:, 0], local[:, 1]), np.arctan2(local[:, 1], local[:, 0])
