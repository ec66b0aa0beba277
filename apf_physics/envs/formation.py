"""``apf_physics/Formation-v0``: the agent steers the leader; the followers follow by their own fields."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from apf_physics.envs.options import StartChooser, WorldSpec, observer_config, resolve_worlds, robot_options
from apf_physics.envs.reward import TERMS, reward_weights
from apf_physics.envs.task import NavigationTask, TrapOption
from apf_physics.control.formation import formation_success, link_lengths, links_in_range
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.render.drawing import Snapshot, draw_frame, field_image, formation_roles
from apf_physics.world.core import FormationSpec


class FormationEnv(gym.Env):
    """A leader and its followers (Model §3); the agent controls the leader.

    ## Description

    As ``Navigate-v0`` for the leader, while ``followers`` robots follow it in a chain (or in
    the world's formation shape) by their own potential fields
    (:class:`~apf_physics.control.formation.FollowerController`). All robots move in the same
    control step, through the physics.

    ## Action Space

    ``Discrete(9)``: the leader's move, Model Table 1 order (see ``Navigate-v0``).

    ## Observation Space

    As ``Navigate-v0``'s, around the leader: ``(1, k, k)``, or ``(2, k, k)`` with the leader's
    visit memory (``memory=True``), raw or ``obs_scale="log"``.

    ## Rewards

    As ``Navigate-v0`` for the leader (terms in ``info["reward_terms"]``); W1 applies when any
    robot of the formation touches an obstacle, the map's edge or another robot.

    ## Starting State

    The leader starts as in ``Navigate-v0``; followers are placed behind it (away from the
    target) on free positions within range.

    ## Episode End

    Terminated when the leader reaches a target (also at its start: see ``Navigate-v0``) or
    any robot collides; truncated after ``max_episode_steps`` (registration, 100), and, with a
    ``trap`` detector, when it finds the leader stuck (``info["trapped"]``; see ``Navigate-v0``). ``info["formation_success"]`` is true at the
    end when the leader reached the target and every link is within ``comm_range``.

    ## Arguments

    ``world``, ``obs_size``, ``reward``, ``starts``, ``resolution``, ``memory``,
    ``obs_scale``, ``observer``, ``trap``, ``render_mode`` as in ``Navigate-v0``; ``formation``: a
    :class:`~apf_physics.world.FormationSpec` or dict overriding the world's (default: the
    world's, else 2 followers in a line, comm_range 3).

    ``info`` carries ``positions`` (every robot, leader first), ``links`` (distance of each
    follower to the robot it follows), ``links_in_range``, and ``link_in_range_share`` so far.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, world: WorldSpec | None = None, obs_size: int = 11, reward: Any = "thesis-fixed",
                 starts: Any = "world", resolution: int = 4, formation: FormationSpec | dict | None = None,
                 render_mode: str | None = None, memory: bool = False, previous: bool = False, obs_scale: str = "raw",
                 observer: ObserverConfig | dict | None = None, trap: TrapOption = None,
                 action: str = "discrete", kinematics: str | None = None, observation: str = "window",
                 lidar: Any = None, limits: Any = None):
        self.worlds = resolve_worlds(world)
        self.robot = robot_options(self.worlds, action, kinematics, observation, lidar, limits)
        if formation is None:
            spec = self.worlds[0].formation or FormationSpec()
        else:
            spec = formation if isinstance(formation, FormationSpec) else FormationSpec(**formation)
        self.formation = spec
        self.observer = observer_config(obs_size, resolution, memory, obs_scale, observer, previous)
        self.weights = reward_weights(reward)
        self.chooser = StartChooser(starts, self.worlds)
        self.render_mode = render_mode
        self.action_space = self.robot.action_space()
        self.task = NavigationTask(self.worlds, 1, self.observer, self.weights, formation=spec, trap=trap,
                                    robot=self.robot)
        """The episodes this environment steps (stepper, physics, observer): for tools and tests to look inside."""
        self.observation_space = self.task.observation_space()
        self.m = spec.followers + 1
        self.followed = spec.followed

    @property
    def world(self):
        return self.worlds[self.task.world_of[0]]

    @property
    def positions(self) -> np.ndarray:
        """(m, 2) every robot's position, the leader first."""
        return self.task.positions[0].copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.task.seed([seed])
        w, start = self.chooser.choose(self.np_random, options)
        self.task.start(np.array([0]), np.array([w]), start[None])
        self.steps = 0
        self.in_range = np.zeros(self.formation.followers)
        self.trails = [[p.copy()] for p in self.positions]
        return self.task.observation(0), self._get_info()

    def step(self, action):
        result = self.task.step(np.array([int(action)]) if self.robot.action == "discrete" else action)
        for trail, p in zip(self.trails, self.positions):
            trail.append(p.copy())
        self.steps += 1
        self.in_range += links_in_range(self.positions, self.followed, self.formation.comm_range)
        reached, collided = bool(result.reached[0]), bool(result.collided[0])
        info = self._get_info()
        info["reward_terms"] = dict(zip(TERMS, result.terms[:, 0].tolist()))
        info["success"] = reached
        info["collision"] = collided
        info["robot_robot_contact"] = bool(result.robot_contact[0])
        info["formation_success"] = formation_success(reached, self.positions, self.followed, self.formation.comm_range)
        if self.task.stepper.trap is not None:
            info["trapped"] = bool(result.trapped[0])
        return (self.task.observation(0), float(result.reward[0]), bool(result.terminated[0]), bool(result.truncated[0]),
                info)

    def _get_info(self) -> dict:
        links = link_lengths(self.positions, self.followed)
        share = self.in_range / self.steps if self.steps else np.ones_like(links)
        return {"positions": self.positions, "position": self.positions[0], "world": self.world.name,
                "distance": float(self.task.distance()[0]), "links": links,
                "links_in_range": links_in_range(self.positions, self.followed, self.formation.comm_range),
                "link_in_range_share": share}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        snap = Snapshot(self.positions, formation_roles(self.m), tuple(np.asarray(t) for t in self.trails),
                        (f"{self.world.name}  step {self.steps}",), self.steps)
        return draw_frame(field_image(self.world), snap)

