"""``NavigateVectorEnv``: N copies of ``Navigate-v0`` stepped as one batch.

Every copy is a slot of one :class:`~apf_physics.envs.task.NavigationTask`, so a step is
one physics call and one observation call for all copies. Autoreset follows Gymnasium ≥ 1.0
(``NEXT_STEP``, the default): the step after an episode ends returns that copy's reset
observation with reward 0 and ``terminated = truncated = False``, ignoring its action. With
``autoreset_mode="same_step"`` (what Stable-Baselines3 and most RL libraries expect) a copy
whose episode ends is reset in the same step: the step returns its new episode's observation,
the last one in ``info["final_obs"]`` and the step's info in ``info["final_info"]`` (masks
``_final_obs``, ``_final_info``), as Gymnasium's ``SAME_STEP`` mode does. Copy ``i`` seeded with
``seed + i`` gives the same observations, rewards and positions as a ``Navigate-v0`` reset
with ``seed + i`` and driven by the same actions.

``info`` has the keys and ``_key`` masks that Gymnasium's ``SyncVectorEnv`` would give for
N ``Navigate-v0`` copies: at an autoreset step a copy's entries are those of its reset
(``position``, ``world``, ``distance``: the new episode's), and its ``success``,
``collision`` and ``reward_terms`` masks are False. A copy whose episode started at its
target reports it at its next step (terminated, success, reward 0: see ``Navigate-v0``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from apf_physics.envs.options import StartChooser, WorldSpec, observer_config, resolve_worlds, robot_options
from apf_physics.envs.reward import TERMS, reward_weights
from apf_physics.envs.task import NavigationTask, TrapOption
from apf_physics.errors import UserError
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.render.drawing import Snapshot, draw_frame, field_image

_BLOCK = 32  # episode starts drawn ahead per copy


class NavigateVectorEnv(VectorEnv):
    """N navigation environments in one physics (see :class:`~apf_physics.envs.navigate.NavigateEnv`).

    Args:
        world: A world file path or bundled name, a World, or a list of them (one drawn per reset).
        num_envs: Number of copies.
        obs_size: Window side k.
        reward: Reward preset name or weights.
        starts: ``"world"``, ``"random"`` or an ``(S, 2)`` array (see ``NavigateEnv``).
        max_episode_steps: Truncation limit ``tt`` (100 in the thesis).
        resolution: Raster nodes per unit for the observation.
        render_mode: ``"rgb_array"`` renders copy 0.
        memory: Add the visit-memory channel (see ``NavigateEnv``).
        previous: Add the window of the field one step earlier (see ``NavigateEnv``).
        obs_scale: ``"raw"`` or ``"log"`` (see ``NavigateEnv``).
        observer: An observer configuration instead of the four options above.
        trap: Truncate an episode that a trap detector finds stuck (see ``NavigateEnv``; default
            None: no trap rule); ``info["trapped"]`` then says which.
        action, kinematics, observation, lidar, limits: The robot's actions, kind and sensor
            (see ``NavigateEnv``).
        autoreset_mode: ``"next_step"`` (default) or ``"same_step"`` (see the module docstring).

    Also reachable as ``gymnasium.make_vec("apf_physics/Navigate-v0", num_envs=N,
    vectorization_mode="vector_entry_point", world=...)``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, world: WorldSpec | None = None, num_envs: int = 8, obs_size: int = 11,
                 reward: Any = "thesis-fixed", starts: Any = "world", max_episode_steps: int = 100,
                 resolution: int = 4, render_mode: str | None = None, memory: bool = False, previous: bool = False,
                 obs_scale: str = "raw", observer: ObserverConfig | dict | None = None, trap: TrapOption = None,
                 action: str = "discrete", kinematics: str | None = None, observation: str = "window",
                 lidar: Any = None, limits: Any = None, autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP):
        modes = {"next_step": AutoresetMode.NEXT_STEP, "same_step": AutoresetMode.SAME_STEP}
        chosen = [m for name, m in modes.items() if autoreset_mode in (m, name)]
        if not chosen:
            raise UserError(f"autoreset_mode must be one of {', '.join(modes)}, got {autoreset_mode!r}")
        self.autoreset_mode = chosen[0]
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        self.worlds = resolve_worlds(world)
        self.robot = robot_options(self.worlds, action, kinematics, observation, lidar, limits)
        self.num_envs = int(num_envs)
        self.observer = observer_config(obs_size, resolution, memory, obs_scale, observer, previous)
        self.weights = reward_weights(reward)
        self.chooser = StartChooser(starts, self.worlds)
        self.max_episode_steps = int(max_episode_steps)
        self.render_mode = render_mode
        self.single_action_space = self.robot.action_space()
        self.task = NavigationTask(self.worlds, self.num_envs, self.observer, self.weights,
                                    max_steps=self.max_episode_steps, trap=trap, robot=self.robot)
        """The episodes this environment steps (stepper, physics, observer): for tools and tests to look inside."""
        self.single_observation_space = self.task.observation_space()
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self._uniforms = np.zeros((self.num_envs, _BLOCK, 4))
        self._drawn = np.full(self.num_envs, _BLOCK)
        self.needs_reset = np.zeros(self.num_envs, bool)
        """(N,) bool: copies whose episode ended at the last step; they start anew at the next (autoreset NEXT_STEP)."""
        self._trail: list[np.ndarray] = []
        self._all = np.ones(self.num_envs, bool)
        self._names = np.array([w.name for w in self.worlds], dtype=object)

    def _uniforms_for(self, slots: np.ndarray) -> np.ndarray:
        """Four uniforms per slot from each copy's own generator: the same numbers, in the same
        order, as ``Navigate-v0``'s ``reset`` draws (drawn ahead in blocks, one call per block)."""
        empty = slots[self._drawn[slots] == _BLOCK]
        for i in empty.tolist():
            self._uniforms[i] = self._rngs[i].random((_BLOCK, 4))
        self._drawn[empty] = 0
        u = self._uniforms[slots, self._drawn[slots]]
        self._drawn[slots] += 1
        return u

    def _starts(self, slots: np.ndarray, options: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(slots, world_ids, starts)``: where the episodes of ``slots`` begin anew, drawn from
        each copy's own generator."""
        if not len(slots):
            return slots, np.zeros(0, np.intp), np.zeros((0, 2))
        if options:
            chosen = [self.chooser.choose(self._rngs[i], options) for i in slots.tolist()]
            worlds = np.array([w for w, _ in chosen], np.intp)
            starts = np.array([s for _, s in chosen], float).reshape(-1, 2)
            self._drawn[slots] = _BLOCK   # the generators moved on: draw afresh next time
        else:
            worlds, starts = self.chooser.draw(self._uniforms_for(slots))
        return slots, worlds, starts

    def _started(self, slots: np.ndarray, starts: np.ndarray) -> None:
        self.needs_reset[slots] = False
        if len(slots) and slots[0] == 0:   # (slots ascending)
            self._trail = [starts[0].copy()]

    def _start(self, slots: np.ndarray, options: dict | None = None) -> None:
        slots, worlds, starts = self._starts(slots, options)
        self.task.start(slots, worlds, starts)
        self._started(slots, starts)

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if seed is not None:
            seeds = list(seed) if isinstance(seed, (list, tuple)) else [seed + i for i in range(self.num_envs)]
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
            self._rngs = [seeding.np_random(s)[0] for s in seeds]
            self._drawn[:] = _BLOCK
            self.task.seed(seeds)
        self._start(np.arange(self.num_envs), options)
        info = self._info()
        return self.task.observation(), info

    def step(self, actions):
        actions = np.asarray(actions).reshape(self.num_envs, *self.single_action_space.shape)
        # the copies whose episode ended last step begin anew once the others have moved
        restart = self._starts(np.flatnonzero(self.needs_reset))
        result = self.task.step(actions, restart)
        self._started(restart[0], restart[2])
        if self.render_mode is not None and not self.needs_reset[0]:  # the trail is only drawn
            self._trail.append(self.task.positions[0, 0].copy())
        self.needs_reset = result.terminated | result.truncated
        stepped = result.moved | self.needs_reset   # (an episode reached at its start ends without moving)
        info = self._info()
        info["reward_terms"] = dict(zip(TERMS, result.terms))
        info["reward_terms"].update({f"_{k}": stepped for k in TERMS})
        info["_reward_terms"] = stepped
        info["success"], info["_success"] = result.reached & stepped, stepped
        info["collision"], info["_collision"] = result.collided & stepped, stepped
        if self.task.stepper.trap is not None:
            info["trapped"], info["_trapped"] = result.trapped & stepped, stepped
        if self.autoreset_mode == AutoresetMode.SAME_STEP and self.needs_reset.any():
            info = self._reset_ended(info)
        return self.task.observation(), result.reward.astype(np.float32), result.terminated, result.truncated, info

    def _reset_ended(self, info: dict) -> dict:
        """``SAME_STEP``: restart the copies whose episode just ended; their last observation and
        the step's info go to ``final_obs`` and ``final_info``, ``info`` is the step's with the
        new episodes' ``position``, ``world`` and ``distance``."""
        ended = self.needs_reset.copy()
        final = self.task.observation()
        final_obs = np.empty(self.num_envs, dtype=object)
        for i in np.flatnonzero(ended).tolist():
            final_obs[i] = {k: v[i] for k, v in final.items()} if isinstance(final, dict) else final[i]
        self._start(np.flatnonzero(ended))
        after = {**info, **self._info()}
        after["final_obs"], after["_final_obs"] = final_obs, ended
        after["final_info"], after["_final_info"] = info, ended
        return after

    def _info(self) -> dict:
        info = {"position": self.task.positions[:, 0].copy(), "_position": self._all,
                "world": self._names[self.task.world_of], "_world": self._all,
                "distance": self.task.distance(), "_distance": self._all}
        if self.robot.unicycle is not None:
            info["heading"], info["_heading"] = self.task.stepper.headings[:, 0].copy(), self._all
        return info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        world = self.worlds[self.task.world_of[0]]
        snap = Snapshot(self.task.positions[0, :1], ("single",), (np.asarray(self._trail),), (world.name,),
                        int(self.task.stepper.steps[0]),
                        headings=self.task.stepper.headings[0, :1] if self.robot.unicycle is not None else None)
        return draw_frame(field_image(world), snap)
