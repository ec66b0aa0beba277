"""The experience pool: a ring buffer of transitions with uniform sampling (thesis §4.3), and n-step returns.

A stored transition is ``(O_n, a_n, R, O_{n+m}, discount)``: ``R`` the discounted sum of the
``m`` rewards that followed ``a_n`` and ``discount`` what the TD target multiplies the value of
``O_{n+m}`` by (``γ^m``, 0 when the episode ended there). With one-step transitions (``m = 1``)
this is eq. 32's target; :class:`NStepReturns` makes ``m``-step ones from a vector env's steps.
"""

from __future__ import annotations

from typing import Any, NamedTuple

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
    """(B, C, k, k) float32 observations O_{n+m}, m steps later."""
    discounts: torch.Tensor
    """(B,) float32: the factor on the value of the next observation (γ^m; 0 where it is terminal)."""
    rewards: torch.Tensor
    """(B,) float32 rewards: the discounted sum of the m rewards to the next observation (already scaled)."""


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
        self.discounts = np.zeros(self.capacity, np.float32)
        self.pos = 0
        """Index the next transition is written to."""
        self.size = 0
        """Number of transitions held."""
        self._batch = ReplayBufferSamples(
            observations=torch.zeros((batch_size, *self.obs_shape)),
            actions=torch.zeros((batch_size, 1), dtype=torch.int64),
            next_observations=torch.zeros((batch_size, *self.obs_shape)),
            discounts=torch.zeros(batch_size),
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
        discounts: np.ndarray,
    ) -> None:
        """Append a batch of transitions (one per row).

        Args:
            obs: (M, C, k, k) observations.
            next_obs: (M, C, k, k) next observations.
            actions: (M,) actions.
            rewards: (M,) rewards (summed and discounted up to ``next_obs``).
            discounts: (M,) the factor on the value of ``next_obs`` (0 where it is terminal).
        """
        m = len(actions)
        if m == 0:
            return
        if m > self.capacity:  # only the newest fit
            obs, next_obs, actions, rewards, discounts = (a[-self.capacity :]
                                                          for a in (obs, next_obs, actions, rewards, discounts))
            m = self.capacity
        rows = (self.pos + np.arange(m)) % self.capacity
        self.observations[rows] = obs
        self.next_observations[rows] = next_obs
        self.actions[rows] = actions
        self.rewards[rows] = rewards
        self.discounts[rows] = discounts
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
        np.take(self.discounts, idx, out=batch.discounts.numpy())
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
            "discounts": torch.from_numpy(self.discounts[:n].copy()),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned (the capacity must not have shrunk)."""
        n = int(state["size"])
        if n > self.capacity:
            raise ValueError(f"saved buffer holds {n} transitions, more than the capacity {self.capacity}")
        for name in ("observations", "next_observations", "actions", "rewards", "discounts"):
            getattr(self, name)[:n] = state[name].numpy()
        self.size = n
        self.pos = int(state["pos"]) % self.capacity if n == self.capacity else n


class NStepTransitions(NamedTuple):
    """Transitions made by :class:`NStepReturns`, ready for :meth:`ReplayBuffer.add` (one per row)."""

    observations: np.ndarray
    next_observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    discounts: np.ndarray


class NStepReturns:
    """Turns the one-step transitions of ``num_envs`` environments stepped together into ``n``-step ones.

    A transition is held until ``n`` rewards have followed it, then given out with their
    discounted sum and the observation ``n`` steps later (``discount`` γⁿ). When an episode
    ends first, its held transitions go out at once: to a terminal observation with discount 0,
    or, cut off by the step limit, to the last observation with γ^m for the ``m`` rewards they
    saw. With ``n = 1`` every transition goes out as it comes (eq. 32's target).

    Args:
        n: Steps per return.
        gamma: γ, the discount rate.
        num_envs: Environments stepped together.
        obs_shape: (C, k, k) shape of one observation.
    """

    def __init__(self, n: int, gamma: float, num_envs: int, obs_shape: tuple[int, ...]):
        self.n, self.gamma = int(n), float(gamma)
        self.observations = np.zeros((self.n, num_envs, *obs_shape), np.float32)
        self.actions = np.zeros((self.n, num_envs), np.int64)
        self.returns = np.zeros((self.n, num_envs))
        self.ages = np.zeros((self.n, num_envs), np.int64)
        """Rewards summed into each held transition so far."""
        self.held = np.zeros((self.n, num_envs), bool)
        self.last_observations = np.zeros((num_envs, *obs_shape), np.float32)
        """Each environment's latest next observation (where :meth:`flush` bootstraps from)."""
        self.slot = 0

    def add(self, obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray, next_obs: np.ndarray,
            terminated: np.ndarray, ended: np.ndarray, valid: np.ndarray) -> NStepTransitions:
        """One step of every environment; returns the transitions that are complete.

        Args:
            obs: (E, C, k, k) observations the actions were taken in.
            actions: (E,) actions.
            rewards: (E,) rewards.
            next_obs: (E, C, k, k) observations after the step.
            terminated: (E,) bool: ``next_obs`` is terminal.
            ended: (E,) bool: the episode ended at this step (terminated or cut off).
            valid: (E,) bool: the step is a transition (not an autoreset step that only restarts).
        """
        slot = self.slot
        self.observations[slot, valid] = obs[valid]
        self.actions[slot] = actions
        self.returns[slot] = 0.0
        self.ages[slot] = 0
        self.held[slot] = valid
        self.last_observations[valid] = next_obs[valid]
        held = self.held
        self.returns += np.where(held, self.gamma ** self.ages * rewards[None], 0.0)
        self.ages += held
        out = held & ((self.ages >= self.n) | (ended & valid)[None])
        self.slot = (slot + 1) % self.n
        return self._give(out, next_obs, np.where(terminated, 0.0, 1.0)[None])

    def flush(self) -> NStepTransitions:
        """Every transition still held, bootstrapped from its environment's latest observation (a segment ends)."""
        return self._give(self.held.copy(), self.last_observations, 1.0)

    def _give(self, out: np.ndarray, next_obs: np.ndarray, live: Any) -> NStepTransitions:
        slots, envs = np.nonzero(out)
        discounts = (np.broadcast_to(live, out.shape) * self.gamma ** self.ages)[slots, envs]
        self.held[slots, envs] = False
        return NStepTransitions(self.observations[slots, envs], next_obs[envs], self.actions[slots, envs],
                                self.returns[slots, envs].astype(np.float32), discounts.astype(np.float32))
