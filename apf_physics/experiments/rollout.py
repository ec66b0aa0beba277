"""Run a planner from a batch of starts through the engine: episodes of single robots or formations.

All starts of a world run at once, one :class:`~apf_physics.sim.engine.Stepper` slot per start.
The planner steers each slot's leader; in a formation the followers follow by their own rule
(:class:`~apf_physics.control.formation.FormationTeam`). Each control step the planner is given the
world at that step (:meth:`~apf_physics.sim.engine.Stepper.moment`, built once for the step). How
an episode ends is the stepper's decision (reached, also at the start; collision, trapped,
timeout), with the planner's trap rule.

**Unicycle robots** (``unicycle=``, by default the world file's robot kind,
:attr:`~apf_physics.world.World.unicycle`): the planners are unchanged, they give holonomic
moves from the robots' positions; each step :func:`~apf_physics.control.tracking.track_safely` turns
a leader's move into ``(v, ω)`` (an arc only where it is as clear as the straight move,
else a turn on the spot and the straight move), and a formation's followers follow by the
rule's unicycle form (:class:`~apf_physics.control.tracking.UnicycleFollowers`, the leader slowed by
its ``leader_cap``). Episodes then carry the robots' headings.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from apf_physics.control.shield import SAFETY
from apf_physics.sim.engine import Outcome, Stepper, TrapDetector
from apf_physics.errors import UserError
from apf_physics.control.formation import Formations, FormationTeam, formation_spec, formation_success, links_in_range
from apf_physics.world.kinematics import KINEMATICS, UnicycleLimits, arc_points
from apf_physics.planners.base import Planner
from apf_physics.control.tracking import (CHECK_SAMPLES, UnicycleFollowers, detour_arcs, give_way, leader_caps, team_drive,
                                          track_safely)
from apf_physics.world.core import Frame, World
from apf_physics.world.io.units import length_to_file, points_to_file

UNICYCLE_TRAP_FACTOR = 2
"""A unicycle's trap window is this many times the planner's: each change of direction can cost it
up to two steps of turning on the spot, so following a boundary takes it longer around one spot
(chosen on a validation set: with the holonomic window ``escape`` was declared trapped while
following boundaries)."""


@dataclass
class FormationRecord:
    """What a formation did in an episode, beside its leader's :class:`Episode`.

    Attributes:
        positions: ``(steps + 1, m, 2)`` every robot's positions, the leader first.
        comm_range: The formation's communication range.
        followed: For each follower, the robot it follows.
        robot_robot_collisions: Control steps in which two robots touched.
        robot_obstacle_collisions: Control steps in which a robot touched an obstacle or the edge.
        link_in_range: Per link (follower i and the robot it follows), the share of steps within range.
        crowd: The world, when this formation was one of several in it (else None).
        index: Which of the world's formations it was.
        between_collisions: Control steps in which one of its robots touched a robot of another formation.
        deadlocks: Times it was found blocked by other formations (and given the right of way).
        headings: ``(steps + 1, m)`` every robot's heading [rad] (unicycles; None for holonomic robots).
    """

    positions: np.ndarray
    comm_range: float
    followed: list[int]
    robot_robot_collisions: int
    robot_obstacle_collisions: int
    link_in_range: list[float]
    crowd: str | None = None
    index: int = 0
    between_collisions: int = 0
    deadlocks: int = 0
    headings: np.ndarray | None = None

    @property
    def min_robot_distance(self) -> float | None:
        """The least distance between two of its robots over the episode; None for a robot alone."""
        p = self.positions
        n = p.shape[1]
        if n < 2:
            return None
        diff = p[:, :, None, :] - p[:, None, :, :]
        d = np.sqrt(np.sum(diff * diff, axis=-1))
        return float(d[:, ~np.eye(n, dtype=bool)].min())

    def final_links_in_range(self) -> list[bool]:
        """Per link, whether it is within range at the end (:func:`~apf_physics.control.formation.links_in_range`)."""
        return links_in_range(self.positions[-1], self.followed, self.comm_range).tolist()

    def succeeded(self, reached: bool) -> bool:
        """The formation's success, its leader having ``reached`` the target (:func:`~apf_physics.control.formation.formation_success`)."""
        return formation_success(reached, self.positions[-1], self.followed, self.comm_range)


@dataclass
class Episode:
    """One run from one start: a robot's, or a formation's (its leader's path, and :attr:`formation`).

    Attributes:
        world: The world's name.
        start: The (leader's) start position.
        outcome: ``"reached"``, ``"collision"``, ``"trapped"`` or ``"timeout"``.
        steps: Control steps taken.
        path: ``(steps + 1, 2)`` the (leader's) positions, the start first.
        contacts: What was touched when the episode ended in a collision (``"obstacle"``,
            ``"wall"``, ``"robot"``).
        formation: The formation's record, for a formation's episode.
        headings: ``(steps + 1,)`` the (leader's) heading [rad] at each position of :attr:`path`
            (unicycles; None for holonomic robots).
        frame: The world file's units and coordinates (:attr:`World.frame`): positions and lengths
            here are in steps, :meth:`to_dict` gives them in the file's.
    """

    world: str
    start: np.ndarray
    outcome: str
    steps: int
    path: np.ndarray
    contacts: list[str] = field(default_factory=list)
    formation: FormationRecord | None = None
    headings: np.ndarray | None = None
    frame: Frame = Frame()

    @property
    def success(self) -> bool:
        """Reached; for a formation, also every follower within range of the robot it follows at the end."""
        reached = self.outcome == "reached"
        return reached if self.formation is None else self.formation.succeeded(reached)

    @property
    def path_length(self) -> float:
        return float(np.sum(np.hypot(*np.diff(self.path, axis=0).T))) if len(self.path) > 1 else 0.0

    def to_dict(self) -> dict:
        """The episode as JSON: positions and lengths in the world file's units and coordinates
        (``units``: the unit's name, or None when the file names none); ``steps`` counts control steps."""
        frame = self.frame
        data = {
            "world": self.world,
            "units": frame.name or None,
            "start": [round(float(v), 9) for v in points_to_file(frame, self.start)],
            "success": self.success,
            "collision": self.outcome == "collision",
            "collision_with": list(self.contacts),
            "trapped": self.outcome == "trapped",
            "outcome": self.outcome,
            "steps": int(self.steps),
            "path_length": round(length_to_file(frame, self.path_length), 4),
            "final_position": [round(float(v), 4) for v in points_to_file(frame, self.path[-1])],
        }
        if self.headings is not None:
            data["final_heading"] = round(float(self.headings[-1]), 4)
        f = self.formation
        if f is not None:
            links = f.final_links_in_range()
            reached = self.outcome == "reached"
            roles = ["leader"] + [f"follower{i + 1}" for i in range(len(f.followed))]
            data["robots"] = [
                {"role": role, "success": reached if k == 0 else reached and links[k - 1],
                 "final_position": [round(float(v), 4) for v in points_to_file(frame, f.positions[-1, k])]}
                for k, role in enumerate(roles)]
            closest = f.min_robot_distance
            data["min_robot_distance"] = None if closest is None else round(length_to_file(frame, closest), 4)
            data["robot_robot_collisions"] = f.robot_robot_collisions
            data["robot_obstacle_collisions"] = f.robot_obstacle_collisions
            data["link_in_range"] = [round(v, 4) for v in f.link_in_range]
            data["trajectory"] = np.round(points_to_file(frame, f.positions), 4).tolist()
            if f.headings is not None:
                data["headings"] = np.round(f.headings, 4).tolist()
            if f.crowd is not None:
                data["crowd"], data["formation"] = f.crowd, f.index
                data["between_collisions"], data["deadlocks"] = f.between_collisions, f.deadlocks
        return data


def default_max_steps(world: World) -> int:
    """A generous step limit: four times the map's perimeter-half."""
    return int(4 * (world.size[0] + world.size[1]))


def robot_limits(world: World, unicycle: UnicycleLimits | bool | None = None) -> UnicycleLimits | None:
    """The unicycle limits a run of ``world`` uses, or None for holonomic robots.

    ``unicycle``: None, the world file's robot kind (:attr:`World.unicycle`); False, holonomic;
    True, unicycles with the world file's limits, or the default :class:`UnicycleLimits`;
    limits, unicycles with those.
    """
    if unicycle is None:
        return world.unicycle
    if unicycle is False:
        return None
    if unicycle is True:
        return world.unicycle if world.unicycle is not None else UnicycleLimits()
    return unicycle


def kinematics_option(kinematics: str | None) -> bool | None:
    """``--kinematics``'s value as :func:`robot_limits`'s ``unicycle``: None (the world file's),
    ``"holonomic"`` False, ``"unicycle"`` True.

    Raises:
        UserError: Another value.
    """
    if kinematics is None:
        return None
    if kinematics not in KINEMATICS:
        raise UserError(f"--kinematics: unknown robot kind {kinematics!r} (known: {', '.join(KINEMATICS)}; "
                        "default: the world file's robot.kinematics)")
    return kinematics == "unicycle"


class _Trace:
    """What a rollout keeps of its slots' episodes: every step's positions (and headings), and what
    each slot's robots touched at the step it collided (``robots``: each slot's robots' global
    indices of the stepper)."""

    def __init__(self, stepper: Stepper, initial: np.ndarray, robots: Sequence[range]):
        self.positions = [initial.copy()]
        self.headings = [stepper.headings.copy()] if stepper.unicycle is not None else None
        self.robots = robots
        self.contacts: list[list[str]] = [[] for _ in robots]

    def record(self, stepper: Stepper, report) -> None:
        self.positions.append(report.positions)
        if self.headings is not None:
            self.headings.append(stepper.headings.copy())
        for slot in np.flatnonzero(report.collided).tolist():
            mine = self.robots[slot]
            self.contacts[slot] = sorted({c.kind for c in report.contacts.contacts if c.robot in mine})

    def episode(self, slot: int, steps: int, size: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """``(positions (steps + 1, m, 2), headings (steps + 1, m) or None)`` of a slot's episode
        (its first ``size`` robots)."""
        robots = slice(None) if size is None else slice(0, size)
        positions = np.stack([p[slot, robots] for p in self.positions[:steps + 1]])
        theta = None if self.headings is None else np.stack([h[slot, robots] for h in self.headings[:steps + 1]])
        return positions, theta


def rollout(world: World, planner: Planner, starts: Sequence[Sequence[float]] | np.ndarray,
            max_steps: int | None = None, trap: TrapDetector = TrapDetector(), formation: bool = False,
            unicycle: UnicycleLimits | bool | None = None) -> list[Episode]:
    """Run ``planner`` from every start in ``world``, all at once, through the engine.

    Args:
        world: The world.
        planner: Steers the robots (the leaders, in formations).
        starts: (n, 2) start positions (of the leaders).
        max_steps: Step limit (default :func:`default_max_steps`).
        trap: Trap detection; its rule and window are replaced by the planner's
            (:attr:`Planner.trap_rule`, :attr:`Planner.trap_window`).
        formation: Run the world's formation (:func:`~apf_physics.control.formation.formation_spec`):
            followers placed behind each leader, moved by their own rule.
        unicycle: The robot kind (:func:`robot_limits`; default the world file's): with limits,
            the robots are unicycles driving the planner's moves (see the module docstring);
            their trap window is :data:`UNICYCLE_TRAP_FACTOR` times the planner's.

    Returns:
        One episode per start, in order.

    Raises:
        UserError: A formation's followers find no free position near a start.
    """
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    n = len(starts)
    if n == 0:
        return []
    max_steps = default_max_steps(world) if max_steps is None else int(max_steps)
    limits = robot_limits(world, unicycle)
    team = FormationTeam(formation_spec(world), n) if formation else None
    m = 1 if team is None else team.robots
    planner.reset(world, starts.copy())   # first: the model it loads sets its trap window
    window = (planner.trap_window or trap.window) * (1 if limits is None else UNICYCLE_TRAP_FACTOR)
    detector = TrapDetector(planner.trap_rule, window, trap.radius, trap.min_drop)
    stepper = Stepper([world], n, m, max_steps=max_steps, trap=detector, unicycle=limits)
    slots = np.arange(n)
    initial = starts[:, None, :] if team is None else team.starts(world, starts)
    stepper.start(slots, initial)
    followers: list[UnicycleFollowers] = []
    if team is not None and limits is None:
        team.reset(slots, [world] * n, initial)
    elif team is not None:
        states = stepper.states()
        for slot in range(n):
            followers.append(UnicycleFollowers(world, team.spec, limits))
            followers[slot].reset(states[slot])
    trace = _Trace(stepper, initial, [range(s * m, (s + 1) * m) for s in range(n)])
    robot_steps = np.zeros(n, int)
    obstacle_steps = np.zeros(n, int)
    in_range = np.zeros((n, max(m - 1, 0)))
    while stepper.running.any():
        active = stepper.running
        positions = stepper.positions
        moment = stepper.moment(int(np.flatnonzero(active)[0]))   # every running slot is at the same step
        leader = planner.act(positions[:, 0], active, moment)
        gave_up = planner.stuck()
        gave_up = active & gave_up if gave_up is not None else np.zeros(n, bool)
        moving = active & ~gave_up
        if limits is not None:
            commands = unicycle_commands(stepper.states(), leader, moving, moment, limits, followers)
        elif team is None:
            commands = np.where(moving[:, None], leader, 0.0)[:, None, :]
        else:
            commands = team.commands(positions, leader, moving)
        report = stepper.step(commands, gave_up)
        trace.record(stepper, report)
        touched = report.contacts
        if team is not None:
            moved = report.moved
            robot_steps += moved & touched.robot.reshape(n, m).any(axis=1)
            obstacle_steps += moved & touched.obstacle_or_edge.reshape(n, m).any(axis=1)
            in_range += moved[:, None] & links_in_range(report.positions, team.followed, team.spec.comm_range)

    episodes = []
    for i in range(n):
        steps = int(stepper.steps[i])
        positions, theta = trace.episode(i, steps)
        record = None
        if team is not None:
            record = FormationRecord(positions, team.spec.comm_range, team.followed, int(robot_steps[i]),
                                     int(obstacle_steps[i]), list(in_range[i] / max(steps, 1)),
                                     headings=None if theta is None else theta.copy())
        episodes.append(Episode(world.name, starts[i], Outcome(stepper.outcome[i]).label, steps,
                                positions[:, 0].copy(), trace.contacts[i], record,
                                headings=None if theta is None else theta[:, 0].copy(), frame=world.frame))
    return episodes


def unicycle_commands(states: np.ndarray, leader_moves: np.ndarray, moving: np.ndarray, moment,
                      limits: UnicycleLimits, followers: Sequence[UnicycleFollowers] = ()) -> np.ndarray:
    """(S, m, 2) every unicycle's ``(v, ω)`` this step: the leaders' moves driven by
    :func:`~apf_physics.control.tracking.track_safely` (slowed by their followers'
    :meth:`~apf_physics.control.tracking.UnicycleFollowers.leader_cap`), the followers' by their rule
    (:meth:`~apf_physics.control.tracking.UnicycleFollowers.drive`, which may stop a leader about to meet
    a follower); slots not ``moving`` are told to stop.

    Args:
        states: (S, m, 5) every robot's ``(x, y, θ, v, ω)`` (:meth:`Stepper.states`).
        leader_moves: (S, 2) the planner's moves of the leaders.
        moving: (S,) bool, the slots that move this step.
        moment: The world at this step.
        limits: The robots' limits.
        followers: One :class:`~apf_physics.control.tracking.UnicycleFollowers` per slot (formations), or none.
    """
    moves = np.where(moving[:, None], leader_moves, 0.0)
    cap = leader_caps(states, moving, followers, limits) if followers else None
    v, omega = track_safely(states[:, 0], moves, moment, limits, speed_cap=cap)
    return team_drive(states, v, omega, moving, followers)


CROWD_TRAP_WINDOW = 40
"""Trap window of a leader among other formations: waiting for one to pass is not being trapped."""


def rollout_formations(world: World, planner: Planner, max_steps: int | None = None,
                       trap: TrapDetector = TrapDetector(), unicycle: UnicycleLimits | bool | None = None) -> list[Episode]:
    """Run every formation of a world with ``formations`` at once, each to its own target.

    Each leader is steered by its own copy of ``planner`` in its own field (its target,
    the obstacles, and the other formations' robots as discs where they stand); followers
    follow; every move gets the right of way of :class:`~apf_physics.control.formation.Formations`.

    Unicycles (``unicycle``, default the world file's robot kind): each leader's move is driven
    by :func:`~apf_physics.control.tracking.track_safely` in its own field, its followers by
    :meth:`~apf_physics.control.tracking.UnicycleFollowers.drive`; then every robot of every formation
    gives way (:func:`formations_unicycle_commands`: a detour, else a stop, in the crowd's order, a
    deadlocked formation first) so that no two robots' arcs meet.

    Returns:
        One episode per formation, in the world's order (:attr:`FormationRecord.crowd` names the world).
    """
    formations = Formations(world)
    count, m = formations.count, formations.robots
    max_steps = default_max_steps(world) if max_steps is None else int(max_steps)
    limits = robot_limits(world, unicycle)
    initial = formations.starts()
    # the planner given is reset first (its model loaded, as a caller's describe() reads it); each
    # formation's leader is a copy of it, reset on its formation's world
    planner.reset(formations.worlds[0], initial[0, :1].copy())
    planners = [copy.copy(planner) for _ in range(count)]
    for f, p in enumerate(planners):
        p.reset(formations.worlds[f], initial[f, :1].copy())
    window = max(planner.trap_window or trap.window, *(p.trap_window or trap.window for p in planners), CROWD_TRAP_WINDOW)
    window *= 1 if limits is None else UNICYCLE_TRAP_FACTOR
    stepper = Stepper(formations.worlds, count, m, max_steps=max_steps,
                      trap=TrapDetector(planner.trap_rule, window, trap.radius, trap.min_drop), crowds=[0] * count,
                      unicycle=limits)
    slots = np.arange(count)
    stepper.start(slots, initial, world_ids=slots, present=formations.present)
    formations.reset(initial)
    followers: list[UnicycleFollowers] = []
    if limits is not None:
        states = stepper.states()
        for f in range(count):
            followers.append(UnicycleFollowers(formations.worlds[f], formations.tasks[f].spec, limits))
            followers[-1].reset(states[f, :formations.sizes[f]])
    trace = _Trace(stepper, initial, [range(f * m, (f + 1) * m) for f in range(count)])
    within = np.zeros(count, int)
    between = np.zeros(count, int)
    obstacle_steps = np.zeros(count, int)
    in_range = [np.zeros(size - 1) for size in formations.sizes]
    step = 0
    while stepper.running.any():
        active = stepper.running
        positions = stepper.positions
        leader, gave_up, views = leader_moves(formations, planners, positions, active, step)
        if limits is None:
            commands = formations.commands(positions, leader, active & ~gave_up, step)
        else:
            commands = formations_unicycle_commands(formations, stepper.states(), leader, active & ~gave_up, views,
                                                    limits, followers, step)
        report = stepper.step(commands, gave_up)
        step += 1
        formations.watch(report.positions, report.moved, step)
        trace.record(stepper, report)
        touched = report.contacts
        pairs = touched.rows   # robot-robot rows: complete as read (only static obstacles are named later)
        robot_pairs = pairs[pairs[:, 1] == 2] if len(pairs) else pairs
        for f in np.flatnonzero(report.moved).tolist():
            mine = (robot_pairs[:, 0] // m == f) if len(robot_pairs) else np.zeros(0, bool)
            others = robot_pairs[mine, 2] // m if len(robot_pairs) else np.zeros(0, int)
            within[f] += bool(np.any(others == f))
            between[f] += bool(np.any(others != f))
            robots = slice(f * m, f * m + formations.sizes[f])
            obstacle_steps[f] += bool(touched.obstacle_or_edge[robots].any())
            in_range[f] += links_in_range(report.positions[f, :formations.sizes[f]], formations.followed[f],
                                          formations.tasks[f].spec.comm_range)

    episodes = []
    for f in range(count):
        steps = int(stepper.steps[f])
        positions, theta = trace.episode(f, steps, formations.sizes[f])
        record = FormationRecord(positions, formations.tasks[f].spec.comm_range, formations.followed[f],
                                 int(within[f] + between[f]), int(obstacle_steps[f]), list(in_range[f] / max(steps, 1)),
                                 crowd=world.name, index=f, between_collisions=int(between[f]),
                                 deadlocks=int(formations.deadlocks[f]), headings=theta)
        episodes.append(Episode(world.name, formations.tasks[f].start, Outcome(stepper.outcome[f]).label, steps,
                                positions[:, 0].copy(), trace.contacts[f], record,
                                headings=None if theta is None else theta[:, 0].copy(), frame=world.frame))
    return episodes


def leader_moves(formations: Formations, planners: Sequence[Planner], positions: np.ndarray, active: np.ndarray,
                 step: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """Each active formation's leader's move, by its own planner in its own view (its target, the other
    formations' robots and the bystanders as discs where they stand): ``(moves (F, 2), gave up (F,),
    views {f: the view at this step})``."""
    count = formations.count
    leader = np.zeros((count, 2))
    gave_up = np.zeros(count, bool)
    views = {}
    for f in np.flatnonzero(active[:count]).tolist():
        view = planners[f].world = formations.view(positions, f)
        views[f] = view.at(step)
        leader[f] = planners[f].act(positions[f, :1], np.ones(1, bool), views[f])[0]
        stuck = planners[f].stuck()
        gave_up[f] = bool(stuck[0]) if stuck is not None else False
    return leader, gave_up, views


def formations_unicycle_commands(formations: Formations, states: np.ndarray, leader_moves: np.ndarray, moving: np.ndarray,
                            views: dict, limits: UnicycleLimits, followers: Sequence[UnicycleFollowers],
                            step: int) -> np.ndarray:
    """(F, m, 2) every unicycle's ``(v, ω)`` of several formations in one world this step.

    Each moving formation: its leader's move driven by :func:`~apf_physics.control.tracking.track_safely`
    in its own view (``views[f]``, the other formations' robots as discs), slowed by its
    followers' ``leader_cap``; its followers by :meth:`UnicycleFollowers.drive`. Then all robots
    give way to one another (:func:`~apf_physics.control.tracking.give_way`), formations in the crowd's
    order (one in a deadlock first), each leader before its followers.
    """
    count, m = states.shape[:2]
    commands = np.zeros((count, m, 2))
    for f in np.flatnonzero(moving).tolist():
        size = formations.sizes[f]
        cap = followers[f].leader_cap(states[f, :size])
        v, omega = track_safely(states[f, :1], leader_moves[f:f + 1], views[f], limits, speed_cap=cap)
        commands[f, :size, 0], commands[f, :size, 1] = followers[f].drive(states[f, :size], v[0], omega[0])
    flat_states = states.reshape(-1, 5)
    flat = commands.reshape(-1, 2)
    arcs = arc_points(flat_states, flat[:, 0], flat[:, 1], CHECK_SAMPLES)
    order = sorted(range(count), key=lambda f: (formations.first_until[f] < step, f))
    robots = np.array([f * m + r for f in order for r in range(formations.sizes[f])], np.intp)
    contact = 2 * formations.world.robot_radius + SAFETY
    now = formations.world.at(step)
    detours, detour_commands = detour_arcs(flat_states, arcs, limits, now)
    # a robot pushed off its planner's path (a detour) may be given a move that nears an obstacle:
    # none comes nearer than the planners' margin, or than it already is
    clear = now.clearance(arcs.reshape(-1, 2)).reshape(len(arcs), -1)
    blocked = (clear[:, 1:].min(axis=1) < np.minimum(now.world.robot_radius + SAFETY, clear[:, 0] - 1e-9)) \
        & (flat[:, 0] != 0)
    flat[:, 0], choice = give_way(arcs, flat[:, 0], robots, contact, detours, blocked)
    took = np.flatnonzero(choice >= 0)
    flat[took] = detour_commands[took, choice[took]]
    return flat.reshape(count, m, 2)
