"""The experience pool: a ring buffer of transitions with uniform sampling (thesis §4.3)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch


class ReplayBufferSamples(NamedTuple):
    """One minibatch, as torch tensors (the layout of SB3's ``ReplayBufferSamples``).

    The tensors are views of buffers owned by the :class:`ReplayBuffer` and are
    overwritten by its next :meth:`~ReplayBuffer.sample` call.
    """

    observations: torch.Tensor
    """(B, C, k, k) float32 observations O_n."""
    actions: torch.Tensor
    """(B, 1) int64 actions a_n (for ``gather``)."""
    next_observations: torch.Tensor
    """(B, C, k, k) float32 observations O_{n+1}."""
    dones: torch.Tensor
    """(B,) float32, 1 where O_{n+1} is terminal (no bootstrapping beyond it)."""
    rewards: torch.Tensor
    """(B,) float32 step rewards R_n (already scaled)."""


class ReplayBuffer:
    """Fixed-capacity FIFO of transitions stored in numpy arrays.

    Sampling copies the chosen rows into preallocated arrays that share memory with the
    returned tensors, so an update allocates nothing here.

    Args:
        capacity: Maximum number of transitions kept; the oldest is overwritten first.
        obs_shape: (C, k, k) shape of one observation.
        batch_size: Number of transitions returned by :meth:`sample`.
    """

    def __init__(self, capacity: int, obs_shape: tuple[int, ...], batch_size: int):
        self.capacity = int(capacity)
        self.obs_shape = tuple(int(v) for v in obs_shape)
        self.observations = np.zeros((self.capacity, *self.obs_shape), np.float32)
        self.next_observations = np.zeros_like(self.observations)
        self.actions = np.zeros(self.capacity, np.int64)
        self.rewards = np.zeros(self.capacity, np.float32)
        self.dones = np.zeros(self.capacity, np.float32)
        self.pos = 0
        """Index the next transition is written to."""
        self.size = 0
        """Number of transitions held."""
        self._batch = ReplayBufferSamples(
            observations=torch.zeros((batch_size, *self.obs_shape)),
            actions=torch.zeros((batch_size, 1), dtype=torch.int64),
            next_observations=torch.zeros((batch_size, *self.obs_shape)),
            dones=torch.zeros(batch_size),
            rewards=torch.zeros(batch_size),
        )

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
    ) -> None:
        """Append a batch of transitions (one per row).

        Args:
            obs: (M, C, k, k) observations.
            next_obs: (M, C, k, k) next observations.
            actions: (M,) actions.
            rewards: (M,) rewards.
            dones: (M,) bool or float, True where ``next_obs`` is terminal.
        """
        m = len(actions)
        if m == 0:
            return
        if m > self.capacity:  # only the newest fit
            obs, next_obs, actions, rewards, dones = (a[-self.capacity :] for a in (obs, next_obs, actions, rewards, dones))
            m = self.capacity
        rows = (self.pos + np.arange(m)) % self.capacity
        self.observations[rows] = obs
        self.next_observations[rows] = next_obs
        self.actions[rows] = actions
        self.rewards[rows] = rewards
        self.dones[rows] = dones
        self.pos = int((self.pos + m) % self.capacity)
        self.size = min(self.size + m, self.capacity)

    def sample(self, rng: np.random.Generator) -> ReplayBufferSamples:
        """Draw a minibatch uniformly, with replacement.

        Args:
            rng: Random generator for the indices.

        Returns:
            The batch; its tensors are reused by the next call.
        """
        batch = self._batch
        idx = rng.integers(0, self.size, size=len(batch.rewards))
        np.take(self.observations, idx, axis=0, out=batch.observations.numpy())
        np.take(self.next_observations, idx, axis=0, out=batch.next_observations.numpy())
        np.take(self.actions, idx, out=batch.actions.numpy()[:, 0])
        np.take(self.rewards, idx, out=batch.rewards.numpy())
        np.take(self.dones, idx, out=batch.dones.numpy())
        return batch

    def state_dict(self) -> dict:
        """The stored transitions and ring position, for a checkpoint (only the filled rows)."""
        n = self.size
        return {
            "pos": self.pos,
            "size": n,
            "observations": torch.from_numpy(self.observations[:n].copy()),
            "next_observations": torch.from_numpy(self.next_observations[:n].copy()),
            "actions": torch.from_numpy(self.actions[:n].copy()),
            "rewards": torch.from_numpy(self.rewards[:n].copy()),
            "dones": torch.from_numpy(self.dones[:n].copy()),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned (the capacity must not have shrunk)."""
        n = int(state["size"])
        if n > self.capacity:
            raise ValueError(f"saved buffer holds {n} transitions, more than the capacity {self.capacity}")
        for name in ("observations", "next_observations", "actions", "rewards", "dones"):
            getattr(self, name)[:n] = state[name].numpy()
        self.size = n
        self.pos = int(state["pos"]) % self.capacity if n == self.capacity else n
