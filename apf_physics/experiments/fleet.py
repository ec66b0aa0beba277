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

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from apf_physics.control.fleet import (FleetNodes, GoalStream, Lattice, Priorities, fleet_moves, place_fleet,
                                       preferences)
from apf_physics.control.shield import ACTIONS
from apf_physics.errors import UserError
from apf_physics.experiments.rollout import Episode, default_max_steps
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

    @property
    def steps(self) -> int:
        """Control steps the run took."""
        return len(self.positions) - 1

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
        return {"world": self.world.name, "planner": self.planner, "robots": robots, "summary": self.summary()}


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
                        seed)
    for step in range(1, limit + 1):
        if lifelong is None and state.at_goal.all():
            break
        state.step(planner, step)
        if progress is not None:
            progress(step, int(state.at_goal.sum()))
    return state.finish(planner, lifelong, time.perf_counter() - clock)


class _FleetState:
    """A fleet's run as it goes: the stepper, every robot's node, goal, cost and goals reached, the trace."""

    def __init__(self, world: World, placed: FleetNodes, fleet: Fleet, stream: GoalStream | None, seed: int):
        n = len(fleet)
        self.world, self.lattice, self.fleet, self.stream = world, placed.lattice, fleet, stream
        self.stepper = Stepper([world], n, 1, crowds=[0] * n, arrival="continue")
        self.slots = np.arange(n)
        self.stepper.start(self.slots, fleet.starts[:, None, :])
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

    def step(self, planner: Planner, step: int) -> None:
        """One control step: the planner's values, the fleet's rule, the engine; arrivals (and new goals)."""
        lattice, clock = self.lattice, time.perf_counter()
        values = planner.fleet_values(lattice, self.nodes, self.goals)
        now = time.perf_counter()
        self.seconds["values"] += now - clock
        prefs = preferences(values, lattice.ok[self.nodes])
        moves = fleet_moves(lattice, self.nodes, prefs, self.priorities.order(), pinned=~self.stepper.running)
        clock = time.perf_counter()
        self.seconds["rule"] += clock - now
        report = self.stepper.step(ACTIONS[moves][:, None, :])
        self.seconds["physics"] += time.perf_counter() - clock
        self.robot_robot += _robot_pairs(report.contacts)
        self.robot_obstacle += int(report.contacts.obstacle_or_edge.sum()) if report.contacts.touched else 0
        self.nodes = lattice.nearest(report.positions[:, 0])
        arrived = self.nodes == self.goals
        self.cost = np.where(arrived & ~self.at_goal, step, self.cost)   # (re)arrived at this step
        if self.stream is not None and arrived.any():
            for i in np.flatnonzero(arrived).tolist():
                self.reached[i] += 1
                self.goals[i] = self.stream.next(i, int(self.nodes[i]))
            self.stepper.set_targets(np.flatnonzero(arrived), lattice.points(self.goals[arrived]))
            arrived = self.nodes == self.goals
        self.at_goal = arrived
        self.priorities.update(arrived)
        self.trace.append(report.positions[:, 0].copy())
        self.goal_trace.append(self.goals.copy())

    def finish(self, planner: Planner, lifelong: int | None, seconds: float) -> FleetRun:
        """End every robot's episode (reached: on its goal, one-shot) and gather the run."""
        steps, stepper = len(self.trace) - 1, self.stepper
        if lifelong is not None:
            cost, arrived, reached = np.full(len(self.fleet), steps), self.reached > 0, self.reached
        else:
            cost = np.where(self.at_goal, self.cost, steps)
            arrived = self.at_goal & stepper.running
            reached = arrived.astype(np.intp)
        stepper.finish(self.slots[arrived], Outcome.REACHED)
        stepper.finish(self.slots, Outcome.TIMEOUT)
        tables = planner.goal_tables(self.lattice) if type(planner).fleet_values is not Planner.fleet_values else None
        return FleetRun(self.world, planner.name, self.fleet, np.stack(self.trace), np.stack(self.goal_trace), cost,
                        arrived, [Outcome(o).label for o in stepper.outcome], self.robot_robot, self.robot_obstacle,
                        reached, seconds, lifelong, (tables.built, tables.peak) if tables is not None else (0, 0),
                        self.lattice, dict(self.seconds))


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
