"""Fleets: many robots on one map, each to its own goal, all at once, through the engine.

:func:`rollout_fleet` runs a :class:`~apf_physics.world.core.Fleet` (a world file's ``robots:``, or
the first N lines of a MovingAI scenario file) as one crowd of single-robot slots of one
:class:`~apf_physics.sim.engine.Stepper` (one pymunk space: robots meet). Each control step the
planner scores every robot's nine unit moves toward its own goal
(:meth:`~apf_physics.planners.base.Planner.fleet_values`) and the fleet's rule picks the moves
(:func:`~apf_physics.control.fleet.fleet_moves`: priority inheritance under the shield among robots).

**One-shot** (the MAPF benchmark's convention): the run ends when every robot stands on its goal
at once, or at the step limit. A robot's cost is the step at which it last arrived on its goal
(a robot on its goal may be pushed off it and come back; one that is not on it at the end costs
every step of the run); the sum of costs and the makespan are over these. **Lifelong**: a robot
that arrives is given its next goal at once, drawn from a seeded stream of its own (free nodes
of its region, the same for every planner); the run lasts a fixed horizon and its throughput is
the goals reached per step.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from apf_physics.control.fleet import (FleetNodes, GoalStream, Lattice, Priorities, fleet_moves, place_fleet,
                                       preferences)
from apf_physics.control.shield import ACTIONS
from apf_physics.errors import UserError
from apf_physics.control.formation import Formations, links_in_range
from apf_physics.experiments.rollout import Episode, FormationRecord, default_max_steps, leader_moves
from apf_physics.planners.base import Planner
from apf_physics.sim.engine import Outcome, Stepper
from apf_physics.world.core import Fleet, World
from apf_physics.world.io.units import length_to_file, points_to_file


@dataclass
class FleetRun:
    """What a fleet did (:func:`rollout_fleet`).

    Attributes:
        world: The map.
        planner: The planner's name.
        fleet: The robots (their starts and targets).
        positions: ``(steps + 1, N, 2)`` every robot's position at every step.
        goals: ``(steps + 1, N)`` each robot's goal node at every step (lifelong: it changes).
        cost: (N,) one-shot: the step each robot last arrived on its goal (the run's steps if it is
            not on it at the end); lifelong: the run's steps.
        arrived: (N,) bool: on its goal at the end (one-shot); lifelong: reached at least one goal.
        outcome: (N,) each robot's :class:`~apf_physics.sim.engine.Outcome` label.
        robot_robot: Robot pairs that touched, summed over the steps.
        robot_obstacle: Robots that touched an obstacle or the map's edge, summed over the steps.
        reached: (N,) goals each robot reached (lifelong; one-shot: 1 if it arrived).
        seconds: Wall time of the run, the planner's tables included.
        lifelong: The run's horizon in lifelong mode, else None.
        tables: ``(built, peak bytes)`` of the planner's per-goal tables.
        lattice: The lattice the robots stood on.
        parts: Seconds spent in the planner's values (its per-goal tables built included), the fleet's
            rule and the engine's step.
        formations: The world's formations among the fleet, an episode each (None: it has none).
    """

    world: World
    planner: str
    fleet: Fleet
    positions: np.ndarray
    goals: np.ndarray
    cost: np.ndarray
    arrived: np.ndarray
    outcome: list[str]
    robot_robot: int
    robot_obstacle: int
    reached: np.ndarray
    seconds: float
    lifelong: int | None = None
    tables: tuple[int, int] = (0, 0)
    lattice: Lattice | None = field(default=None, repr=False)
    parts: dict = field(default_factory=dict)
    formations: list[Episode] | None = None

    @property
    def steps(self) -> int:
        """Control steps the run took."""
        return len(self.positions) - 1

    def drawn(self) -> tuple[np.ndarray, np.ndarray]:
        """``(positions, goals)``, each ``(steps + 1, R, 2)``: every robot at every step and its goal, the
        fleet's robots first, then the formations' (held where they stopped; a leader's goal is its
        formation's target, a follower's is NaN: it has none of its own). What a video draws."""
        positions = self.positions
        goals = self.lattice.points(self.goals.ravel()).reshape(positions.shape)
        for episode in self.formations or ():
            mine = episode.formation.positions
            mine = np.concatenate([mine, np.repeat(mine[-1:], len(positions) - len(mine), axis=0)])
            target = np.full(mine.shape, np.nan)
            target[:, 0] = self.world.formations[episode.formation.index].target
            positions = np.concatenate([positions, mine], axis=1)
            goals = np.concatenate([goals, target], axis=1)
        return positions, goals

    def episodes(self) -> list[Episode]:
        """One :class:`~apf_physics.experiments.rollout.Episode` per robot: its path up to its cost."""
        out = []
        for i in range(len(self.fleet)):
            steps = int(self.cost[i])
            out.append(Episode(self.world.name, self.fleet.starts[i], self.outcome[i], steps,
                               self.positions[:steps + 1, i].copy(), frame=self.world.frame))
        return out

    def summary(self) -> dict:
        """The run's figures (lengths in the world file's units; see :func:`fleet_summary`)."""
        return fleet_summary(self)

    def to_dict(self) -> dict:
        """The run as JSON: per robot (success, collision, steps, path_length, ...) and the summary."""
        frame = self.world.frame
        robots = []
        for i, episode in enumerate(self.episodes()):
            data = episode.to_dict()
            data.update(robot=i, label=self.fleet.labels[i],
                        target=[round(float(v), 9) for v in points_to_file(frame, self.fleet.targets[i])])
            if self.fleet.optimal is not None:
                data["optimal"] = round(length_to_file(frame, float(self.fleet.optimal[i])), 4)
            if self.lifelong is not None:
                data["goals_reached"] = int(self.reached[i])
            robots.append(data)
        out = {"world": self.world.name, "planner": self.planner, "robots": robots, "summary": self.summary()}
        if self.formations is not None:
            out["formations"] = [e.to_dict() for e in self.formations]
        return out


def fleet_summary(run: FleetRun) -> dict:
    """All arrived, the share arrived, makespan, sum of costs (steps, MAPF's convention: each robot's
    last arrival), path lengths, robot–robot and robot–obstacle collisions, the time per robot-step
    (wall time over robots × steps: every robot takes part in every step), the planner's tables; with
    optimal lengths, the sums of costs and of path lengths over the sum of the optima; lifelong: goals
    reached and the throughput in goals per step."""
    n, frame = len(run.fleet), run.world.frame
    paths = np.array([e.path_length for e in run.episodes()])
    data = {"robots": n, "steps": run.steps, "units": frame.name or None,
            "all_arrived": bool(run.arrived.all()), "arrived": int(run.arrived.sum()),
            "arrived_share": round(float(run.arrived.mean()), 4) if n else 0.0,
            "makespan": int(run.cost.max(initial=0)) if run.arrived.all() else None,
            "sum_of_costs": int(run.cost.sum()), "path_length_sum": round(length_to_file(frame, float(paths.sum())), 3),
            "robot_robot_collisions": int(run.robot_robot), "robot_obstacle_collisions": int(run.robot_obstacle),
            "seconds": round(run.seconds, 2),
            "ms_per_robot_step": round(1000 * run.seconds / max(n * run.steps, 1), 4),
            "goal_tables_built": run.tables[0], "goal_tables_peak_bytes": run.tables[1],
            "seconds_by_part": {k: round(v, 2) for k, v in run.parts.items()}}
    if run.fleet.optimal is not None:
        best = float(np.sum(run.fleet.optimal))
        data.update(optimal_sum=round(length_to_file(frame, best), 3),
                    soc_over_optimal=round(float(run.cost.sum()) / best, 4) if best > 0 else None,
                    path_over_optimal=round(float(paths.sum()) / best, 4) if best > 0 else None)
    if run.formations is not None:
        data.update(formations=len(run.formations), formations_arrived=sum(e.success for e in run.formations))
    if run.lifelong is not None:
        goals = int(run.reached.sum())
        data.update(horizon=run.lifelong, goals_reached=goals, throughput=round(goals / max(run.steps, 1), 4))
        for key in ("all_arrived", "arrived", "arrived_share", "makespan", "sum_of_costs"):
            data.pop(key)
    return data


def rollout_fleet(world: World, planner: Planner, fleet: Fleet | None = None, max_steps: int | None = None,
                  lifelong: int | None = None, seed: int = 0,
                  progress: Callable[[int, int], None] | None = None) -> FleetRun:
    """Run a fleet all at once through the engine (see the module docstring).

    Args:
        world: The map.
        planner: Scores every robot's moves (:meth:`~apf_physics.planners.base.Planner.fleet_values`).
        fleet: The robots (default: the world's ``robots:``).
        max_steps: One-shot: the step limit (default :func:`~apf_physics.experiments.rollout.default_max_steps`).
        lifelong: Run this many steps, a robot given its next goal as soon as it arrives (None: one-shot).
        seed: The lifelong goal streams' seed, and PIBT's tie-break among equal priorities.
        progress: Called with ``(step, robots on their goal)`` after each step.

    Raises:
        UserError: The fleet does not fit its lattice (:func:`place_fleet`), or the planner cannot drive a fleet.
    """
    fleet = world.robots if fleet is None else fleet
    if fleet is None or not len(fleet):
        raise UserError(f"{world.label}: no robots to run as a fleet")
    clock = time.perf_counter()
    placed = place_fleet(world, fleet, distinct_goals=lifelong is None)
    limit = int(lifelong) if lifelong is not None else (default_max_steps(world) if max_steps is None else int(max_steps))
    planner.reset(world, np.zeros((0, 2)))   # the world, and no robot of its own: a fleet's are scored by fleet_values
    state = _FleetState(world, placed, fleet, GoalStream(placed.lattice, placed.starts, seed) if lifelong else None,
                        seed, planner)
    for step in range(1, limit + 1):
        if lifelong is None and state.done:
            break
        state.step(planner, step)
        if progress is not None:
            progress(step, int(state.at_goal.sum()))
    return state.finish(planner, lifelong, time.perf_counter() - clock)


class _FleetState:
    """A fleet's run as it goes: the stepper, every robot's node, goal, cost and goals reached, the trace.

    The fleet's robots are slots ``F, F + 1, ...`` of one crowd of the stepper, after the world's
    formations (slots ``0 .. F − 1``, :class:`_Formations`), if it has any.
    """

    def __init__(self, world: World, placed: FleetNodes, fleet: Fleet, stream: GoalStream | None, seed: int,
                 planner: Planner):
        n = len(fleet)
        self.world, self.lattice, self.fleet, self.stream = world, placed.lattice, fleet, stream
        self.teams = _Formations(world, planner, fleet.starts) if world.formations else None
        f, m = (self.teams.formations.count, self.teams.formations.robots) if self.teams else (0, 1)
        self.first = f
        self.stepper = Stepper(([] if self.teams is None else self.teams.formations.worlds) + [world], f + n, m,
                               crowds=[0] * (f + n), arrival="continue")
        initial, present = np.repeat(fleet.starts[:, None, :], m, axis=1), np.zeros((n, m), bool)
        present[:, 0] = True
        if self.teams is not None:
            initial = np.concatenate([self.teams.initial, initial])
            present = np.concatenate([self.teams.formations.present, present])
        self.slots = np.arange(f, f + n)
        self.stepper.start(np.arange(f + n), initial, world_ids=np.minimum(np.arange(f + n), f), present=present)
        self.goals = placed.goals.copy()
        self.stepper.set_targets(self.slots, self.lattice.points(self.goals))
        self.priorities = Priorities(n, seed)
        self.nodes = placed.starts.copy()
        self.at_goal = self.nodes == self.goals
        self.cost = np.zeros(n, np.intp)
        self.reached = np.zeros(n, np.intp)
        self.trace, self.goal_trace = [fleet.starts.copy()], [self.goals.copy()]
        self.robot_robot = self.robot_obstacle = 0
        self.seconds = {"values": 0.0, "rule": 0.0, "physics": 0.0}

    @property
    def done(self) -> bool:
        """One-shot: every robot on its goal, and no formation still on its way."""
        return bool(self.at_goal.all()) and (self.teams is None or not self.stepper.running[:self.first].any())

    def step(self, planner: Planner, step: int) -> None:
        """One control step: the formations' moves, the planner's values, the fleet's rule, the engine;
        arrivals (and new goals)."""
        lattice, clock, f = self.lattice, time.perf_counter(), self.first
        commands = np.zeros(self.stepper.positions.shape)
        movers = gave_up = None
        if self.teams is not None:
            commands[:f], gave_up, movers = self.teams.moves(self.stepper, step - 1)
        values = planner.fleet_values(lattice, self.nodes, self.goals)
        now = time.perf_counter()
        self.seconds["values"] += now - clock
        prefs = preferences(values, lattice.ok[self.nodes])
        moves = fleet_moves(lattice, self.nodes, prefs, self.priorities.order(), pinned=~self.stepper.running[f:],
                            movers=movers)
        commands[f:, 0] = ACTIONS[moves]
        clock = time.perf_counter()
        self.seconds["rule"] += clock - now
        report = self.stepper.step(commands, gave_up)
        self.seconds["physics"] += time.perf_counter() - clock
        self.robot_robot += _robot_pairs(report.contacts)
        self.robot_obstacle += int(report.contacts.obstacle_or_edge.sum()) if report.contacts.touched else 0
        if self.teams is not None:
            self.teams.after(self.stepper, report, step)
        self.nodes = lattice.nearest(report.positions[f:, 0])
        arrived = self.nodes == self.goals
        self.cost = np.where(arrived & ~self.at_goal, step, self.cost)   # (re)arrived at this step
        if self.stream is not None and arrived.any():
            for i in np.flatnonzero(arrived).tolist():
                self.reached[i] += 1
                self.goals[i] = self.stream.next(i, int(self.nodes[i]))
            self.stepper.set_targets(self.slots[arrived], lattice.points(self.goals[arrived]))
            arrived = self.nodes == self.goals
        self.at_goal = arrived
        self.priorities.update(arrived)
        self.trace.append(report.positions[f:, 0].copy())
        self.goal_trace.append(self.goals.copy())

    def finish(self, planner: Planner, lifelong: int | None, seconds: float) -> FleetRun:
        """End every robot's episode (reached: on its goal, one-shot) and gather the run."""
        steps, stepper = len(self.trace) - 1, self.stepper
        if lifelong is not None:
            cost, arrived, reached = np.full(len(self.fleet), steps), self.reached > 0, self.reached
        else:
            cost = np.where(self.at_goal, self.cost, steps)
            arrived = self.at_goal & stepper.running[self.first:]
            reached = arrived.astype(np.intp)
        stepper.finish(self.slots[arrived], Outcome.REACHED)
        stepper.finish(np.arange(len(stepper.outcome)), Outcome.TIMEOUT)
        tables = planner.goal_tables(self.lattice) if type(planner).fleet_values is not Planner.fleet_values else None
        return FleetRun(self.world, planner.name, self.fleet, np.stack(self.trace), np.stack(self.goal_trace), cost,
                        arrived, [Outcome(o).label for o in stepper.outcome[self.first:]], self.robot_robot,
                        self.robot_obstacle, reached, seconds, lifelong,
                        (tables.built, tables.peak) if tables is not None else (0, 0), self.lattice, dict(self.seconds),
                        None if self.teams is None else self.teams.episodes(self.world, stepper))


class _Formations:
    """A world's formations among its fleet: each leader steered by its own copy of the fleet's planner,
    its followers by their rule, every move given the right of way of
    :class:`~apf_physics.control.formation.Formations` with the fleet's robots standing as bystanders;
    the fleet then checks its moves against theirs (:func:`~apf_physics.control.fleet.fleet_moves`'s
    ``movers``). A formation whose leader reaches its target stops there."""

    def __init__(self, world: World, planner: Planner, bystanders: np.ndarray):
        self.formations = Formations(world)
        self.formations.bystanders = bystanders
        self.initial = self.formations.starts()
        self.formations.reset(self.initial)
        self.planners = [copy.copy(planner) for _ in range(self.formations.count)]
        for f, p in enumerate(self.planners):
            p.reset(self.formations.worlds[f], self.initial[f, :1].copy())
        self.trace = [self.initial.copy()]

    def moves(self, stepper: Stepper, step: int) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """``(commands (F, m, 2), gave up (S,), movers)``: the formations' moves this step."""
        formations, count = self.formations, self.formations.count
        positions = stepper.positions
        formations.bystanders = positions[count:, 0]
        active = stepper.running[:count]
        leader, gave_up, _ = leader_moves(formations, self.planners, positions[:count], active, step)
        commands = formations.commands(positions[:count], leader, active & ~gave_up, step)
        present = formations.present
        given_up = np.zeros(len(stepper.outcome), bool)
        given_up[:count] = gave_up & active
        return commands, given_up, (positions[:count][present], commands[present])

    def after(self, stepper: Stepper, report, step: int) -> None:
        """A formation whose leader reached its target stops; the deadlock watch; the trace."""
        count = self.formations.count
        stepper.finish(np.flatnonzero(report.reached[:count]), Outcome.REACHED)
        self.formations.watch(report.positions[:count], report.moved[:count], step)
        self.trace.append(report.positions[:count].copy())

    def episodes(self, world: World, stepper: Stepper) -> list[Episode]:
        """One episode per formation (its leader's path, its robots' in the record)."""
        out = []
        positions = np.stack(self.trace)
        for f in range(self.formations.count):
            size = self.formations.sizes[f]
            steps = int(stepper.steps[f])
            mine = positions[:steps + 1, f, :size]
            record = FormationRecord(mine, self.formations.tasks[f].spec.comm_range, self.formations.followed[f], 0, 0,
                                     list(links_in_range(mine[1:], self.formations.followed[f],
                                                         self.formations.tasks[f].spec.comm_range).mean(axis=0))
                                     if steps else [], crowd=world.name, index=f)
            out.append(Episode(world.name, self.formations.tasks[f].start, Outcome(stepper.outcome[f]).label, steps,
                               mine[:, 0].copy(), formation=record, frame=world.frame))
        return out


def _robot_pairs(contacts) -> int:
    """Robot pairs touching in a step's contact log."""
    if not contacts.touched:
        return 0
    rows = contacts.rows
    robots = rows[rows[:, 1] == 2] if len(rows) else rows
    if not len(robots):
        return 0
    return len({(min(a, b), max(a, b)) for a, b in zip(robots[:, 0].tolist(), robots[:, 2].tolist())})


def format_fleet_table(runs: list[FleetRun]) -> str:
    """One row per run: robots arrived, makespan, sum of costs (and over the optima), collisions, time."""
    header = (f"{'planner':<10} {'world':<24} {'robots':>6} {'arrived':>12} {'makespan':>8} {'SoC':>8} "
              f"{'SoC/opt':>7} {'r-r':>4} {'r-obst':>6} {'ms/robot-step':>13}")
    lines = [header, "-" * len(header)]
    for run in runs:
        s = run.summary()
        if run.lifelong is not None:
            lines.append(f"{run.planner:<10} {run.world.name[:24]:<24} {s['robots']:>6} lifelong {s['horizon']} steps: "
                         f"{s['goals_reached']} goals, {s['throughput']:.3f} per step; r-r {s['robot_robot_collisions']}, "
                         f"r-obst {s['robot_obstacle_collisions']}, {s['ms_per_robot_step']:.3f} ms/robot-step")
            continue
        ratio = "-" if s.get("soc_over_optimal") is None else f"{s['soc_over_optimal']:.3f}"
        makespan = "-" if s["makespan"] is None else str(s["makespan"])
        arrived = f"{s['arrived']}/{s['robots']}"
        lines.append(f"{run.planner:<10} {run.world.name[:24]:<24} {s['robots']:>6} {arrived:>12} {makespan:>8} "
                     f"{s['sum_of_costs']:>8} {ratio:>7} {s['robot_robot_collisions']:>4} "
                     f"{s['robot_obstacle_collisions']:>6} {s['ms_per_robot_step']:>13.3f}")
    return "\n".join(lines)
