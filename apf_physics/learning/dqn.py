"""Deep Q-learning (Model §2, thesis §4) as a :class:`~apf_physics.learning.learner.Learner`.

Each step acts ε-greedily (Model eq. 34) in every training environment, stores the transitions
in the experience pool and makes the configured updates, whose TD target is eq. 32. A segment
starts with fresh environments seeded from ``(seed, transitions so far)``: with the pool saved
in the checkpoint (``save_buffer``) a resumed run continues exactly as the uninterrupted one.
"""

from __future__ import annotations

import collections
import copy
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from apf_physics.envs import NavigateVectorEnv
from apf_physics.models.network import QNetwork
from apf_physics.models.policy import DQNPolicy
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.learning.buffer import NStepReturns, ReplayBuffer
from apf_physics.learning.config import N_ACTIONS, TrainConfig, epsilon_schedule
from apf_physics.learning.learner import Counters, Learner
from apf_physics.learning.phases import Phase
from apf_physics.world.core import World


def q_network(config: TrainConfig) -> QNetwork:
    """A freshly initialised Q-network for this configuration."""
    n = config.network
    return QNetwork(obs_shape=config.observer.shape, filters=n.filters, hidden=n.hidden, n_actions=N_ACTIONS,
                    negative_slope=n.negative_slope, obs_transform=n.obs_transform)


def epsilon_greedy(q_network: torch.nn.Module, obs: np.ndarray, epsilon: float,
                   rng: np.random.Generator) -> np.ndarray:
    """ε-greedy actions for a batch: a random action with probability ε, else the greedy one."""
    with torch.inference_mode():
        actions = q_network(torch.from_numpy(obs)).argmax(1).numpy()
    explore = rng.random(len(actions)) < epsilon
    if explore.any():
        actions = np.where(explore, rng.integers(0, N_ACTIONS, len(actions)), actions)
    return actions


class QLearning:
    """The Q-network, its target network, optimiser and experience pool, and the TD update (Model eq. 32)."""

    def __init__(self, config: TrainConfig):
        self.config = config.dqn
        self.q_network = q_network(config)
        self.target_network = (copy.deepcopy(self.q_network) if self.config.target_update != "none"
                               else self.q_network)
        if self.target_network is not self.q_network:
            self.target_network.requires_grad_(False)
        self.max_grad_norm = config.network.max_grad_norm
        self.optimizer = torch.optim.Adam(self.q_network.parameters(), lr=config.network.learning_rate, fused=True)
        self.buffer = ReplayBuffer(self.config.buffer_size, config.observer.shape, self.config.batch_size)
        self.updates = 0
        self._online = list(self.q_network.parameters())
        self._target = list(self.target_network.parameters())
        self._loss_sum, self._loss_count = torch.zeros(()), 0

    @property
    def ready(self) -> bool:
        """Whether the pool holds enough transitions to learn from."""
        return len(self.buffer) >= max(self.config.learning_starts, self.config.batch_size)

    def update(self, rng: np.random.Generator) -> None:
        """One gradient step on a minibatch drawn with ``rng``, then the target network's update."""
        c = self.config
        batch = self.buffer.sample(rng)
        with torch.no_grad():
            if c.double_dqn:  # choose with the online network, value with the target network
                next_actions = self.q_network(batch.next_observations).argmax(1, keepdim=True)
                next_q = self.target_network(batch.next_observations).gather(1, next_actions).squeeze(1)
            else:
                next_q = self.target_network(batch.next_observations).amax(1)
            # TD target (eq. 32, over m steps): R + γ^m·max Q(O_{n+m}), nothing beyond a terminal step
            td_target = batch.rewards + batch.discounts * next_q
        q_taken = self.q_network(batch.observations).gather(1, batch.actions).squeeze(1)
        if c.loss == "huber":  # Huber loss: less sensitive to outliers than the thesis's MSE
            loss = F.smooth_l1_loss(q_taken, td_target)
        else:
            loss = F.mse_loss(q_taken, td_target)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self._online, self.max_grad_norm, foreach=True)
        self.optimizer.step()
        self.updates += 1
        if c.target_update == "soft":
            with torch.no_grad():
                torch._foreach_lerp_(self._target, self._online, c.tau)
        elif c.target_update == "hard" and self.updates % c.target_update_every == 0:
            self.target_network.load_state_dict(self.q_network.state_dict())
        self._loss_sum += loss.detach()  # summed as a tensor: no per-update synchronisation
        self._loss_count += 1

    def mean_loss(self) -> Optional[float]:
        """Mean loss of the updates since the last call (None: there were none)."""
        mean = float(self._loss_sum) / self._loss_count if self._loss_count else None
        self._loss_sum, self._loss_count = torch.zeros(()), 0
        return mean


class Collector:
    """Acts ε-greedily, stores the transitions in the pool and keeps recent episodes' returns.

    Args:
        learning: Whose network acts and whose pool fills.
        reward_scale: Rewards are stored multiplied by it (returns are kept unscaled).
        n_step: Steps per stored return (:class:`~apf_physics.learning.buffer.NStepReturns`).
        gamma: γ, the discount rate of the returns.
        window: Recent episodes kept for :meth:`means`.
    """

    def __init__(self, learning: QLearning, reward_scale: float = 1.0, n_step: int = 1, gamma: float = 1.0,
                 window: int = 100):
        self.learning = learning
        self.reward_scale = reward_scale
        self.n_step, self.gamma = n_step, gamma
        self.recent_returns: collections.deque = collections.deque(maxlen=window)
        self.recent_success: collections.deque = collections.deque(maxlen=window)

    def begin(self, obs: np.ndarray, starts: np.ndarray) -> None:
        """Start from freshly reset environments' observations and where their searches start."""
        self.obs = obs
        self.starts = np.array(starts, float)
        self.prev_done = np.zeros(len(obs), bool)
        self.ep_return = np.zeros(len(obs))
        self.returns = NStepReturns(self.n_step, self.gamma, len(obs), obs.shape[1:])
        self.ended: list[tuple[np.ndarray, np.ndarray]] = []
        """``(starts, success)`` of the searches that ended since :meth:`take_ended`."""

    def step(self, step: Callable[[np.ndarray], tuple], epsilon: float, rng: np.random.Generator) -> tuple[int, int]:
        """One vector step; ``step(actions)`` returns ``(obs, rewards, terminated, truncated, success, positions)``.

        With NEXT_STEP autoreset the step right after an episode ends only returns the reset
        observation (and the new search's start): that is no transition.

        Returns:
            Transitions made (stored now or held for their n-step return) and episodes that ended.
        """
        actions = epsilon_greedy(self.learning.q_network, self.obs, epsilon, rng)
        next_obs, rewards, terminated, truncated, success, positions = step(actions)
        valid = ~self.prev_done
        self.starts[~valid] = positions[~valid]
        done = (terminated | truncated) & valid
        self.learning.buffer.add(*self.returns.add(self.obs, actions, rewards * self.reward_scale, next_obs,
                                                   terminated, done, valid))
        self.ep_return += np.where(valid, rewards, 0.0)
        if done.any():
            self.recent_returns.extend(self.ep_return[done].tolist())
            self.recent_success.extend(np.asarray(success, bool)[done].tolist())
            self.ended.append((self.starts[done].copy(), np.asarray(success, bool)[done]))
            self.ep_return[done] = 0.0
        self.prev_done = terminated | truncated
        self.obs = next_obs
        return int(valid.sum()), int(done.sum())

    def end(self) -> None:
        """The environments close: store the transitions still waiting for their n-step return."""
        self.learning.buffer.add(*self.returns.flush())

    def take_ended(self) -> tuple[np.ndarray, np.ndarray]:
        """Starts and success of the searches that ended since the last call."""
        ended, self.ended = self.ended, []
        if not ended:
            return np.zeros((0, 2)), np.zeros(0, bool)
        return np.concatenate([s for s, _ in ended]), np.concatenate([k for _, k in ended])

    def means(self) -> tuple[str | float, str | float]:
        """Mean return and success rate of the recent episodes, rounded for ``train.csv`` (``""``: none yet)."""
        if not self.recent_returns:
            return "", ""
        return round(float(np.mean(self.recent_returns)), 4), round(float(np.mean(self.recent_success)), 4)


class FailureStarts:
    """Training starts drawn where the policy fails: a share of them weighted by the recent failures near each.

    The map is divided into cells of one unit (one step); each cell keeps counts of the recent
    training searches that started in it and of those that failed, multiplied by
    :data:`FAILURE_MEMORY` at every draw (recent searches count most). A draw of
    :data:`DRAWN_STARTS` starts takes a ``share`` of them from the pool with weights
    ``(failures + 0.05) / (searches + 1)`` of their cells, and the rest uniformly from the pool,
    so every start stays possible.

    Args:
        pool: (S, 2) the training starts drawn from (in steps).
        world: Their world (its size and the frame of its file's units).
        share: The share drawn by failure.
    """

    def __init__(self, pool: np.ndarray, world: World, share: float):
        self.pool, self.share, self.frame = np.asarray(pool, float), float(share), world.frame
        self.width, self.height = (max(1, int(np.ceil(v))) for v in world.size)
        self.cells = self._cells(self.pool)
        self.searches = np.zeros(self.width * self.height)
        self.failures = np.zeros(self.width * self.height)

    def _cells(self, points: np.ndarray) -> np.ndarray:
        ix = np.clip(np.floor(points[:, 0]), 0, self.width - 1).astype(np.intp)
        iy = np.clip(np.floor(points[:, 1]), 0, self.height - 1).astype(np.intp)
        return ix * self.height + iy

    def record(self, starts: np.ndarray, success: np.ndarray) -> None:
        """Count searches that ended: their starts (in the world file's units) and whether they succeeded."""
        if len(starts):
            cells = self._cells((np.asarray(starts, float) - np.asarray(self.frame.offset, float)) / self.frame.unit)
            np.add.at(self.searches, cells, 1.0)
            np.add.at(self.failures, cells, (~np.asarray(success, bool)).astype(float))

    def draw(self, rng: np.random.Generator) -> np.ndarray:
        """(:data:`DRAWN_STARTS`, 2) starts for the next environments; the counts then fade."""
        weights = ((self.failures + 0.05) / (self.searches + 1.0))[self.cells]
        by_failure = int(round(self.share * DRAWN_STARTS))
        rows = np.concatenate([rng.choice(len(self.pool), by_failure, p=weights / weights.sum()),
                               rng.integers(0, len(self.pool), DRAWN_STARTS - by_failure)])
        self.searches *= FAILURE_MEMORY
        self.failures *= FAILURE_MEMORY
        return self.pool[rows]

    def state(self) -> dict[str, list[float]]:
        return {"searches": self.searches.tolist(), "failures": self.failures.tolist()}

    def load(self, state: dict[str, list[float]]) -> None:
        self.searches[:], self.failures[:] = state["searches"], state["failures"]


FAILURE_MEMORY = 0.5
"""What the counts of :class:`FailureStarts` keep at each draw: the last two or three draws' searches count,
as the policy changes between draws (0.8 was measured too: on fixed20 it reached the target later)."""
def start_pool(starts: Any, world: World, seed: int, count: int = 50_000) -> np.ndarray:
    """The starts :class:`FailureStarts` draws from, for a phase's ``starts``: its array; the world's own
    starts for ``"world"``; for ``"random"`` (or a world without starts) ``count`` random free positions
    away from the targets (generator seeded ``[seed, 7]``, as ``"reachable"`` starts are drawn)."""
    if not isinstance(starts, str):
        return np.asarray(starts, float)
    if starts == "world" and len(world.starts):
        return np.asarray(world.starts, float)
    return world.random_free_positions(np.random.default_rng([seed, 7]), count, away_from_targets=True)


DRAWN_STARTS = 4096
"""Starts of the environments between two draws of :class:`FailureStarts` (each copy draws among them)."""
REDRAW_STARTS_EVERY = 100
"""Vector steps between draws of :class:`FailureStarts` (new environments, seeded from the steps so far)."""
STARTS_STREAM = 0x57A7
"""Tag mixed into the seed of each draw of :class:`FailureStarts`."""


class TrainingEnvs:
    """The environments of a segment: one or two :class:`~apf_physics.envs.NavigateVectorEnv` stepped as one.

    The first starts its searches as the phase says, the second (a ``world_start_fraction``
    share of ``num_envs``) at the worlds' own starts. Env ``i`` is seeded with the ``i``-th
    value of ``SeedSequence(seed)``.
    """

    def __init__(self, worlds: Sequence[World], starts: Any, config: TrainConfig, seed: Sequence[int]):
        env = config.env
        n_world = int(round(env.world_start_fraction * env.num_envs))
        parts = [(starts, env.num_envs - n_world), ("world", n_world)]
        self.envs = [NavigateVectorEnv(world=list(worlds), num_envs=n, starts=s, observer=env.observer,
                                       reward=env.reward_weights, max_episode_steps=env.max_episode_steps)
                     for s, n in parts if n > 0]
        self.seeds = [int(s) for s in np.random.SeedSequence(list(seed)).generate_state(env.num_envs)]

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        """``(obs, positions)`` of all envs (positions in the world file's units, as ``info`` gives them)."""
        out, offset = [], 0
        for env in self.envs:
            obs, info = env.reset(seed=self.seeds[offset:offset + env.num_envs])
            out.append((obs, info["position"]))
            offset += env.num_envs
        return out[0] if len(out) == 1 else tuple(np.concatenate(parts) for parts in zip(*out))

    def step(self, actions: np.ndarray) -> tuple:
        """``(obs, rewards, terminated, truncated, success, positions)`` of all envs."""
        out, offset = [], 0
        for env in self.envs:
            obs, reward, terminated, truncated, info = env.step(actions[offset:offset + env.num_envs])
            out.append((obs, reward, terminated, truncated, info["success"], info["position"]))
            offset += env.num_envs
        return out[0] if len(out) == 1 else tuple(np.concatenate(parts) for parts in zip(*out))

    def close(self) -> None:
        for env in self.envs:
            env.close()


class DQNLearner(Learner):
    """Deep Q-learning of the window network in :class:`TrainingEnvs`; a step is one vector step."""

    def __init__(self, config: TrainConfig):
        self.config = config
        self.learning = QLearning(config)
        # what is evaluated and kept as best.pt
        self.network = (self.learning.target_network if config.dqn.eval_network == "target"
                        else self.learning.q_network)
        self.observer = config.observer
        self.collector = Collector(self.learning, config.dqn.reward_scale, config.dqn.n_step, config.dqn.gamma)
        self.envs: Optional[TrainingEnvs] = None
        self.epsilon = config.dqn.epsilon_initial
        self.failure_starts: Optional[FailureStarts] = None
        self._failure_state: Optional[dict] = None

    def begin(self, worlds: Sequence[World], phase: Phase, seed: tuple[int, int]) -> None:
        self.worlds, self.phase = list(worlds), phase
        if self.config.env.failure_starts and self.failure_starts is None:
            pool = start_pool(phase.starts, worlds[0], self.config.run.seed)
            self.failure_starts = FailureStarts(pool, worlds[0], self.config.env.failure_starts)
            if self._failure_state is not None:
                self.failure_starts.load(self._failure_state)
        self._open(seed)

    def _open(self, seed: tuple[int, int]) -> None:
        """New environments seeded from ``seed``; their starts drawn by failure if the configuration says so."""
        starts = self.phase.starts
        if self.failure_starts is not None:
            starts = self.failure_starts.draw(np.random.default_rng([STARTS_STREAM, *seed]))
        self.envs = TrainingEnvs(self.worlds, starts, self.config, seed=seed)
        self.collector.begin(*self.envs.reset())

    def collect(self, c: Counters, rng: np.random.Generator) -> tuple[int, int]:
        dqn = self.config.dqn
        self.epsilon = epsilon_schedule(dqn, c.phase_episodes if dqn.restart_exploration else c.episodes)
        if self.failure_starts is not None:
            self.failure_starts.record(*self.collector.take_ended())
            if c.vector_steps and c.vector_steps % REDRAW_STARTS_EVERY == 0:   # the searches in flight end here
                self.end()
                self._open((self.config.run.seed, c.global_step))
        return self.collector.step(self.envs.step, self.epsilon, rng)

    def update(self, c: Counters, rng: np.random.Generator) -> None:
        if self.learning.ready and c.vector_steps % self.config.dqn.train_frequency == 0:
            for _ in range(self.config.dqn.gradient_steps):
                self.learning.update(rng)

    def end(self) -> None:
        self.collector.end()
        self.envs.close()
        self.envs = None

    def planner(self, shield: bool) -> DQNPlanner:
        return DQNPlanner(policy=DQNPolicy(self.network, self.observer), shield=shield)

    def log_values(self, c: Counters) -> dict[str, Any]:
        mean_return, training_success = self.collector.means()
        return {"epsilon": round(self.epsilon, 5), "mean_return": mean_return, "training_success": training_success,
                "loss": self.learning.mean_loss()}

    def state(self, with_buffer: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        learning, collector = self.learning, self.collector
        state = {"updates": learning.updates, "loss_count": learning._loss_count,
                 "collector": {"returns": list(collector.recent_returns), "success": list(collector.recent_success)}}
        if self.failure_starts is not None:
            state["failure_starts"] = self.failure_starts.state()
        tensors = {"q_network": learning.q_network.state_dict(), "optimizer": learning.optimizer.state_dict(),
                   "loss_sum": learning._loss_sum.clone()}
        if learning.target_network is not learning.q_network:
            tensors["target_network"] = learning.target_network.state_dict()
        if with_buffer:
            tensors["buffer"] = learning.buffer.state_dict()
        return state, tensors

    def load(self, state: dict[str, Any], tensors: dict[str, Any]) -> None:
        learning = self.learning
        learning.q_network.load_state_dict(tensors["q_network"])
        if learning.target_network is not learning.q_network:
            learning.target_network.load_state_dict(tensors["target_network"])
        learning.optimizer.load_state_dict(tensors["optimizer"])
        if "buffer" in tensors:
            learning.buffer.load_state_dict(tensors["buffer"])
        learning.updates = int(state["updates"])
        learning._loss_sum, learning._loss_count = tensors["loss_sum"].clone(), int(state["loss_count"])
        self.collector.recent_returns.extend(state["collector"]["returns"])
        self.collector.recent_success.extend(state["collector"]["success"])
        self._failure_state = state.get("failure_starts")

    @property
    def updates(self) -> int:
        return self.learning.updates
