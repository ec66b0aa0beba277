"""Formations: a leader steered by a planner, followers moved by their own fields (SPEC §3).

:func:`rollout_formation` runs one formation per start, all at once (one physics slot per
start, ``1 + followers`` robots per slot), and reports per episode every robot's success,
the smallest robot–robot distance, collisions by kind, and the share of steps each link
stayed within ``comm_range``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from apf_physics.evaluate import Evaluation, evaluate
from apf_physics.physics import Physics
from apf_physics.planners.base import Planner
from apf_physics.planners.follower import FollowerController, initial_followers
from apf_physics.rollout import Episode, TrapDetector, default_max_steps
from apf_physics.world import FormationSpec, World


def formation_spec(world: World) -> FormationSpec:
    """The world's formation, or the thesis's default line of two followers."""
    return world.formation if world.formation is not None else FormationSpec()


@dataclass
class FormationEpisode(Episode):
    """A formation's run from one start (the leader's path is :attr:`path`).

    Attributes:
        positions: ``(steps + 1, 1 + n, 2)`` every robot's positions, the leader first.
        comm_range: The formation's communication range.
        robot_robot_collisions: Control steps in which two robots touched.
        robot_obstacle_collisions: Control steps in which a robot touched an obstacle or the edge.
        link_in_range: Per link (follower i and the robot it follows), the share of steps within range.
    """

    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2)))
    comm_range: float = 0.0
    robot_robot_collisions: int = 0
    robot_obstacle_collisions: int = 0
    link_in_range: list = field(default_factory=list)
    followed: list = field(default_factory=list)

    @property
    def min_robot_distance(self) -> float:
        p = self.positions
        diff = p[:, :, None, :] - p[:, None, :, :]
        d = np.sqrt(np.sum(diff * diff, axis=-1))
        n = p.shape[1]
        return float(d[:, ~np.eye(n, dtype=bool)].min()) if n > 1 else float("inf")

    def final_links_in_range(self) -> list[bool]:
        last = self.positions[-1]
        return [bool(np.hypot(*(last[i + 1] - last[j])) <= self.comm_range) for i, j in enumerate(self.followed)]

    @property
    def success(self) -> bool:
        return self.outcome == "reached" and all(self.final_links_in_range())

    def to_dict(self) -> dict:
        data = super().to_dict()
        data["success"] = self.success
        links = self.final_links_in_range()
        roles = ["leader"] + [f"follower{i + 1}" for i in range(len(self.followed))]
        data["robots"] = [
            {"role": role, "success": (self.outcome == "reached") if k == 0 else (self.outcome == "reached" and links[k - 1]),
             "final_position": [round(float(v), 4) for v in self.positions[-1, k]]}
            for k, role in enumerate(roles)]
        data["min_robot_distance"] = round(self.min_robot_distance, 4)
        data["robot_robot_collisions"] = self.robot_robot_collisions
        data["robot_obstacle_collisions"] = self.robot_obstacle_collisions
        data["link_in_range"] = [round(v, 4) for v in self.link_in_range]
        return data


def rollout_formation(world: World, planner: Planner, starts: Sequence[Sequence[float]] | np.ndarray,
                      max_steps: int | None = None, trap: TrapDetector = TrapDetector()) -> list[FormationEpisode]:
    """Run a formation from every start (the leader's start) in ``world``, all at once.

    The leader follows ``planner``; the followers follow :class:`FollowerController`. An
    episode ends when the leader reaches a target, when any robot touches an obstacle, the
    edge or another robot (collision), when the leader is trapped, or at ``max_steps``.
    """
    spec = formation_spec(world)
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    n, m = len(starts), spec.followers + 1
    if n == 0:
        return []
    max_steps = default_max_steps(world) if max_steps is None else int(max_steps)
    controllers = [FollowerController(world, spec) for _ in range(n)]
    followed = list(range(spec.followers)) if spec.shape == "line" else [0] * spec.followers
    initial = np.stack([np.vstack([s, initial_followers(world, spec, s)]) for s in starts])    # (n, m, 2)
    physics = Physics([world] * n, robots_per_slot=m)
    physics.place(np.arange(n * m), initial.reshape(-1, 2))
    for controller, robots in zip(controllers, initial):
        controller.reset(robots)
    planner.reset(world, starts.copy())

    history = [initial.copy()]
    watch = trap.watch(planner.trap_rule, starts, world.potential(starts), planner.trap_window)
    outcome: list[str | None] = [None] * n
    contacts: list[list[str]] = [[] for _ in range(n)]
    rr = np.zeros(n, int)
    ro = np.zeros(n, int)
    in_range = np.zeros((n, spec.followers))
    steps = np.zeros(n, int)
    active = np.ones(n, bool)
    positions = initial.copy()
    for _ in range(max_steps):
        if not active.any():
            break
        leader_cmd = planner.act(positions[:, 0], active)
        gave_up = planner.stuck()
        if gave_up is not None:
            for i in np.flatnonzero(gave_up & active):
                outcome[i] = "trapped"
                active[i] = False
        commands = np.zeros((n, m, 2))
        for i in np.flatnonzero(active):
            commands[i, 0] = leader_cmd[i]
            commands[i, 1:] = controllers[i].act(positions[i], leader_cmd[i])
        log = physics.step(commands.reshape(-1, 2))
        new = physics.positions.reshape(n, m, 2)
        positions = np.where(active[:, None, None], new, positions)
        history.append(positions.copy())
        leader_u = world.potential(positions[:, 0])
        touched_robot = log.robot.reshape(n, m).any(axis=1)
        touched_obstacle = (log.obstacle | log.wall).reshape(n, m).any(axis=1)
        dist = np.min(np.linalg.norm(positions[:, 0, None, :] - world.targets[None], axis=2), axis=1)
        for i in np.flatnonzero(active):
            steps[i] += 1
            link = np.array([np.hypot(*(positions[i, k + 1] - positions[i, j])) for k, j in enumerate(followed)])
            in_range[i] += link <= spec.comm_range
            rr[i] += int(touched_robot[i])
            ro[i] += int(touched_obstacle[i])
            if touched_robot[i] or touched_obstacle[i]:
                outcome[i] = "collision"
                mine = set(range(i * m, (i + 1) * m))
                contacts[i] = sorted({c.kind for c in log.contacts if c.robot in mine})
            elif dist[i] <= world.goal_tolerance:
                outcome[i] = "reached"
            else:
                if watch.step(i, positions[i, 0], leader_u[i]):
                    outcome[i] = "trapped"
            if outcome[i] is not None:
                active[i] = False
    traj = np.stack(history)                                               # (T, n, m, 2)
    episodes = []
    for i in range(n):
        positions_i = traj[: steps[i] + 1, i]
        episodes.append(FormationEpisode(
            world.name, starts[i], outcome[i] or "timeout", int(steps[i]), positions_i[:, 0].copy(), contacts[i],
            positions=positions_i, comm_range=spec.comm_range, robot_robot_collisions=int(rr[i]),
            robot_obstacle_collisions=int(ro[i]),
            link_in_range=list(in_range[i] / max(steps[i], 1)), followed=followed))
    return episodes


def evaluate_formation(planner: Planner, worlds: Sequence[World], starts: dict[str, np.ndarray] | None = None,
                       max_steps: int | None = None) -> Evaluation:
    """Run the formation from every start of every world."""
    return evaluate(planner, worlds, starts, max_steps, run=rollout_formation, label=f"{planner.name}+formation")
