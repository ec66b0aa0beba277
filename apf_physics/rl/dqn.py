"""Deep Q-learning for the potential-window navigation task (thesis §4, SPEC §2).

Reads like cleanrl's ``dqn.py`` (a Q-network, an experience pool, an ε schedule and a
loop whose TD target fits on one screen) but is a library: :func:`train` takes a
:class:`DQNConfig` and returns a :class:`TrainResult`; the command line is a thin layer
over it (:mod:`apf_physics.commands.train`).

Presets (:func:`preset`):

- ``thesis-fixed``: Table 3 as written (11×11 window, filters 10/10/20, m = 7, MSE,
  no target network, raw observations, 30,000 searches from the world's starts).
- ``thesis-general``: Table 4 (9×9 window, filters 4/4, 150 searches).
- ``fast``: the thesis-fixed network trained the way it learns fastest here
  (64 parallel envs, batch 128, double DQN, Huber loss, soft target τ = 0.01, rewards /
  1000, signed-log relative observations, training starts at every free point at an
  integer offset from the target, greedy evaluation every 3,200 transitions) and stopped
  at the first evaluation where every start of the world succeeds.

Every action moves the robot by an integer vector, so from a start ``p`` it only ever
stands at ``p + (i, j)`` (until a collision ends the search): with a goal tolerance below
√2/2, a random start whose offset from the target is farther than the tolerance from an
integer vector can never succeed (≈ 21 % of uniform random starts at tolerance 0.5, see
:func:`reachable_mask`; fixed20's tolerance is now 0.75, where every start can). Training
from such starts wastes those searches and teaches the network to circle the target.
``train_starts="lattice"`` (the states reachable from the world's integer starts) learns
the world's starts fastest; ``"reachable"`` (random starts that can succeed) generalises
to other offsets.
"""

from __future__ import annotations

import collections
import copy
import csv
import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from apf_physics.errors import UserError
from apf_physics.rl.buffer import ReplayBuffer
from apf_physics.models.files import model_meta, read_file, save_model, write_file
from apf_physics.models.network import OBS_TRANSFORMS, QNetwork
from apf_physics.rl.plot import plot_training_curve

N_ACTIONS = 9
TRAIN_STARTS = ("world", "random", "reachable", "lattice")
"""Values of :attr:`DQNConfig.train_starts`."""
CSV_COLUMNS = ("global_step", "episodes", "epsilon", "mean_return", "success_rate", "loss", "eval_success", "wall_time",
               "eval_random_success")
"""Columns of ``train.csv``."""


@dataclass(frozen=True)
class DQNConfig:
    """Everything that defines a training run. Build one with :func:`preset`."""

    preset: str = "custom"
    """Name of the preset this configuration started from (informational)."""

    # --- network (saved with the model) ---
    obs_size: int = 11
    """k: side of the observation window [points, spacing 1 world unit]."""
    filters: tuple[int, ...] = (10, 10, 20)
    """Output channels of each 2×2 convolution."""
    hidden: tuple[int, ...] = (32, 32)
    """Widths of the hidden fully connected layers."""
    negative_slope: float = 0.001
    """Leaky ReLU slope λ."""
    obs_transform: str = "raw"
    """``"raw"`` or ``"relative-log"`` (signed log of U − U at the robot's cell); applied inside the network."""

    # --- environment ---
    reward: str = "thesis-fixed"
    """Reward preset of the environment (W1–W4, β of SPEC §2)."""
    max_episode_steps: int = 100
    """tt: moves per search before it is cut off."""
    train_starts: str = "world"
    """Where training searches start: ``"world"`` (the world's starts in turn), ``"random"`` (any free
    position), ``"reachable"`` (random free positions from which the integer moves of the action set can
    end within the goal tolerance of a target: see :func:`reachable_mask`) or ``"lattice"`` (the free
    points at integer offsets from a target, like the world's starts)."""
    num_envs: int = 1
    """Environments stepped in parallel (one vector step adds this many transitions)."""

    # --- learning ---
    gamma: float = 0.95
    """γ: discount rate."""
    learning_rate: float = 1e-3
    """η: Adam's learning rate."""
    batch_size: int = 7
    """m: transitions per update."""
    buffer_size: int = 100_000
    """Capacity of the experience pool [transitions]."""
    learning_starts: int = 8
    """Transitions in the pool before the first update (the thesis: more than m)."""
    train_frequency: int = 1
    """Vector steps between training rounds."""
    gradient_steps: int = 1
    """Updates per training round."""
    loss: str = "mse"
    """TD loss: ``"mse"`` (the thesis, eq. 35) or ``"huber"`` (less sensitive to outliers)."""
    double_dqn: bool = False
    """Choose the next action with the online network, value it with the target network."""
    target_update: str = "none"
    """``"none"`` (TD targets from the online network, as the thesis), ``"hard"`` (copy every
    ``target_update_every`` updates) or ``"soft"`` (Polyak averaging with ``tau`` each update)."""
    target_update_every: int = 1000
    """Updates between copies of a hard target network."""
    tau: float = 0.01
    """Soft target update rate: target ← (1 − τ)·target + τ·online."""
    max_grad_norm: Optional[float] = None
    """Clip the gradient's global norm to this (None: no clipping)."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this before learning (the logged returns are unscaled)."""

    # --- exploration (SPEC eq. 34: ε_s = max(ε_i·(ts − s)/ts, ε_f) over searches s) ---
    epsilon_initial: float = 0.95
    """ε_i."""
    epsilon_final: float = 0.05
    """ε_f."""
    exploration_episodes: int = 30_000
    """ts: searches over which ε decays."""

    # --- run ---
    total_episodes: Optional[int] = 30_000
    """Stop after this many searches (None: no limit)."""
    total_steps: Optional[int] = None
    """Stop after this many transitions (None: no limit)."""
    time_limit: Optional[float] = None
    """Stop after this many seconds of training, over all resumed sessions (None: no limit)."""
    eval_every: int = 10_000
    """Transitions between greedy evaluations on the world's starts."""
    eval_random_starts: int = 0
    """Also evaluate from this many random free starts that can reach a target (:func:`reachable_mask`),
    drawn once per run from a generator of its own (not the training starts' stream). The best
    checkpoint is then the one with the most successes from the world's starts, ties broken by
    these; ``target_success`` still refers to the world's starts only. 0: world's starts only."""
    target_success: Optional[float] = None
    """Stop once a greedy evaluation reaches this success rate (None: never stop early)."""
    checkpoint_every: int = 50_000
    """Transitions between ``last.pt`` checkpoints."""
    log_every: int = 2_000
    """Transitions between rows of ``train.csv``."""
    save_buffer: bool = False
    """Store the experience pool in ``last.pt`` (large); without it a resumed run refills it first."""
    threads: int = 1
    """torch intra-op threads during training. More than 1 helps only on an idle machine: on 2 busy
    cores, 2 threads made the network's forward pass ~10× slower (threads waiting on each other)."""
    seed: int = 0
    """Seed of the environments, the network's initial weights, ε-greedy and minibatch sampling."""

    def __post_init__(self):
        checks = [
            (self.obs_transform in OBS_TRANSFORMS, f"obs_transform must be one of {OBS_TRANSFORMS}"),
            (self.loss in ("mse", "huber"), "loss must be 'mse' or 'huber'"),
            (self.target_update in ("none", "hard", "soft"), "target_update must be 'none', 'hard' or 'soft'"),
            (self.train_starts in TRAIN_STARTS, f"train_starts must be one of {TRAIN_STARTS}"),
            (self.obs_size >= 3 and self.obs_size % 2 == 1, "obs_size must be odd and at least 3"),
            (self.eval_random_starts >= 0, "eval_random_starts must not be negative"),
            (min(self.num_envs, self.batch_size, self.threads) >= 1, "num_envs, batch_size and threads must be positive"),
            (0 < self.tau <= 1, "tau must be in (0, 1]"),
            (self.exploration_episodes >= 1, "exploration_episodes must be positive"),
            (self.total_episodes is not None or self.total_steps is not None or self.time_limit is not None
             or self.target_success is not None, "set total_episodes, total_steps, time_limit or target_success"),
            (min(self.eval_every, self.checkpoint_every, self.log_every, self.train_frequency,
                 self.gradient_steps, self.target_update_every, self.max_episode_steps) >= 1,
             "intervals and counts must be positive"),
        ]
        for ok, message in checks:
            if not ok:
                raise UserError(f"invalid training configuration: {message}")

    def to_dict(self) -> dict[str, Any]:
        """Plain values (tuples as lists), for JSON."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "DQNConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        return _replace_checked(cls(), data)

    def network(self, obs_channels: int = 1) -> QNetwork:
        """A freshly initialised Q-network for this configuration."""
        return QNetwork(
            obs_shape=(obs_channels, self.obs_size, self.obs_size),
            filters=self.filters,
            hidden=self.hidden,
            n_actions=N_ACTIONS,
            negative_slope=self.negative_slope,
            obs_transform=self.obs_transform,
        )


PRESETS: dict[str, dict[str, Any]] = {
    "thesis-fixed": dict(),
    "thesis-general": dict(
        obs_size=9, filters=(4, 4), reward="thesis-general",
        exploration_episodes=150, total_episodes=150, eval_every=2_000, checkpoint_every=5_000, log_every=500,
    ),
    "fast": dict(
        obs_transform="relative-log", train_starts="lattice", num_envs=64, batch_size=128,
        learning_starts=2_000, loss="huber", double_dqn=True, target_update="soft", tau=0.01,
        max_grad_norm=10.0, reward_scale=1e-3, exploration_episodes=3_000,
        total_episodes=None, total_steps=3_000_000, eval_every=3_200, target_success=1.0,
        checkpoint_every=128_000, log_every=6_400,
    ),
}
"""Keyword overrides of :class:`DQNConfig`'s defaults (which are Table 3's) for each preset."""


def _coerce(name: str, value: Any, default: Any) -> Any:
    """Convert a value from YAML/JSON/CLI to the type of the field's default."""
    if isinstance(default, tuple) and isinstance(value, (list, tuple)):
        return tuple(value)
    if isinstance(default, bool) or value is None:
        return value
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


_OPTIONAL_FLOATS = {"max_grad_norm", "target_success", "time_limit"}


def _replace_checked(config: DQNConfig, overrides: dict[str, Any]) -> DQNConfig:
    names = {f.name: f for f in dataclasses.fields(DQNConfig)}
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise UserError(f"unknown training option(s) {', '.join(unknown)}; valid: {', '.join(sorted(names))}")
    values = {}
    for key, value in overrides.items():
        default = getattr(config, key)
        if key in _OPTIONAL_FLOATS and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        values[key] = _coerce(key, value, default)
    return dataclasses.replace(config, **values)


def preset(name: str, **overrides: Any) -> DQNConfig:
    """A named configuration with some fields changed.

    Args:
        name: One of :data:`PRESETS`.
        **overrides: :class:`DQNConfig` fields to change.

    Returns:
        The configuration.

    Raises:
        UserError: Unknown preset or field, or an invalid value.
    """
    if name not in PRESETS:
        raise UserError(f"unknown training preset {name!r}; choose one of {', '.join(PRESETS)}")
    return _replace_checked(DQNConfig(preset=name, **PRESETS[name]), overrides)


def epsilon_schedule(config: DQNConfig, episodes: int) -> float:
    """ε after ``episodes`` finished searches: ``max(ε_i·(ts − s)/ts, ε_f)`` (SPEC eq. 34)."""
    ts = config.exploration_episodes
    return max(config.epsilon_initial * (ts - episodes) / ts, config.epsilon_final)


# ----------------------------------------------------------------------------------------
# Environments


def reachable_mask(world: Any, points: np.ndarray) -> np.ndarray:
    """Which start points can end a step within the goal tolerance of a target.

    Every action moves the robot by an integer vector (SPEC Table 1) and only a collision,
    which ends the search, moves it otherwise; so from ``p`` the robot only ever stands at
    ``p + (i, j)``. It can succeed only if one of those points is within the goal tolerance
    of a target, i.e. if ``p − t`` is within the tolerance of an integer vector. For
    uniformly random starts that holds for π·0.5² ≈ 79 % of them at tolerance 0.5, and for
    all of them at a tolerance of √2/2 or more.

    Args:
        world: The world (its ``targets`` and ``goal_tolerance``).
        points: (N, 2) start points.

    Returns:
        (N,) bool.
    """
    d = np.asarray(points, float)[:, None, :] - np.asarray(world.targets, float)[None]
    offset = d - np.round(d)
    return (np.linalg.norm(offset, axis=2) <= world.goal_tolerance).any(axis=1)


def validation_starts(world: Any, count: int, seed: int) -> np.ndarray:
    """``count`` random free starts that can reach a target, for :attr:`DQNConfig.eval_random_starts`.

    Drawn like ``"random"`` training starts but from a generator of their own (seeded with
    ``[seed, 13]``), farther than the goal tolerance from every target and kept by
    :func:`reachable_mask`.
    """
    rng = np.random.default_rng([seed, 13])
    targets = np.asarray(world.targets, float)
    out = np.empty((0, 2))
    while len(out) < count:
        points = world.random_free_positions(rng, 4 * count)
        far = np.min(np.linalg.norm(points[:, None] - targets[None], axis=2), axis=1) > world.goal_tolerance
        out = np.vstack([out, points[far & reachable_mask(world, points)]])
    return out[:count]


def training_starts(world: Any, kind: str, seed: int, count: int = 50_000) -> Any:
    """What to pass as the environments' ``starts`` for :attr:`DQNConfig.train_starts`.

    ``"world"`` and ``"random"`` are passed through; ``"reachable"`` gives up to ``count``
    random free positions (drawn like ``"random"``, with ``seed``) kept by
    :func:`reachable_mask` and farther than the goal tolerance from every target;
    ``"lattice"`` gives the free points at integer offsets from the targets, shuffled.
    """
    if kind in ("world", "random"):
        return kind
    rng = np.random.default_rng([seed, 7])
    targets = np.asarray(world.targets, float)
    if kind == "reachable":
        points = world.random_free_positions(rng, count)
        points = points[reachable_mask(world, points)]
    else:
        w, h = world.size
        xs = [t[0] + np.arange(np.floor(-t[0]), np.ceil(w - t[0]) + 1) for t in targets]
        ys = [t[1] + np.arange(np.floor(-t[1]), np.ceil(h - t[1]) + 1) for t in targets]
        points = np.concatenate([np.stack(np.meshgrid(x, y), -1).reshape(-1, 2) for x, y in zip(xs, ys)])
        points = points[world.is_free(points)]
        points = rng.permutation(np.unique(points, axis=0))
    far = np.min(np.linalg.norm(points[:, None] - targets[None], axis=2), axis=1) > world.goal_tolerance
    return points[far]



EnvFactory = Callable[..., Any]
"""``factory(world, *, num_envs, seed, starts, config) -> gymnasium.vector.VectorEnv``.

``starts`` is ``"world"``, ``"random"`` or an (num_envs, 2) array giving each env's start.
The env must autoreset in NEXT_STEP mode and report ``info["success"]`` (bool per env).
"""



def epsilon_greedy(q_network: torch.nn.Module, obs: np.ndarray, epsilon: float,
                   rng: np.random.Generator) -> np.ndarray:
    """ε-greedy actions for a batch: a random action with probability ε, else the greedy one."""
    with torch.inference_mode():
        actions = q_network(torch.from_numpy(obs)).argmax(1).numpy()
    explore = rng.random(len(actions)) < epsilon
    if explore.any():
        actions = np.where(explore, rng.integers(0, N_ACTIONS, len(actions)), actions)
    return actions


def store_transitions(buffer: ReplayBuffer, obs: np.ndarray, next_obs: np.ndarray, actions: np.ndarray,
                      rewards: np.ndarray, terminated: np.ndarray, prev_done: np.ndarray) -> np.ndarray:
    """Add a vector step's transitions to the buffer and return which were real.

    With NEXT_STEP autoreset, the step right after a done only returns the reset observation:
    that transition is not learned from.
    """
    valid = ~prev_done
    buffer.add(obs[valid], next_obs[valid], actions[valid], rewards[valid], terminated[valid])
    return valid

class Learner:
    """The Q-network, its target network, optimiser and replay buffer, and the TD update (SPEC eq. 32).

    What both trainers (:func:`train` and :func:`apf_physics.rl.general.train_general`) share;
    they collect the transitions, decide when to update, evaluate and log.

    Args:
        config: Network, buffer and learning-rule fields are used.
        obs_shape: (C, k, k) observations.
    """

    def __init__(self, config: "DQNConfig", obs_shape: tuple[int, int, int]):
        self.config = config
        self.q_network = config.network(obs_channels=obs_shape[0])
        self.target_network = copy.deepcopy(self.q_network) if config.target_update != "none" else self.q_network
        if self.target_network is not self.q_network:
            self.target_network.requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.q_network.parameters(), lr=config.learning_rate, fused=True)
        self.buffer = ReplayBuffer(config.buffer_size, obs_shape, config.batch_size)
        self.updates = 0
        self._online = list(self.q_network.parameters())
        self._target = list(self.target_network.parameters())
        self._loss_sum, self._loss_count = torch.zeros(()), 0

    @property
    def ready(self) -> bool:
        """Whether the buffer holds enough transitions to learn from."""
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
            # TD target (eq. 32): R + γ·max Q(O_{n+1}), nothing beyond a terminal step
            td_target = batch.rewards + c.gamma * (1.0 - batch.dones) * next_q
        q_taken = self.q_network(batch.observations).gather(1, batch.actions).squeeze(1)
        if c.loss == "huber":  # Huber loss: less sensitive to outliers than the thesis's MSE
            loss = F.smooth_l1_loss(q_taken, td_target)
        else:
            loss = F.mse_loss(q_taken, td_target)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if c.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self._online, c.max_grad_norm, foreach=True)
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

    def tensors(self, buffer: bool = False) -> dict[str, Any]:
        """What a checkpoint keeps of the learner (``buffer``: also the replay buffer)."""
        out = {"q_network": self.q_network.state_dict(), "optimizer": self.optimizer.state_dict()}
        if self.target_network is not self.q_network:
            out["target_network"] = self.target_network.state_dict()
        if buffer:
            out["buffer"] = self.buffer.state_dict()
        return out

    def load(self, tensors: dict[str, Any], updates: int) -> None:
        """Restore from :meth:`tensors` of a checkpoint, and the update count."""
        self.q_network.load_state_dict(tensors["q_network"])
        if self.target_network is not self.q_network:
            self.target_network.load_state_dict(tensors["target_network"])
        self.optimizer.load_state_dict(tensors["optimizer"])
        if "buffer" in tensors:
            self.buffer.load_state_dict(tensors["buffer"])
        self.updates = int(updates)


class Collector:
    """Acts ε-greedily in a vector environment, stores the transitions in the learner's buffer,
    and keeps the returns and successes of the episodes that end.

    Args:
        learner: Whose network acts and whose buffer fills.
        reward_scale: Rewards are stored multiplied by it (returns are kept unscaled).
        window: Recent episodes kept in :attr:`recent_returns` and :attr:`recent_success`.
    """

    def __init__(self, learner: Learner, reward_scale: float = 1.0, window: int = 100):
        self.learner = learner
        self.reward_scale = reward_scale
        self.recent_returns: collections.deque = collections.deque(maxlen=window)
        self.recent_success: collections.deque = collections.deque(maxlen=window)

    def begin(self, obs: np.ndarray) -> None:
        """Start from freshly reset environments' observations."""
        self.obs = obs
        self.prev_done = np.zeros(len(obs), bool)
        self.ep_return = np.zeros(len(obs))

    def step(self, step: Callable[[np.ndarray], tuple], epsilon: float, rng: np.random.Generator) -> tuple[int, int]:
        """One vector step: ``step(actions)`` returns ``(obs, rewards, terminated, truncated, success)``.

        Returns:
            Transitions stored and episodes that ended.
        """
        actions = epsilon_greedy(self.learner.q_network, self.obs, epsilon, rng)
        next_obs, rewards, terminated, truncated, success = step(actions)
        valid = store_transitions(self.learner.buffer, self.obs, next_obs, actions, rewards * self.reward_scale,
                                  terminated, self.prev_done)
        done = (terminated | truncated) & valid
        self.ep_return += np.where(valid, rewards, 0.0)
        if done.any():
            self.recent_returns.extend(self.ep_return[done].tolist())
            self.recent_success.extend(np.asarray(success, bool)[done].tolist())
            self.ep_return[done] = 0.0
        self.prev_done = terminated | truncated
        self.obs = next_obs
        return int(valid.sum()), int(done.sum())

    def means(self) -> tuple[str | float, str | float]:
        """Mean return and success rate of the recent episodes, rounded for ``train.csv`` (``""``: none yet)."""
        if not self.recent_returns:
            return "", ""
        return round(float(np.mean(self.recent_returns)), 4), round(float(np.mean(self.recent_success)), 4)


def start_csv(path: Optional[Path], columns: Sequence[str], resume_step: Optional[int] = None) -> None:
    """Begin ``train.csv``: a header for a new run; on resume, drop the rows logged after ``resume_step``."""
    if path is None:
        return
    rows: list[dict] = []
    if resume_step is not None and path.exists():
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f) if int(r["global_step"]) <= resume_step]
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(rows)


def navigate_env_factory(world: Any, *, num_envs: int, seed: int, starts: Any, config: DQNConfig):
    """The package's own vector environment (:class:`apf_physics.envs.NavigateVectorEnv`).

    For evaluation (``starts`` an array with one row per env) copy i begins at row i.
    """
    from apf_physics.envs import NavigateVectorEnv

    env = NavigateVectorEnv(world=world, num_envs=num_envs, starts=starts, obs_size=config.obs_size,
                            reward=config.reward, max_episode_steps=config.max_episode_steps)
    return env


@dataclass
class EvalResult:
    """Outcome of one greedy evaluation.

    Attributes:
        successes: Starts from which the target was reached.
        episodes: Starts tried.
        mean_return: Mean unscaled episode return.
    """

    successes: int
    episodes: int
    mean_return: float

    @property
    def success_rate(self) -> float:
        return self.successes / max(self.episodes, 1)


def evaluate_greedy(network: QNetwork, envs: Any, seed: int = 0, max_steps: int = 10_000) -> EvalResult:
    """Run one greedy episode in every env of ``envs`` and count successes.

    Deterministic for a deterministic env and a fixed ``seed``.

    Args:
        network: The Q-network.
        envs: A vector env whose env i starts at the i-th evaluation start.
        seed: Reset seed.
        max_steps: Safety bound on vector steps.

    Returns:
        The successes, episodes and mean return.
    """
    obs, _ = envs.reset(seed=seed)
    n = envs.num_envs
    running = np.ones(n, bool)
    returns = np.zeros(n)
    success = np.zeros(n, bool)
    for _ in range(max_steps):
        with torch.inference_mode():
            actions = network(torch.from_numpy(obs)).argmax(1).numpy()
        obs, rewards, terminated, truncated, info = envs.step(actions)
        returns += np.where(running, rewards, 0.0)
        success |= running & np.asarray(info.get("success", np.zeros(n, bool)), bool)
        running &= ~(terminated | truncated)
        if not running.any():
            break
    return EvalResult(successes=int(success.sum()), episodes=n, mean_return=float(returns.mean()))


# ----------------------------------------------------------------------------------------
# Training


@dataclass
class TrainResult:
    """What a training run did.

    Attributes:
        config: The configuration trained with.
        global_step: Transitions collected (over all envs).
        episodes: Searches finished.
        updates: Gradient updates made.
        wall_time: Seconds of training, over all resumed sessions.
        best_eval_success: Best greedy evaluation success rate (None if never evaluated).
        best_eval_step: Transition count at that evaluation.
        best_eval_random: Success rate from the validation starts at that evaluation (None without
            ``eval_random_starts``).
        time_to_target: Wall time when ``target_success`` was first reached (None: not reached).
        stopped_early: Whether training stopped because ``target_success`` was reached.
        out_dir: Directory with ``train.csv``, ``train.png``, ``best.pt``, ``last.pt`` (None: nothing written).
        network: The online network at the end.
        best_state: State dict of the best-evaluated network (None if never evaluated).
        history: The rows of ``train.csv`` written in this session.
    """

    config: DQNConfig
    global_step: int
    episodes: int
    updates: int
    wall_time: float
    best_eval_success: Optional[float]
    best_eval_step: Optional[int]
    best_eval_random: Optional[float]
    time_to_target: Optional[float]
    stopped_early: bool
    out_dir: Optional[Path]
    network: QNetwork
    best_state: Optional[dict]
    history: list = field(default_factory=list)

    @property
    def best_path(self) -> Optional[Path]:
        return None if self.out_dir is None else self.out_dir / "best.pt"

    @property
    def last_path(self) -> Optional[Path]:
        return None if self.out_dir is None else self.out_dir / "last.pt"


def _world_info(world: Any) -> dict[str, Any]:
    info = {"name": getattr(world, "name", None), "source": getattr(world, "source", None)}
    return {k: (os.fspath(v) if isinstance(v, os.PathLike) else v) for k, v in info.items()}


def load_checkpoint_config(path: str | os.PathLike) -> DQNConfig:
    """The configuration stored in a training checkpoint (for ``--resume``)."""
    meta, _ = read_file(path)
    return DQNConfig.from_dict(meta["config"])


def train(
    config: DQNConfig,
    world: Any,
    *,
    out_dir: str | os.PathLike | None = None,
    resume: bool = False,
    env_factory: EnvFactory = navigate_env_factory,
    progress: bool = True,
) -> TrainResult:
    """Train a Q-network on ``world`` with deep Q-learning.

    Args:
        config: The configuration (see :func:`preset`).
        world: The world to train in (its ``starts`` are the evaluation starts, its
            ``field`` is recorded in the saved models).
        out_dir: Directory for ``train.csv``, ``train.png``, ``best.pt`` (the network
            with the best greedy evaluation) and ``last.pt`` (the full training state);
            created if missing. None: write nothing.
        resume: Continue from ``out_dir/last.pt`` (its configuration must equal ``config``
            except for the stopping criteria).
        env_factory: Builds the vector environments (see :data:`EnvFactory`).
        progress: Show a tqdm progress bar.

    Returns:
        The result; the networks are also in the files when ``out_dir`` is given.

    Raises:
        UserError: ``resume`` without a usable checkpoint, or with a different configuration.
    """
    out = Path(out_dir) if out_dir is not None else None
    if resume and out is None:
        raise UserError("resuming needs the output directory of the run to continue")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    try:
        return _train(config, world, out, resume, env_factory, progress)
    finally:
        torch.set_num_threads(previous_threads)


def _train(config, world, out, resume, env_factory, progress) -> TrainResult:
    rng = np.random.default_rng(config.seed)  # ε-greedy and minibatch sampling
    torch.manual_seed(config.seed)

    starts = np.asarray(world.starts, float).reshape(-1, 2)
    eval_envs = env_factory(world, num_envs=len(starts), seed=config.seed, starts=starts, config=config)
    random_envs = None
    if config.eval_random_starts:
        validation = validation_starts(world, config.eval_random_starts, config.seed)
        random_envs = env_factory(world, num_envs=len(validation), seed=config.seed, starts=validation, config=config)
    obs_shape = tuple(eval_envs.single_observation_space.shape)
    if obs_shape[1:] != (config.obs_size, config.obs_size):
        raise UserError(f"the environment's observations are {obs_shape}, but obs_size is {config.obs_size}")

    learner = Learner(config, obs_shape)
    q_network = learner.q_network

    # Counters and bests, restored on resume.
    global_step = episodes = vector_steps = 0
    elapsed_before = 0.0
    best_success: Optional[float] = None
    best_random: Optional[float] = None
    best_step: Optional[int] = None
    time_to_target: Optional[float] = None
    best_state: Optional[dict] = None
    csv_path = out / "train.csv" if out is not None else None

    if resume:
        last = out / "last.pt"
        meta, tensors = read_file(last)
        if meta.get("kind") != "checkpoint":
            raise UserError(f"{last}: not a training checkpoint")
        saved = DQNConfig.from_dict(meta["config"])
        ignore = {"total_steps", "total_episodes", "time_limit", "target_success", "threads", "eval_every", "checkpoint_every", "log_every", "save_buffer"}
        differ = [f.name for f in dataclasses.fields(DQNConfig)
                  if f.name not in ignore and getattr(saved, f.name) != getattr(config, f.name)]
        if differ:
            raise UserError(f"{last}: was trained with different options ({', '.join(differ)}); "
                            "resume with the same preset and options")
        counters = meta["counters"]
        learner.load(tensors, counters["updates"])
        global_step, episodes, vector_steps = (int(counters[k]) for k in ("global_step", "episodes", "vector_steps"))
        elapsed_before = float(counters["wall_time"])
        best_success, best_step, time_to_target = counters["best_eval_success"], counters["best_eval_step"], counters["time_to_target"]
        best_random = counters.get("best_eval_random")
        rng.bit_generator.state = meta["numpy_rng"]
        torch.set_rng_state(tensors["torch_rng"])
        if "best_state" in tensors:
            best_state = tensors["best_state"]
    start_csv(csv_path, CSV_COLUMNS, global_step if resume else None)

    envs = env_factory(world, num_envs=config.num_envs, seed=config.seed + global_step,
                       starts=training_starts(world, config.train_starts, config.seed), config=config)
    n = config.num_envs
    collector = Collector(learner, config.reward_scale)
    collector.begin(envs.reset(seed=config.seed + global_step)[0])
    no_success = np.zeros(n, bool)

    def env_step(actions: np.ndarray) -> tuple:
        next_obs, rewards, terminated, truncated, info = envs.step(actions)
        return next_obs, rewards, terminated, truncated, info.get("success", no_success)
    history: list[dict] = []
    next_log = (global_step // config.log_every + 1) * config.log_every
    next_eval = (global_step // config.eval_every + 1) * config.eval_every
    next_checkpoint = (global_step // config.checkpoint_every + 1) * config.checkpoint_every
    field_params = world.field
    world_info = _world_info(world)
    start_time = time.perf_counter()
    stopped_early = False

    def wall() -> float:
        return elapsed_before + time.perf_counter() - start_time

    def training_meta() -> dict:
        return {"world": world_info, "global_step": global_step, "episodes": episodes, "updates": learner.updates,
                "wall_time": wall(), "eval_success": best_success, "eval_step": best_step,
                "eval_random_success": best_random, "eval_random_starts": config.eval_random_starts}

    def save_checkpoint() -> None:
        if out is None:
            return
        meta = model_meta(q_network, field_params, config.to_dict(), training_meta())
        meta["kind"] = "checkpoint"
        meta["counters"] = {"global_step": global_step, "episodes": episodes, "updates": learner.updates,
                            "vector_steps": vector_steps, "wall_time": wall(), "best_eval_success": best_success,
                            "best_eval_step": best_step, "time_to_target": time_to_target,
                            "best_eval_random": best_random}
        meta["numpy_rng"] = rng.bit_generator.state
        tensors = {**learner.tensors(buffer=config.save_buffer), "torch_rng": torch.get_rng_state()}
        if best_state is not None:
            tensors["best_state"] = best_state
        write_file(out / "last.pt", meta, tensors)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=config.total_steps, initial=global_step, unit="step", dynamic_ncols=True, smoothing=0.05)

    def finished() -> bool:
        return ((config.total_steps is not None and global_step >= config.total_steps)
                or (config.total_episodes is not None and episodes >= config.total_episodes)
                or (config.time_limit is not None and wall() >= config.time_limit))

    try:
        while not finished():
            epsilon = epsilon_schedule(config, episodes)
            added, ended = collector.step(env_step, epsilon, rng)
            episodes += ended
            global_step += added
            vector_steps += 1
            if bar is not None:
                bar.update(added)

            if learner.ready and vector_steps % config.train_frequency == 0:
                for _ in range(config.gradient_steps):
                    learner.update(rng)

            eval_success = eval_random = None
            if global_step >= next_eval:
                next_eval += config.eval_every * max(1, (global_step - next_eval) // config.eval_every + 1)
                result = evaluate_greedy(q_network, eval_envs, seed=config.seed)
                eval_success = result.success_rate
                if random_envs is not None:
                    eval_random = evaluate_greedy(q_network, random_envs, seed=config.seed).success_rate
                if best_success is None or (eval_success, eval_random or 0.0) > (best_success, best_random or 0.0):
                    best_success, best_step, best_random = eval_success, global_step, eval_random
                    best_state = {k: v.clone() for k, v in q_network.state_dict().items()}
                    if out is not None:
                        save_model(out / "best.pt", q_network,
                                   model_meta(q_network, field_params, config.to_dict(), training_meta()))
                if config.target_success is not None and eval_success >= config.target_success:
                    if time_to_target is None:
                        time_to_target = wall()
                    stopped_early = True

            if global_step >= next_log or eval_success is not None or stopped_early:
                if global_step >= next_log:
                    next_log += config.log_every * max(1, (global_step - next_log) // config.log_every + 1)
                mean_return, success_rate = collector.means()
                row = {
                    "global_step": global_step,
                    "episodes": episodes,
                    "epsilon": round(epsilon, 5),
                    "mean_return": mean_return,
                    "success_rate": success_rate,
                    "loss": "" if (loss := learner.mean_loss()) is None else round(loss, 6),
                    "eval_success": round(eval_success, 4) if eval_success is not None else "",
                    "wall_time": round(wall(), 3),
                    "eval_random_success": round(eval_random, 4) if eval_random is not None else "",
                }
                history.append(row)
                if csv_path is not None:
                    with open(csv_path, "a", newline="") as f:
                        csv.DictWriter(f, CSV_COLUMNS).writerow(row)
                    if eval_success is not None:
                        plot_training_curve(csv_path, out / "train.png")
                if bar is not None:
                    bar.set_postfix(eps=f"{epsilon:.3f}", succ=row["success_rate"], ret=row["mean_return"],
                                    eval=best_success if best_success is None else f"{best_success:.2f}", refresh=False)

            if global_step >= next_checkpoint:
                next_checkpoint += config.checkpoint_every * max(1, (global_step - next_checkpoint) // config.checkpoint_every + 1)
                save_checkpoint()
            if stopped_early:
                break
    except KeyboardInterrupt:
        save_checkpoint()  # an interrupted run resumes from here
        raise
    finally:
        if bar is not None:
            bar.close()
        envs.close()
        eval_envs.close()
        if random_envs is not None:
            random_envs.close()

    save_checkpoint()
    if csv_path is not None:
        plot_training_curve(csv_path, out / "train.png")
    return TrainResult(
        config=config, global_step=global_step, episodes=episodes, updates=learner.updates, wall_time=wall(),
        best_eval_success=best_success, best_eval_step=best_step, best_eval_random=best_random, time_to_target=time_to_target,
        stopped_early=stopped_early, out_dir=out, network=q_network, best_state=best_state, history=history,
    )
