"""PettingZoo ``ParallelEnv`` classes: several formations in one world (``FormationsParallelEnv``), and a
fleet of robots each with its own goal (``FleetParallelEnv``).

PettingZoo is an optional extra (``pip install "apf-physics[pettingzoo]"``); this module
needs it only to subclass ``ParallelEnv`` when it is installed.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from apf_physics.control.fleet import STAY
from apf_physics.control.shield import ACTIONS
from apf_physics.envs.options import FileUnits, observer_config, resolve_worlds
from apf_physics.envs.reward import TERMS, reward_weights
from apf_physics.envs.task import FleetTask, FormationsTask, TrapOption
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.render.drawing import Snapshot, draw_frame, field_image, formation_roles
from apf_physics.render.fleet import fleet_colours, fleet_frame, fleet_image

try:
    from pettingzoo import ParallelEnv
except ImportError:  # the extra is not installed: the class can still be built, not registered
    ParallelEnv = object


class _OneWorldParallelEnv(ParallelEnv):
    """What both environments share: one observation space and the nine moves for every agent,
    a seeded generator, nothing to close."""

    _observation_space: spaces.Space
    _action_space: spaces.Space   # each env its own (a space is seeded)

    def observation_space(self, agent: str) -> spaces.Space:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Space:
        return self._action_space

    def _seed(self, seed: int | None) -> None:
        """A new generator from ``seed`` (None: keep the one it has, as Gymnasium's ``reset`` does)."""
        if seed is not None:
            self.np_random, _ = seeding.np_random(seed)

    def close(self) -> None:
        pass


class FormationsParallelEnv(_OneWorldParallelEnv):
    """Every formation of a world with ``formations:`` moving at once, each to its own target.

    ## Agents

    ``agents="leaders"`` (default): one agent per formation, ``leader_<f>``; its followers
    follow by their own rule and every move gets the right of way
    (:class:`~apf_physics.control.formation.Formations`), so robots never touch one another.
    ``agents="all"``: every robot is an agent, ``robot_<f>_<r>`` (r = 0 the leader), moved
    exactly as told (collisions are then the agents' to avoid).

    ## Action Space

    ``Discrete(9)`` per agent, Model Table 1 order (see ``Navigate-v0``).

    ## Observation Space

    ``Navigate-v0``'s, around the agent, in its formation's field (its own target): the
    robots of the other formations (with ``"all"``: every other robot) are discs of the
    robot radius that repel and read as walls where they stand.

    ## Rewards

    ``Navigate-v0``'s terms per agent (``infos[agent]["reward_terms"]``): W1 when its formation
    (with ``"all"``: the robot itself) touches anything, W2 when its formation's leader
    reaches the target, W3 every step, W4 on the change of U at the agent.

    ## Episode End

    An agent terminates when its formation reaches its target (also at its start: see
    ``Navigate-v0``) or collides; it is truncated after ``max_episode_steps``, and, with a
    ``trap`` detector, when it finds the formation's leader stuck (``infos[agent]["trapped"]``;
    see ``Navigate-v0``). Its formation's robots then stay where they are.

    ## Arguments

    ``world`` (a world file with ``formations:``, a bundled name, or a World), ``agents``,
    ``obs_size``, ``reward``, ``resolution``, ``memory``, ``obs_scale``, ``observer``,
    ``max_episode_steps`` (100), ``trap`` (default None), ``render_mode``.

    ``infos[agent]`` holds its ``position``, ``formation``, ``world``, ``distance`` (to its
    formation's target) and ``units``: positions and lengths in the world file's units and
    coordinates, as ``Navigate-v0``'s.
    """

    metadata = {"name": "apf_physics_formations_v0", "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, world: Any = None, agents: str = "leaders", obs_size: int = 11, reward: Any = "thesis-fixed",
                 resolution: int = 4, memory: bool = False, previous: bool = False, obs_scale: str = "raw",
                 observer: ObserverConfig | dict | None = None, max_episode_steps: int = 100,
                 render_mode: str | None = None, trap: TrapOption = None):
        (self.world,) = resolve_worlds(world)
        self.observer = observer_config(obs_size, resolution, memory, obs_scale, observer, previous)
        self.task = FormationsTask(self.world, self.observer, reward_weights(reward), agents, max_episode_steps, trap)
        """The episodes this environment steps (stepper, physics, observer): for tools and tests to look inside."""
        low, high = self.task.observer.value_bounds()  # finite: from the worlds' U
        self._observation_space = spaces.Box(low, high, self.observer.shape, np.float32)
        self.possible_agents = list(self.task.names)
        self.agents: list[str] = []
        self.render_mode = render_mode
        self._action_space = spaces.Discrete(len(ACTIONS))
        self._index = {name: a for a, name in enumerate(self.possible_agents)}
        self._units = FileUnits([self.world])   # (every formation's world is this world with its own target)
        self.np_random, _ = seeding.np_random(None)

    def reset(self, seed: int | None = None, options: dict | None = None):
        self._seed(seed)
        self.task.start()
        self.agents = list(self.possible_agents)
        obs = self.task._obs
        return {a: obs[self._index[a]] for a in self.agents}, {a: self._info(a) for a in self.agents}

    def step(self, actions: dict):
        chosen = np.full(len(self.possible_agents), 8, np.intp)   # agents no longer playing: stay
        for agent, action in actions.items():
            chosen[self._index[agent]] = int(action)
        result = self.task.step(chosen)
        live = list(self.agents)
        observations = {a: result.observation[self._index[a]] for a in live}
        rewards = {a: float(result.reward[self._index[a]]) for a in live}
        terminations = {a: bool(result.terminated[self._index[a]]) for a in live}
        truncations = {a: bool(result.truncated[self._index[a]]) for a in live}
        infos = {}
        for a in live:
            i = self._index[a]
            infos[a] = {**self._info(a), "reward_terms": dict(zip(TERMS, result.terms[:, i].tolist())),
                        "success": bool(result.reached[i]), "collision": bool(result.collided[i]),
                        "robot_robot_contact": bool(result.robot_contact[i])}
            if self.task.stepper.trap is not None:
                infos[a]["trapped"] = bool(result.trapped[i])
        self.agents = [a for a in live if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, infos

    def _info(self, agent: str) -> dict:
        a = self._index[agent]
        f, r = self.task.members[a]
        position = self.task.stepper.positions[f, r]
        world = self.task.formations.worlds[f]
        units = self._units
        return {"position": units.points(position, 0), "formation": f, "world": self.world.name,
                "distance": float(units.lengths(world.distance_to_target(position[None])[0], 0)),
                "units": units.names[0]}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        formations = self.task.formations
        positions = np.concatenate([self.task.stepper.positions[f, :size] for f, size in enumerate(formations.sizes)])
        roles = tuple(role for size in formations.sizes for role in formation_roles(size))
        families = tuple(f for f, size in enumerate(formations.sizes) for _ in range(size))
        snapshot = Snapshot(positions, roles, (), (f"{self.world.name}  step {self.task.step_count}",),
                            self.task.step_count, families)
        return draw_frame(field_image(self.world), snapshot)


class FleetParallelEnv(_OneWorldParallelEnv):
    """A fleet on one map: every robot an agent with a goal of its own, as POGEMA's environments
    are, through the physics.

    ## Agents

    ``robot_<i>`` for each of the world's ``robots:`` (or ``num_agents`` robots drawn at each reset
    with ``starts="random"``, or for a world without robots).

    ## Action Space

    ``Discrete(9)`` per agent, Model Table 1 order (up, down, left, right, the four diagonals, stay),
    one step from node to node of the fleet's lattice (:class:`~apf_physics.control.fleet.Lattice`).
    A move into an obstacle, or that would bring two robots within ``2·radius + SAFETY`` of each
    other (the shield among robots, :func:`~apf_physics.control.fleet.fleet_moves`, in an order drawn
    each step), is refused and the agent stays: POGEMA's soft collisions, with bodies that never touch
    (``infos[agent]["refused"]``).

    ## Observation Space

    ``Box(0, 1, (3, k, k), float32)``, ``k = 2·obs_radius + 1`` (POGEMA's): obstacles (and the map's
    outside), the other robots, and the agent's goal (on the window's border when beyond it), in a
    window of nodes around the agent, north up.

    ## Rewards

    POGEMA's: 1 when the agent reaches its goal, else 0.

    ## Episode End

    ``on_target="finish"`` (default): an agent terminates on reaching its goal; its robot stays
    there, a body in the others' way. ``"restart"`` (lifelong): it is given its next goal at once
    and goes on. Every agent is truncated after ``max_episode_steps``.

    ## Arguments

    ``world`` (a world file with ``robots:``, a world, or a map's world with ``num_agents``),
    ``num_agents``, ``starts`` (``"world"`` or ``"random"``), ``obs_radius`` (5), ``on_target``,
    ``max_episode_steps`` (256), ``render_mode``.

    ``infos[agent]`` holds its ``position`` and ``goal`` (the world file's units), ``success``,
    ``refused`` and ``collision`` (the physics' contact log: never, by the rule above).
    """

    metadata = {"name": "apf_physics_fleet_v0", "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, world: Any = None, num_agents: int | None = None, starts: str = "world", obs_radius: int = 5,
                 on_target: str = "finish", max_episode_steps: int = 256, render_mode: str | None = None):
        (self.world,) = resolve_worlds(world)
        if starts not in ("world", "random"):
            raise ValueError(f"starts must be 'world' or 'random', got {starts!r}")
        self.random_starts = starts == "random" or self.world.robots is None
        self.task = FleetTask(self.world, num_agents, obs_radius, on_target, max_episode_steps)
        self.possible_agents = [f"robot_{i}" for i in range(self.task.count)]
        self.agents: list[str] = []
        self.render_mode = render_mode
        self._observation_space = spaces.Box(0.0, 1.0, self.task.shape, np.float32)
        self._action_space = spaces.Discrete(len(ACTIONS))
        self._units = FileUnits([self.world])
        self.np_random, _ = seeding.np_random(None)

    def reset(self, seed: int | None = None, options: dict | None = None):
        self._seed(seed)
        self.task.start(self.np_random, self.random_starts)
        self.agents = list(self.possible_agents)
        obs = self.task.observe()
        return ({a: obs[i] for i, a in enumerate(self.possible_agents)},
                {a: self._info(i) for i, a in enumerate(self.possible_agents)})

    def step(self, actions: dict):
        chosen = np.full(self.task.count, STAY, np.intp)   # agents no longer playing: stay
        for agent, action in actions.items():
            chosen[int(agent.rsplit("_", 1)[1])] = int(action)
        reward, terminated, truncated, refused, collided = self.task.step(chosen)
        obs = self.task.observe()
        live = list(self.agents)
        index = {a: int(a.rsplit("_", 1)[1]) for a in live}
        infos = {a: {**self._info(i), "success": bool(reward[i] > 0), "refused": bool(refused[i]),
                     "collision": bool(collided[i])} for a, i in index.items()}
        out = ({a: obs[i] for a, i in index.items()}, {a: float(reward[i]) for a, i in index.items()},
               {a: bool(terminated[i]) for a, i in index.items()}, {a: bool(truncated[i]) for a, i in index.items()},
               infos)
        self.agents = [a for a in live if not (terminated[index[a]] or truncated[index[a]])]
        return out

    def _info(self, i: int) -> dict:
        task = self.task
        return {"position": self._units.points(task.lattice.points(task.nodes[i:i + 1])[0], 0),
                "goal": self._units.points(task.lattice.points(task.goals[i:i + 1])[0], 0), "units": self._units.names[0]}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        task = self.task
        positions = task.lattice.points(task.nodes)[None]
        goals = task.lattice.points(task.goals)[None]
        image = fleet_image(self.world, 1024)
        return fleet_frame(image, positions, goals, 0, fleet_colours(task.count),
                           (f"{self.world.name}  step {task.steps}",))
