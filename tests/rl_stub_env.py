"""A tiny numpy grid world with the vector-env interface the trainer expects.

Stands in for :class:`apf_physics.envs.NavigateVectorEnv` in the learner's tests, so they
stay fast and test the learner alone: integer positions, unit moves, the potential of
SPEC §1 without black hole (attraction plus walls), the thesis's reward terms, NEXT_STEP
autoreset and ``info["success"]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

from apf_physics.actions import ACTIONS
from apf_physics.field import FieldParams


@dataclass(frozen=True)
class StubWorld:
    """A grid world: free cells are integer points of [0, W) × [0, H) not in ``blocked``."""

    name: str = "stub"
    size: tuple[int, int] = (7, 7)
    target: tuple[int, int] = (5, 5)
    blocked: tuple[tuple[int, int], ...] = ((3, 2), (3, 3), (3, 4))
    starts: np.ndarray = field(default_factory=lambda: np.array([[0, 0], [1, 3], [0, 6], [5, 0], [2, 1], [6, 3]], float))
    field: FieldParams = field(default_factory=lambda: FieldParams(katt=2, krep=20, kstr=8, p0=0.5, ps=8, u_max=100))
    source: str | None = None

    def potential_grid(self) -> np.ndarray:
        """U at every cell, [x, y] indexed; blocked cells read the wall value."""
        xs, ys = np.meshgrid(np.arange(self.size[0]), np.arange(self.size[1]), indexing="ij")
        u = 0.5 * self.field.katt * ((xs - self.target[0]) ** 2 + (ys - self.target[1]) ** 2)
        for x, y in self.blocked:
            u[x, y] = np.inf
        return u


class StubVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` robots in one :class:`StubWorld`, stepped together.

    Args:
        world: The grid world.
        num_envs: Number of robots.
        seed: Seed of the start draws.
        starts: ``"world"`` (the world's starts in turn), ``"random"`` (any free cell) or an
            (num_envs, 2) array (robot i always starts at row i).
        obs_size: Observation window side k.
        max_episode_steps: tt.
    """

    metadata = {"autoreset_mode": gym.vector.AutoresetMode.NEXT_STEP}

    def __init__(self, world: StubWorld, num_envs: int = 1, seed: int | None = None, starts="world",
                 obs_size: int = 5, max_episode_steps: int = 30):
        self.world = world
        self.num_envs = num_envs
        self.k = obs_size
        self.max_episode_steps = max_episode_steps
        self.starts = starts
        u = world.potential_grid()
        self.u_wall = float(np.nanmax(u[np.isfinite(u)])) + world.field.u_max
        pad = obs_size // 2
        self.padded = np.full((u.shape[0] + 2 * pad, u.shape[1] + 2 * pad), self.u_wall, np.float32)
        self.padded[pad:-pad, pad:-pad] = np.where(np.isfinite(u), u, self.u_wall)
        self.u = self.padded[pad:-pad, pad:-pad]
        self.free = np.argwhere(np.isfinite(u))
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (1, obs_size, obs_size), np.float32)
        self.single_action_space = gym.spaces.Discrete(len(ACTIONS))
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self.moves = ACTIONS.astype(int)
        self.pos = np.zeros((num_envs, 2), int)
        self.steps = np.zeros(num_envs, int)
        self.needs_reset = np.zeros(num_envs, bool)
        self.next_world_start = 0
        self.rng = np.random.default_rng(seed)

    def _draw_starts(self, which: np.ndarray) -> None:
        idx = np.flatnonzero(which)
        if isinstance(self.starts, str) and self.starts == "random":
            self.pos[idx] = self.free[self.rng.integers(0, len(self.free), len(idx))]
        elif isinstance(self.starts, str):
            for i in idx:
                self.pos[i] = self.world.starts[self.next_world_start % len(self.world.starts)]
                self.next_world_start += 1
        else:
            self.pos[idx] = np.asarray(self.starts, int)[idx]
        self.steps[idx] = 0

    def _obs(self) -> np.ndarray:
        k = self.k
        rows = self.pos[:, 1, None] + (k // 2 - np.arange(k))[None, :] + k // 2   # top row = highest y
        cols = self.pos[:, 0, None] + (np.arange(k) - k // 2)[None, :] + k // 2
        return self.padded[cols[:, None, :], rows[:, :, None]][:, None].astype(np.float32)

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.next_world_start = 0
        self._draw_starts(np.ones(self.num_envs, bool))
        self.needs_reset[:] = False
        return self._obs(), {}

    def step(self, actions):
        actions = np.asarray(actions)
        resetting = self.needs_reset.copy()
        u_before = self.u[self.pos[:, 0], self.pos[:, 1]]
        new = self.pos + self.moves[actions]
        inside = (new >= 0).all(1) & (new[:, 0] < self.world.size[0]) & (new[:, 1] < self.world.size[1])
        clipped = np.clip(new, 0, np.array(self.world.size) - 1)
        collision = ~inside | (self.u[clipped[:, 0], clipped[:, 1]] >= self.u_wall)
        self.pos = np.where(collision[:, None], self.pos, clipped)
        self.steps += 1
        success = ~collision & (self.pos == np.array(self.world.target)).all(1)
        u_after = self.u[self.pos[:, 0], self.pos[:, 1]]
        reward = -1.0 - 4.0 * (u_after - u_before) - 1000.0 * collision + 1000.0 * success
        terminated = collision | success
        truncated = ~terminated & (self.steps >= self.max_episode_steps)
        # NEXT_STEP autoreset: envs done last step only reset now
        if resetting.any():
            self._draw_starts(resetting)
            reward[resetting] = 0.0
            terminated[resetting] = truncated[resetting] = success[resetting] = collision[resetting] = False
        self.needs_reset = terminated | truncated
        info = {"success": success, "collision": collision, "position": self.pos.astype(float)}
        return self._obs(), reward.astype(np.float32), terminated, truncated, info


def stub_env_factory(world, *, num_envs, seed, starts, config):
    """An :data:`apf_physics.rl.dqn.EnvFactory` building :class:`StubVectorEnv`."""
    return StubVectorEnv(world, num_envs=num_envs, seed=seed, starts=starts, obs_size=config.obs_size,
                         max_episode_steps=config.max_episode_steps)
