"""``apf_physics/Formation-v0``: the agent steers the leader; the followers follow by their own fields."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from apf_physics.actions import ACTIONS
from apf_physics.envs.options import StartChooser, WorldSpec, check_starts, resolve_worlds
from apf_physics.envs.reward import TERMS, reward_terms, reward_weights
from apf_physics.observation import WindowSampler
from apf_physics.physics import Physics
from apf_physics.planners.follower import FollowerController, initial_followers
from apf_physics.world import FormationSpec


class FormationEnv(gym.Env):
    """A leader and its followers (SPEC §3); the agent controls the leader.

    ## Description

    As ``Navigate-v0`` for the leader, while ``followers`` robots follow it in a chain (or in
    the world's formation shape) by their own potential fields
    (:class:`~apf_physics.planners.follower.FollowerController`). All robots move in the same
    control step, through the physics.

    ## Action Space

    ``Discrete(9)``: the leader's move, SPEC Table 1 order (see ``Navigate-v0``).

    ## Observation Space

    ``Box(-inf, inf, (1, k, k), float32)``: the potential window around the leader, as in
    ``Navigate-v0``.

    ## Rewards

    As ``Navigate-v0`` for the leader (terms in ``info["reward_terms"]``); W1 applies when any
    robot of the formation touches an obstacle, the map's edge or another robot.

    ## Starting State

    The leader starts as in ``Navigate-v0``; followers are placed behind it (away from the
    target) on free positions within range.

    ## Episode End

    Terminated when the leader reaches a target or any robot collides; truncated after
    ``max_episode_steps`` (registration, 100). ``info["formation_success"]`` is true at the
    end when the leader reached the target and every link is within ``comm_range``.

    ## Arguments

    ``world``, ``obs_size``, ``reward``, ``starts``, ``resolution``, ``render_mode`` as in
    ``Navigate-v0``; ``formation``: a :class:`~apf_physics.world.FormationSpec` or dict
    overriding the world's (default: the world's, else 2 followers in a line, comm_range 3).

    ``info`` carries ``positions`` (every robot, leader first), ``links`` (distance of each
    follower to the robot it follows), ``links_in_range``, and ``link_in_range_share`` so far.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, world: WorldSpec | None = None, obs_size: int = 11, reward: Any = "thesis-fixed",
                 starts: Any = "world", resolution: int = 4, formation: FormationSpec | dict | None = None,
                 render_mode: str | None = None):
        self.worlds = resolve_worlds(world)
        if formation is None:
            spec = self.worlds[0].formation or FormationSpec()
        else:
            spec = formation if isinstance(formation, FormationSpec) else FormationSpec(**formation)
        self.formation = spec
        self.obs_size = int(obs_size)
        self.weights = reward_weights(reward)
        if self.weights.revisit:
            raise ValueError("the formation environment keeps no visit memory: use reward weights with revisit 0")
        self.chooser = StartChooser(check_starts(starts))
        self.render_mode = render_mode
        self.action_space = spaces.Discrete(len(ACTIONS))
        self.observation_space = spaces.Box(-np.inf, np.inf, (1, self.obs_size, self.obs_size), np.float32)
        self.sampler = WindowSampler(self.worlds, self.obs_size, resolution)
        self.m = spec.followers + 1
        self.physics = Physics([self.worlds[0]], robots_per_slot=self.m,
                               pitch=max(max(w.size) for w in self.worlds) + 4.0)
        self.followed = list(range(spec.followers)) if spec.shape == "line" else [0] * spec.followers
        self._episode = 0
        self._w = 0

    @property
    def world(self):
        return self.worlds[self._w]

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._episode = 0
        self._w, start = self.chooser.choose(self.worlds, self.np_random, self._episode)
        self._episode += 1
        world = self.world
        self.physics.set_world(0, world)
        self.positions = np.vstack([start, initial_followers(world, self.formation, start)])
        self.physics.place(np.arange(self.m), self.positions)
        self.controller = FollowerController(world, self.formation)
        self.controller.reset(self.positions)
        self.steps = 0
        self.in_range = np.zeros(self.formation.followers)
        self.trails = [[p.copy()] for p in self.positions]
        obs = self._observe()
        return obs, self._get_info()

    def _observe(self) -> np.ndarray:
        window = self.sampler.sample(self.positions[:1], self._w)
        self._u = float(window[0, self.obs_size // 2, self.obs_size // 2])
        return window.astype(np.float32)

    def _links(self) -> np.ndarray:
        return np.array([np.hypot(*(self.positions[i + 1] - self.positions[j])) for i, j in enumerate(self.followed)])

    def step(self, action):
        move = ACTIONS[int(action)]
        commands = np.vstack([move, self.controller.act(self.positions, move)])
        u_before = self._u
        log = self.physics.step(commands)
        self.positions = self.physics.positions
        for trail, p in zip(self.trails, self.positions):
            trail.append(p.copy())
        obs = self._observe()
        self.steps += 1
        collided = bool(log.any.any())
        d = np.min(np.hypot(*(self.world.targets - self.positions[0]).T))
        reached = bool(d <= self.world.goal_tolerance) and not collided
        terms = reward_terms(self.weights, np.array([collided]), np.array([reached]), np.array([u_before]),
                             np.array([self._u]))
        reward = float(sum(v[0] for v in terms.values()))
        links = self._links()
        self.in_range += links <= self.formation.comm_range
        info = self._get_info()
        info["reward_terms"] = {name: float(terms[name][0]) for name in TERMS}
        info["success"] = reached
        info["collision"] = collided
        info["robot_robot_contact"] = bool(log.robot.any())
        info["formation_success"] = reached and bool(np.all(links <= self.formation.comm_range))
        return obs, reward, reached or collided, False, info

    def _get_info(self) -> dict:
        links = self._links()
        return {"positions": self.positions.copy(), "position": self.positions[0].copy(), "links": links,
                "links_in_range": links <= self.formation.comm_range,
                "link_in_range_share": self.in_range / max(self.steps, 1) if self.steps else np.ones_like(links)}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from apf_physics.render.drawing import Snapshot, draw_frame, field_image, formation_roles

        snap = Snapshot(self.positions, formation_roles(self.m), tuple(np.asarray(t) for t in self.trails),
                        (f"{self.world.name}  step {self.steps}",))
        return draw_frame(field_image(self.world), snap)
