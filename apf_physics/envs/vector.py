"""``NavigateVectorEnv``: N copies of ``Navigate-v0`` stepped as one batch.

Every copy's world is tiled in one pymunk space, so a step is one physics call for all
copies; observations are sampled with one batched gather. Autoreset follows Gymnasium ≥ 1.0
(``NEXT_STEP``): the step after an episode ends returns that copy's reset observation with
reward 0 and ``terminated = truncated = False``, ignoring its action. Copy ``i`` seeded with
``seed + i`` gives the same observations, rewards and positions as a ``Navigate-v0`` reset
with ``seed + i`` and driven by the same actions.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from apf_physics.actions import ACTIONS
from apf_physics.envs.batch import NavigationBatch
from apf_physics.envs.options import StartChooser, WorldSpec, check_starts, resolve_worlds
from apf_physics.envs.reward import reward_weights


class NavigateVectorEnv(VectorEnv):
    """N navigation environments in one physics space (see :class:`~apf_physics.envs.navigate.NavigateEnv`).

    Args:
        world: A world file path, a World, or a list of them (one drawn per reset).
        num_envs: Number of copies.
        obs_size: Window side k.
        reward: Reward preset name or weights.
        starts: ``"world"``, ``"random"`` or an ``(S, 2)`` array (see ``NavigateEnv``).
        max_episode_steps: Truncation limit ``tt`` (100 in the thesis).
        resolution: Raster nodes per unit for the observation.
        render_mode: ``"rgb_array"`` renders copy 0.
        memory: Add a second observation channel, the copy's visit memory (see
            ``NavigateEnv``); observations are then ``(N, 2, k, k)``.

    With a list of starts (``"world"`` or an array of S rows), copy ``i`` takes row
    ``(i + e·N) mod S`` in its ``e``-th episode, so N copies share out the list.

    Also reachable as ``gymnasium.make_vec("apf_physics/Navigate-v0", num_envs=N,
    vectorization_mode="vector_entry_point", world=...)``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, world: WorldSpec | None = None, num_envs: int = 8, obs_size: int = 11,
                 reward: Any = "thesis-fixed", starts: Any = "world", max_episode_steps: int = 100,
                 resolution: int = 4, render_mode: str | None = None, memory: bool = False):
        self.worlds = resolve_worlds(world)
        self.num_envs = int(num_envs)
        self.obs_size = int(obs_size)
        self.weights = reward_weights(reward)
        self.chooser = StartChooser(check_starts(starts))
        self.max_episode_steps = int(max_episode_steps)
        self.render_mode = render_mode
        self.single_action_space = spaces.Discrete(len(ACTIONS))
        self.memory = bool(memory)
        channels = 2 if self.memory else 1
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (channels, self.obs_size, self.obs_size), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._batch = NavigationBatch(self.worlds, self.num_envs, self.obs_size, self.weights, resolution,
                                        memory=self.memory)
        self._rngs = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self._episode = np.zeros(self.num_envs, int)
        self._steps = np.zeros(self.num_envs, int)
        self._needs_reset = np.zeros(self.num_envs, bool)
        self._trail: list[np.ndarray] = []

    def _start(self, slots: np.ndarray) -> None:
        starts = np.empty((len(slots), 2))
        for j, i in enumerate(slots):
            # Copy i's e-th episode takes start row i + e·N: the copies share out the list.
            w, starts[j] = self.chooser.choose(self.worlds, self._rngs[i], int(i + self._episode[i] * self.num_envs))
            self._episode[i] += 1
            self._batch.set_world(int(i), w)
        self._batch.place(slots, starts)
        self._steps[slots] = 0
        self._needs_reset[slots] = False
        if 0 in slots:
            self._trail = [self._batch.positions[0].copy()]

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if seed is not None:
            seeds = list(seed) if isinstance(seed, (list, tuple)) else [seed + i for i in range(self.num_envs)]
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
            self._rngs = [seeding.np_random(s)[0] for s in seeds]
            self._episode[:] = 0
        self._start(np.arange(self.num_envs))
        return self._batch.observation(), self._info()

    def step(self, actions):
        actions = np.asarray(actions).reshape(self.num_envs)
        restarting = np.flatnonzero(self._needs_reset)
        moving = ~self._needs_reset
        result = self._batch.step(actions, moving)
        self._steps[moving] += 1
        reward = np.where(moving, result.reward, 0.0).astype(np.float32)
        terminated = result.terminated & moving
        truncated = moving & ~terminated & (self._steps >= self.max_episode_steps)
        info = self._info()
        info["reward_terms"] = {k: np.where(moving, v, 0.0) for k, v in result.terms.items()}
        info["success"] = result.reached & moving
        info["collision"] = result.collided & moving
        if len(restarting):
            self._start(restarting)
        if moving[0] and self.render_mode is not None:  # the trail is only drawn
            self._trail.append(self._batch.positions[0].copy())
        self._needs_reset = terminated | truncated
        return self._batch.observation(), reward, terminated, truncated, info

    def _info(self) -> dict:
        return {"position": self._batch.positions.copy(), "episode_step": self._steps.copy()}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from apf_physics.render.drawing import Snapshot, draw_frame, field_image

        world = self.worlds[self._batch.world_of[0]]
        snap = Snapshot(self._batch.positions[:1], ("single",), (np.asarray(self._trail),), (world.name,))
        return draw_frame(field_image(world), snap)
