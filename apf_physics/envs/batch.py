"""The navigation task for a batch of robots, each in its own world: the engine behind
``Navigate-v0`` (a batch of one) and :class:`~apf_physics.envs.vector.NavigateVectorEnv`.

One step: actions → velocity commands → one physics call for the whole batch → contacts,
target check, potential windows (one batched gather) and reward terms.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import math

import numpy as np

from apf_physics.actions import ACTIONS
from apf_physics.envs.reward import RewardWeights, reward_terms
from apf_physics.observation import VisitMemory, WindowSampler
from apf_physics.physics import Physics
from apf_physics.world import World


@dataclass(frozen=True)
class StepResult:
    observation: np.ndarray    # (N, C, k, k) float32
    reward: np.ndarray         # (N,) float64
    terminated: np.ndarray     # (N,) bool
    terms: dict                # name -> (N,) float64
    reached: np.ndarray        # (N,) bool
    collided: np.ndarray       # (N,) bool


class NavigationBatch:
    """N robots, slot n in world ``worlds[world_of[n]]``.

    Args:
        worlds: The worlds episodes may use.
        num: Batch size.
        obs_size: Window side k.
        weights: Reward weights.
        resolution: Raster nodes per unit for the observation.
        memory: Add channel 1, the robot's visit memory (:class:`~apf_physics.observation.VisitMemory`).

    The visit counts are kept when ``memory`` is set or the weights have a revisit term (W5).
    """

    def __init__(self, worlds: Sequence[World], num: int, obs_size: int, weights: RewardWeights, resolution: int = 4,
                 memory: bool = False):
        self.worlds = list(worlds)
        self.num = int(num)
        self.weights = weights
        self.sampler = WindowSampler(self.worlds, obs_size, resolution)
        self.world_of = np.zeros(self.num, dtype=np.intp)
        self.physics = Physics([self.worlds[0]] * self.num,
                               pitch=max(max(w.size) for w in self.worlds) + 4.0)
        self.positions = np.zeros((self.num, 2))
        self.targets = [w.targets for w in self.worlds]
        self._target_list = [w.targets.tolist() for w in self.worlds]
        self.tolerance = np.array([w.goal_tolerance for w in self.worlds])
        self.show_memory = bool(memory)
        self.memory = VisitMemory(self.num, obs_size) if memory or weights.revisit else None
        self._obs = np.zeros((self.num, 2 if memory else 1, obs_size, obs_size), np.float32)
        self._u = np.zeros(self.num)
        self._center = obs_size // 2

    def set_world(self, slot: int, world_index: int) -> None:
        self.world_of[slot] = world_index
        self.physics.set_world(slot, self.worlds[world_index])

    def place(self, slots: np.ndarray, positions: np.ndarray) -> None:
        """Start episodes: put robots at ``positions`` and refresh their observations."""
        slots = np.asarray(slots, dtype=np.intp)
        self.physics.place(slots, positions)
        self.positions[slots] = positions
        if self.memory is not None:
            self.memory.reset(slots, self.positions[slots], [self.worlds[w] for w in self.world_of[slots]])
        self._observe(slots)
        self.distance = self.distance_to_target()

    def _observe(self, slots: np.ndarray) -> None:
        window = self.sampler.sample(self.positions[slots], self.world_of[slots])
        self._obs[slots, 0] = window
        self._u[slots] = window[:, self._center, self._center]
        if self.show_memory:
            self._obs[slots, 1] = self.memory.window(self.positions[slots], slots)

    def observation(self, slots: np.ndarray | None = None) -> np.ndarray:
        return self._obs.copy() if slots is None else self._obs[slots].copy()

    def distance_to_target(self) -> np.ndarray:
        """(N,) distance from each robot to the nearest target of its world."""
        if self.num == 1:  # the single environment: plain floats beat numpy's per-call overhead
            x, y = self.positions[0]
            return np.array([min(math.hypot(x - tx, y - ty) for tx, ty in self._target_list[self.world_of[0]])])
        out = np.empty(self.num)
        for w in np.unique(self.world_of) if len(self.worlds) > 1 else (0,):
            mine = self.world_of == w if len(self.worlds) > 1 else slice(None)
            diff = self.positions[mine, None, :] - self.targets[w][None]
            out[mine] = np.sqrt(np.min(np.einsum("ntj,ntj->nt", diff, diff), axis=1))
        return out

    def step(self, actions: np.ndarray, moving: np.ndarray | None = None) -> StepResult:
        """Advance every robot whose ``moving`` flag is set (default: all) by its action."""
        actions = np.asarray(actions, dtype=np.intp).reshape(self.num)
        command = ACTIONS[actions]
        if moving is not None:
            command = np.where(moving[:, None], command, 0.0)
        u_before = self._u.copy()
        before = self.positions
        log = self.physics.step(command)
        self.positions = self.physics.positions
        moved = np.hypot(*(self.positions - before).T) if self.weights.length else None
        revisits = None
        if self.memory is not None:
            if self.weights.revisit:
                revisits = self.memory.count(self.positions).astype(float)
            self.memory.visit(self.positions)
        self._observe(np.arange(self.num))
        collided = log.obstacle | log.wall
        self.distance = self.distance_to_target()
        reached = (self.distance <= self.tolerance[self.world_of]) & ~collided
        terms = reward_terms(self.weights, collided, reached, u_before, self._u, revisits, moved)
        reward = sum(terms.values())
        return StepResult(self._obs.copy(), reward, collided | reached, terms, reached, collided)
