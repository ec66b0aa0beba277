"""The shield: moves checked for clearance before a robot makes them, over one step or over time.

A planner scores moves; the shield admits only those that keep the robot ``SAFETY`` clear of
everything along the move (:func:`move_clearance`) and, near moving obstacles, over the steps
after it (:func:`shield_over_time`, docs/planners.md, "The shield over time").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from apf_physics.world.obstacles import CircleObstacle
from apf_physics.world.search import physics_offsets
from apf_physics.world.core import Moment, World
from apf_physics.world.kinematics import ACTION_NAMES, ACTIONS, FINE_ACTIONS, MOVE_SETS  # noqa: F401 (the moves' old home)

SAFETY = 0.05
"""Clearance kept beyond touching by planners that check their moves [world units]."""
MOVE_SAMPLES = 8
"""Points sampled along a move by :func:`move_clearance`, after its start."""


def move_clearance(where: Moment | World, positions: np.ndarray, moves: np.ndarray = ACTIONS) -> np.ndarray:
    """A lower bound of the clearance of a robot's centre along each straight move.

    The clearance is sampled at the start and at :data:`MOVE_SAMPLES` evenly spaced points of
    the move (:meth:`Moment.path_clearance`), and the least of them is lowered by half the
    spacing: clearance changes no faster than distance, so no point between two samples is
    nearer than that. A move whose bound is at least the robot's radius cannot touch anything
    (the physics moves the disc along the segment).

    Args:
        where: The world at the control step the moves start at (:meth:`World.at`): moving
            obstacles are taken where they are along the move. A :class:`World`: its static
            obstacles only (:meth:`World.static_path_clearance`).
        positions: (N, 2) robot centres.
        moves: (M, 2) displacements (default: the nine moves of :data:`ACTIONS`).

    Returns:
        (N, M) clearance bounds.
    """
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    moves = np.asarray(moves, dtype=float).reshape(-1, 2)
    spacing = np.hypot(*moves.T) / MOVE_SAMPLES                                   # (M,)
    start = np.repeat(positions, len(moves), axis=0)
    end = start + np.tile(moves, (len(positions), 1))
    # a move of length 0 is one point: any positive spacing samples it
    clear = where.path_clearance(start, end, np.tile(np.where(spacing > 0, spacing, 1.0), len(positions)))
    return clear.reshape(len(positions), len(moves)) - 0.5 * spacing[None, :]


# -- the shield over time ------------------------------------------------------------------------------

HORIZON = 3
"""Control steps a move's continuation must stay clear over (the move itself included).

The widest moving obstacle of the generated worlds is a 2.5 × 1 box (half-diagonal 1.35): to
leave the path of one coming head-on, a robot of radius 0.25 moves 1.35 + 0.25 + :data:`SAFETY`
≈ 1.65 across it, two unit moves; the move being chosen is the third step (it commits the
robot for one step before any escape starts). A longer horizon costs 9 more sequences per step
of it and rejects moves for obstacles that will have turned away by then."""
SENSING_RADIUS = 8.0
"""How far a robot senses moving obstacles (from its centre to their boundary) [units]: beyond
anything that can reach the robot's moves within :data:`HORIZON` steps at the highest speed a
world file allows (``HORIZON · (√2 + 1) + radius + SAFETY`` ≈ 7.5 for a robot of radius 0.25)."""
TURN_AWARE = True
"""With ``velocity`` prediction, check the move being made against every heading a moving obstacle
may take (at the speed it was seen at), not only the one it had: constant velocity alone missed
obstacles that turned back at the end of their route within the step (2 collisions in 100
validation starts, 0 with this)."""
PREDICTIONS = ("velocity", "known")
"""How the shield predicts where moving obstacles go: ``velocity``, at constant velocity from
where each obstacle is now and where it was at the last step (what a robot can sense, within
:data:`SENSING_RADIUS`); ``known``, the world file's motion as the physics executes it."""


def shielded_argmax(q: np.ndarray, room: np.ndarray) -> np.ndarray:
    """(N,) indices of the highest ``q`` among the moves with ``room >= 0``; rows without any: the most room."""
    safe = room >= 0
    best = np.where(safe, q, -np.inf).argmax(axis=1)
    return np.where(safe.any(axis=1), best, room.argmax(axis=1))


def predicted_offsets(world: World, t: int, s: np.ndarray, prediction: str = "velocity") -> np.ndarray:
    """``(len(s), M, 2)``: where each moving obstacle (in :attr:`World.moving` order) is predicted at steps ``t + s``.

    ``velocity``: its offset at ``t`` plus ``s`` times its displacement since ``t − 1`` (at step 0
    the world's offset at step −1: the robot's sensors ran before the episode started);
    ``known``: as the physics moves it (:func:`~apf_physics.world.search.physics_offsets`).
    """
    s = np.asarray(s, float)
    if prediction == "known":
        return physics_offsets(world, t + s)
    if prediction != "velocity":
        raise ValueError(f"unknown prediction {prediction!r} (known: {', '.join(PREDICTIONS)})")
    now, last = world.moving_offsets(float(t)), world.moving_offsets(float(t) - 1.0)
    return now[None] + s[:, None, None] * (now - last)[None]


def shield_over_time(moment: Moment, positions: np.ndarray, moves: np.ndarray, q: np.ndarray,
                     prediction: str = "velocity", horizon: int = HORIZON) -> np.ndarray:
    """(N,) the move each robot makes: the best-valued admitted one, else the one that puts contact off longest.

    A move is admitted when (1) the robot keeps ``robot_radius + SAFETY`` from everything all
    along it, every moving obstacle where it may be at each moment of the step (the robot's disc
    swept relative to each obstacle as both move), and (2) one of the nine unit moves, held for
    the ``horizon − 1`` steps after it, keeps that clearance too, every moving obstacle where it
    is predicted (``prediction``, :func:`predicted_offsets`). With ``known`` motion an obstacle
    is where the physics will put it; with ``velocity`` prediction (:data:`TURN_AWARE`) the move
    itself is checked against every heading the obstacle may take over the step at the fastest
    speed it was seen at over the last two steps (it may reach the end of its route and turn
    back, or round a corner, at any moment: the disc it can reach grows by that speed); each
    later step of the continuation as the shield will judge it when it comes: every heading
    from where the obstacle will be at that step's start at constant velocity (a continuation
    judged by constant velocity alone could lead where the next step's check admits nothing). Staying put is a move like the others. When no move is admitted the robot
    is judged again with every sequence of unit moves as its continuation (``9 ** (horizon − 1)``
    of them) and twice the samples, only for such robots: the best-valued move admitted so, else the move whose best
    continuation keeps it out of contact (clearance below its radius) the longest, the most room
    among those.

    Only robots with a moving obstacle within reach (sensed, and near enough to meet within
    ``horizon`` steps) are checked over time; the others, and every robot of a world without
    moving obstacles, get the shield of one step, :func:`move_clearance` against what stands
    still (in a world without moving obstacles exactly today's shield).

    Clearances are lower bounds: the least of the samples (:data:`MOVE_SAMPLES` per step) lowered
    by half the spacing of the robot's motion relative to each obstacle.

    Args:
        moment: The world at the control step the move starts at.
        positions: (N, 2) robot centres.
        moves: (M, 2) the planner's moves.
        q: (N, M) the value of each move (higher is better).
        prediction: One of :data:`PREDICTIONS`.
        horizon: Steps (≥ 2) over which a move and its continuation are checked.
    """
    world = moment.world
    if not world.moving:
        bar = world.robot_radius + SAFETY
        return shielded_argmax(q, move_clearance(moment, positions, moves) - bar)
    positions = np.asarray(positions, float).reshape(-1, 2)
    a = assess_moves(moment, positions, moves, prediction, horizon)
    admitted, contact, room = a.admitted.copy(), a.contact.copy(), a.room.copy()
    stuck = np.flatnonzero(~admitted.any(axis=1) & a.watched)
    if len(stuck):   # no move admitted: try every sequence of unit moves after each move, not only held ones
        rich = assess_moves(moment, positions[stuck], moves, prediction, horizon, every_sequence(horizon),
                            samples=2 * MOVE_SAMPLES)
        admitted[stuck], contact[stuck], room[stuck] = rich.admitted, rich.contact, rich.room
    safe_pick = np.where(admitted, q, -np.inf).argmax(axis=1)
    longest = contact >= contact.max(axis=1, keepdims=True)
    fallback = np.where(longest, room, -np.inf).argmax(axis=1)
    return np.where(admitted.any(axis=1), safe_pick, fallback)


def held_moves(horizon: int = HORIZON) -> np.ndarray:
    """``(9, horizon − 1, 2)``: each of the nine unit moves held for ``horizon − 1`` steps."""
    return np.repeat(ACTIONS[:, None, :], horizon - 1, axis=1)


def every_sequence(horizon: int = HORIZON) -> np.ndarray:
    """``(9 ** (horizon − 1), horizon − 1, 2)``: every sequence of ``horizon − 1`` unit moves."""
    grids = np.meshgrid(*[np.arange(len(ACTIONS))] * (horizon - 1), indexing="ij")
    return ACTIONS[np.stack([g.ravel() for g in grids], axis=1)]


class MoveAssessment(NamedTuple):
    """What :func:`assess_moves` finds of each robot's (row) moves (column)."""

    admitted: np.ndarray
    """(N, M) bool: the move and one of its continuations keep ``robot_radius + SAFETY`` clear."""
    contact: np.ndarray
    """(N, M): steps until the robot's clearance bound falls below its radius along the move's
    best continuation (inf: not within the horizon; unwatched robots: inf)."""
    room: np.ndarray
    """(N, M): the least clearance bound beyond ``robot_radius + SAFETY`` along the move and its best continuation."""
    watched: np.ndarray
    """(N,) bool: robots with a moving obstacle within reach, checked over time."""


def assess_moves(moment: Moment, positions: np.ndarray, moves: np.ndarray, prediction: str = "velocity",
                 horizon: int = HORIZON, continuations: np.ndarray | None = None,
                 samples: int = MOVE_SAMPLES) -> MoveAssessment:
    """Each robot's moves as :func:`shield_over_time` judges them (see there).

    ``continuations``: ``(C, horizon − 1, 2)`` the move sequences tried after each move; by
    default the nine unit moves, each held (:func:`held_moves`). ``samples``: per step, for the
    robots checked over time (more: tighter bounds).
    """
    world = moment.world
    positions = np.asarray(positions, float).reshape(-1, 2)
    moves = np.asarray(moves, float).reshape(-1, 2)
    bar = world.robot_radius + SAFETY
    if horizon < 2:
        raise ValueError(f"horizon {horizon}: the shield over time looks at least 2 steps ahead")
    t = int(round(moment.t))
    n, m = len(positions), len(moves)
    static_room = move_clearance(world, positions, moves)                          # (N, M), static only
    k = int(samples)
    s1 = np.arange(k + 1) / k                                                       # the move
    s2 = 1.0 + np.arange(1, (horizon - 1) * k + 1) / k                              # its continuation
    offsets = predicted_offsets(world, t, np.concatenate([s1, s2]), prediction)     # (S, Mv, 2)
    # what the robot sees: every moving obstacle (within the sensing radius), the crowd's discs standing
    shapes = [world.obstacles[i] for i in world.moving] + [CircleObstacle(c, world.robot_radius) for c in world.others]
    paths = [offsets[:, j] for j in range(len(world.moving))] + [np.zeros((len(s1) + len(s2), 2))] * len(world.others)
    reach_moves = float(np.max(np.hypot(*moves.T)))
    # the fastest each obstacle was seen to move over the last two steps (a turn within a step shortens it)
    seen = world.moving_offsets(np.array([t - 2.0, t - 1.0, float(t)]))                     # (3, Mv, 2)
    sensed_speed = np.hypot(*np.diff(seen, axis=0).transpose(2, 0, 1)).max(axis=0).tolist() + [0.0] * len(world.others)
    near = []
    for shape, path, seen_speed in zip(shapes, paths, sensed_speed):
        d_now, _ = shape.signed_distance(positions - path[0])
        speed = max(float(np.max(np.hypot(*np.diff(path, axis=0).T))) * k, seen_speed)
        reach = reach_moves + (horizon - 1) * np.sqrt(2.0) + horizon * speed + bar
        sensed = d_now <= SENSING_RADIUS if prediction == "velocity" else np.ones(n, bool)
        near.append(sensed & (d_now <= reach))
    watched = np.flatnonzero(np.any(near, axis=0)) if near else np.zeros(0, int)
    all_room = static_room - bar
    all_admitted = all_room >= 0
    all_contact = np.full((n, m), np.inf)
    is_watched = np.zeros(n, bool)
    is_watched[watched] = True
    if not len(watched):
        return MoveAssessment(all_admitted, all_contact, all_room, is_watched)
    p = positions[watched]
    w = len(watched)
    cont = held_moves(horizon) if continuations is None else np.asarray(continuations, float)  # (C, L, 2)
    first = p[:, None, None, :] + s1[None, None, :, None] * moves[None, :, None, :]             # (W, M, S1, 2)
    after = (p[:, None, :] + moves[None, :, :])[:, :, None, None, :]                            # (W, M, 1, 1, 2)
    index = np.clip(np.ceil(s2 - 1.0 - 1e-9).astype(int) - 1, 0, cont.shape[1] - 1)          # (S2,) the later step of each sample
    begun = np.concatenate([np.zeros((len(cont), 1, 2)), np.cumsum(cont, axis=1)], axis=1)    # (C, L + 1, 2)
    shift = begun[:, index] + (s2 - 1.0 - index)[None, :, None] * cont[:, index]              # (C, S2, 2)
    later = after + shift[None, None]                                                           # (W, M, C, S2, 2)
    step_move = np.hypot(*moves.T)                                                              # (M,)
    step_cont = np.hypot(cont[:, index, 0], cont[:, index, 1])                                  # (C, S2)
    # static clearance along the continuations, as a lower bound per sample
    c_static = world.static_clearance(later.reshape(-1, 2), near=True).reshape(w, m, len(cont), len(s2))
    c_static = c_static - 0.5 * step_cont[None, None] / k
    # static clearance along the move, per sample (a lower bound at each)
    first_samples = (world.static_clearance(first.reshape(-1, 2), near=True).reshape(w, m, len(s1))
                     - 0.5 * step_move[None, :, None] / k)
    later_samples = c_static
    for j, (shape, path, close) in enumerate(zip(shapes, paths, near)):
        rows = np.flatnonzero(close[watched])
        if not len(rows):
            continue
        speed = np.hypot(*np.diff(path, axis=0).T)
        v1 = float(speed[:k].max()) * k if k else 0.0
        v2 = float(speed[k:].max()) * k if len(speed) > k else v1
        if prediction == "velocity" and TURN_AWARE:
            # the move itself: against every heading the obstacle may take at the speed it was seen at
            v = max(v1, sensed_speed[j])
            d1, _ = shape.signed_distance((first[rows] - path[None, None, :1]).reshape(-1, 2))
            d1 = d1.reshape(len(rows), m, len(s1)) - v * s1[None, None, :] - 0.5 * (step_move[None, :, None] + v) / k
        else:
            d1, _ = shape.signed_distance((first[rows] - path[None, None, :len(s1)]).reshape(-1, 2))
            d1 = d1.reshape(len(rows), m, len(s1)) - 0.5 * (step_move[None, :, None] + v1) / k
        if prediction == "velocity" and TURN_AWARE:
            # each later step as the shield will judge it then, if the obstacle keeps its velocity
            # until that step starts: against every heading from where it will be at that start
            v = max(v2, sensed_speed[j])
            base = np.ceil(s2 - 1e-9) - 1.0                                       # the step each sample is in
            at_start = path[np.searchsorted(np.concatenate([s1, s2]), base)]      # (S2, 2) predicted at that step's start
            d2, _ = shape.signed_distance((later[rows] - at_start[None, None, None]).reshape(-1, 2))
            d2 = (d2.reshape(len(rows), m, len(cont), len(s2)) - v * (s2 - base)[None, None, None, :]
                  - 0.5 * (step_cont[None, None] + v) / k)
        else:
            d2, _ = shape.signed_distance((later[rows] - path[None, None, None, len(s1):]).reshape(-1, 2))
            d2 = d2.reshape(len(rows), m, len(cont), len(s2)) - 0.5 * (step_cont[None, None] + v2) / k
        first_samples[rows] = np.minimum(first_samples[rows], d1)
        later_samples[rows] = np.minimum(later_samples[rows], d2)
    first_room = first_samples.min(axis=2)                                           # (W, M)
    later_room = later_samples.min(axis=3) if len(s2) else np.full((w, m, len(cont)), np.inf)
    admitted = (first_room >= bar) & (later_room >= bar).any(axis=2)
    # time until contact (clearance below the radius) of each move along its best continuation
    r = world.robot_radius
    times = np.concatenate([s1, s2])
    samples = np.concatenate([np.broadcast_to(first_samples[:, :, None, :], (w, m, len(cont), len(s1))),
                              later_samples], axis=3)                                # (W, M, C, S)
    touching = samples < r
    contact = np.where(touching.any(axis=3), times[touching.argmax(axis=3)], np.inf)  # (W, M, C)
    all_admitted[watched] = admitted
    all_contact[watched] = contact.max(axis=2)
    all_room[watched] = np.minimum(first_room[:, :, None], later_room).max(axis=2) - bar
    return MoveAssessment(all_admitted, all_contact, all_room, is_watched)
