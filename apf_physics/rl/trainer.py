"""Deep Q-learning (Model §2, thesis §4): one loop over a list of phases.

:func:`train` takes a :class:`~apf_physics.rl.config.TrainConfig` and the phases to train
(:mod:`apf_physics.rl.phases`: one world is one phase, a curriculum several) and returns a
:class:`TrainResult`. Each vector step acts ε-greedily in every environment, stores the
transitions and makes the configured updates (:class:`Learner`, whose TD target is
eq. 32); every ``eval_every`` transitions the greedy network is run as the DQN planner through
the physics on the phase's validation set (:mod:`apf_physics.rl.evaluation`), and the best
evaluation so far is written to ``best.pt``.

The run goes in segments. A segment ends at a checkpoint (``last.pt``: network, optimiser,
counters, random states, optionally the experience pool), at the end of a phase and when the
pool of generated worlds is redrawn; every segment starts with fresh environments seeded from
``(seed, transitions so far)``. So a run resumed from any checkpoint it wrote on its own
(with ``save_buffer``) continues exactly as the uninterrupted run; a run resumed after an
interrupt (Ctrl-C saves a checkpoint where it stopped) continues from there with fresh
environments.
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from apf_physics.envs import NavigateVectorEnv
from apf_physics.errors import UserError
from apf_physics.models.files import model_meta, read_file, save_model, write_file
from apf_physics.models.network import QNetwork
from apf_physics.rl import evaluation
from apf_physics.rl.buffer import ReplayBuffer
from apf_physics.rl.config import N_ACTIONS, TrainConfig, differing_fields, epsilon_schedule
from apf_physics.rl.phases import Phase, draw_pool
from apf_physics.rl.plot import plot_training_curve
from apf_physics.rl.rundir import RunDir

CSV_COLUMNS = ("global_step", "episodes", "phase", "epsilon", "mean_return", "success_rate", "loss",
               "eval_success", "eval_trap_success", "eval_collisions", "eval_length_ratio", "eval_spl",
               "eval_random_success", "pool_draws", "wall_time")
"""Columns of ``train.csv`` (``eval_*``: the evaluation made at that step, if any)."""


# ----------------------------------------------------------------------------------------
# Learning


def epsilon_greedy(q_network: torch.nn.Module, obs: np.ndarray, epsilon: float,
                   rng: np.random.Generator) -> np.ndarray:
    """ε-greedy actions for a batch: a random action with probability ε, else the greedy one."""
    with torch.inference_mode():
        actions = q_network(torch.from_numpy(obs)).argmax(1).numpy()
    explore = rng.random(len(actions)) < epsilon
    if explore.any():
        actions = np.where(explore, rng.integers(0, N_ACTIONS, len(actions)), actions)
    return actions


class Learner:
    """The Q-network, its target network, optimiser and experience pool, and the TD update (Model eq. 32).

    Args:
        config: Network, pool and learning-rule fields are used.
    """

    def __init__(self, config: TrainConfig):
        self.config = config
        self.q_network = config.network()
        self.target_network = copy.deepcopy(self.q_network) if config.target_update != "none" else self.q_network
        if self.target_network is not self.q_network:
            self.target_network.requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.q_network.parameters(), lr=config.learning_rate, fused=True)
        self.buffer = ReplayBuffer(config.buffer_size, config.observer.shape, config.batch_size)
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
        """What a checkpoint keeps of the learner (``buffer``: also the experience pool)."""
        out = {"q_network": self.q_network.state_dict(), "optimizer": self.optimizer.state_dict(),
               "loss_sum": self._loss_sum.clone()}
        if self.target_network is not self.q_network:
            out["target_network"] = self.target_network.state_dict()
        if buffer:
            out["buffer"] = self.buffer.state_dict()
        return out

    def load(self, tensors: dict[str, Any], updates: int, loss_count: int) -> None:
        """Restore from :meth:`tensors` of a checkpoint, with the update and loss counts."""
        self.q_network.load_state_dict(tensors["q_network"])
        if self.target_network is not self.q_network:
            self.target_network.load_state_dict(tensors["target_network"])
        self.optimizer.load_state_dict(tensors["optimizer"])
        if "buffer" in tensors:
            self.buffer.load_state_dict(tensors["buffer"])
        self.updates = int(updates)
        self._loss_sum, self._loss_count = tensors["loss_sum"].clone(), int(loss_count)


class Collector:
    """Acts ε-greedily, stores the transitions in the learner's pool and keeps recent episodes' returns.

    Args:
        learner: Whose network acts and whose pool fills.
        reward_scale: Rewards are stored multiplied by it (returns are kept unscaled).
        window: Recent episodes kept for :meth:`means`.
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
        """One vector step; ``step(actions)`` returns ``(obs, rewards, terminated, truncated, success)``.

        With NEXT_STEP autoreset the step right after an episode ends only returns the reset
        observation: that transition is not stored.

        Returns:
            Transitions stored and episodes that ended.
        """
        actions = epsilon_greedy(self.learner.q_network, self.obs, epsilon, rng)
        next_obs, rewards, terminated, truncated, success = step(actions)
        valid = ~self.prev_done
        self.learner.buffer.add(self.obs[valid], next_obs[valid], actions[valid],
                                rewards[valid] * self.reward_scale, terminated[valid])
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

    def state(self) -> dict:
        return {"returns": list(self.recent_returns), "success": list(self.recent_success)}

    def load(self, state: dict) -> None:
        self.recent_returns.extend(state["returns"])
        self.recent_success.extend(state["success"])


class TrainingEnvs:
    """The environments of a segment: one or two :class:`~apf_physics.envs.NavigateVectorEnv` stepped as one.

    The first starts its searches as the phase says, the second (a ``world_start_fraction``
    share of ``num_envs``) at the worlds' own starts. Env ``i`` is seeded with the ``i``-th
    value of ``SeedSequence(seed)``.
    """

    def __init__(self, worlds: Sequence, starts: Any, config: TrainConfig, seed: Sequence[int]):
        n_world = int(round(config.world_start_fraction * config.num_envs))
        parts = [(starts, config.num_envs - n_world), ("world", n_world)]
        self.envs = [NavigateVectorEnv(world=list(worlds), num_envs=n, starts=s, observer=config.observer,
                                       reward=config.reward_weights, max_episode_steps=config.max_episode_steps)
                     for s, n in parts if n > 0]
        self.seeds = [int(s) for s in np.random.SeedSequence(list(seed)).generate_state(config.num_envs)]

    def reset(self) -> np.ndarray:
        obs, offset = [], 0
        for env in self.envs:
            obs.append(env.reset(seed=self.seeds[offset:offset + env.num_envs])[0])
            offset += env.num_envs
        return obs[0] if len(obs) == 1 else np.concatenate(obs)

    def step(self, actions: np.ndarray) -> tuple:
        """``(obs, rewards, terminated, truncated, success)`` of all envs."""
        out, offset = [], 0
        for env in self.envs:
            obs, reward, terminated, truncated, info = env.step(actions[offset:offset + env.num_envs])
            out.append((obs, reward, terminated, truncated, info["success"]))
            offset += env.num_envs
        return out[0] if len(out) == 1 else tuple(np.concatenate(parts) for parts in zip(*out))

    def close(self) -> None:
        for env in self.envs:
            env.close()


# ----------------------------------------------------------------------------------------
# The run


@dataclass
class Counters:
    """Where a run stands (saved in every checkpoint)."""

    global_step: int = 0
    """Transitions collected."""
    episodes: int = 0
    """Searches finished."""
    vector_steps: int = 0
    phase: int = 0
    """Index of the current phase (``len(phases)``: all done)."""
    phase_steps: int = 0
    phase_episodes: int = 0
    pool_draws: int = 0
    wall_time: float = 0.0
    """Seconds of training over all sessions, up to the checkpoint."""
    best_step: Optional[int] = None
    """Transitions at the best evaluation."""
    top_success: Optional[float] = None
    """Highest ``success`` of any evaluation (what ``target_success`` is compared with)."""
    time_to_target: Optional[float] = None
    """Wall time at which an evaluation first reached ``target_success``."""
    last_eval_step: Optional[int] = None


@dataclass
class Evaluations:
    """The best and the latest evaluation of a run, and the best network's weights."""

    best: Optional[dict] = None
    latest: Optional[dict] = None
    best_state: Optional[dict] = None

    def record(self, summary: dict, c: Counters, network: QNetwork, config: TrainConfig) -> bool:
        """Note an evaluation made at ``c.global_step``; returns whether it is the best so far."""
        self.latest = summary
        c.last_eval_step = c.global_step
        c.top_success = max(c.top_success or 0.0, summary["success"])
        if (config.target_success is not None and c.time_to_target is None
                and summary["success"] >= config.target_success):
            c.time_to_target = c.wall_time
        if self.best is not None and evaluation.score(summary, config.select) <= evaluation.score(self.best, config.select):
            return False
        self.best, c.best_step = summary, c.global_step
        self.best_state = {k: v.clone() for k, v in network.state_dict().items()}
        return True


@dataclass
class TrainResult:
    """What a training run did.

    Attributes:
        config: The configuration.
        counters: Steps, searches, phase, wall time and the best evaluation's step.
        updates: Gradient updates made.
        best: Figures of the best evaluation (None: never evaluated).
        latest: Figures of the latest evaluation (None: never evaluated).
        stop_reason: Why the run stopped (None: interrupted).
        already_finished: A resumed run that had already stopped by its rules: nothing was trained or written.
        out_dir: The output folder (None: nothing written).
        written: Files written by this session.
        network: The online network at the end.
        best_state: State dict of the best network (None: never evaluated).
        history: Rows of ``train.csv`` written in this session.
    """

    config: TrainConfig
    counters: Counters
    updates: int
    best: Optional[dict]
    latest: Optional[dict]
    stop_reason: Optional[str]
    already_finished: bool
    out_dir: Optional[Path]
    written: list
    network: QNetwork
    best_state: Optional[dict]
    history: list = field(default_factory=list)

    @property
    def global_step(self) -> int:
        return self.counters.global_step

    @property
    def episodes(self) -> int:
        return self.counters.episodes

    @property
    def wall_time(self) -> float:
        return self.counters.wall_time

    @property
    def stopped_early(self) -> bool:
        """Stopped because an evaluation reached ``target_success``."""
        return self.stop_reason is not None and self.stop_reason.startswith("target")


def stop_reason(config: TrainConfig, phases: Sequence[Phase], c: Counters, wall: float) -> Optional[str]:
    """Why the run must stop now (None: it goes on)."""
    if c.phase >= len(phases):
        return "every phase finished"
    if config.total_steps is not None and c.global_step >= config.total_steps:
        return f"total_steps {config.total_steps} reached"
    if config.total_episodes is not None and c.episodes >= config.total_episodes:
        return f"total_episodes {config.total_episodes} reached"
    if config.time_limit is not None and wall >= config.time_limit:
        return f"time_limit {config.time_limit:g} s reached"
    if config.target_success is not None and c.top_success is not None and c.top_success >= config.target_success:
        return f"target_success {config.target_success:g} reached"
    return None


def next_multiple(value: int, every: int) -> int:
    return (value // every + 1) * every


def train(config: TrainConfig, phases: Sequence[Phase], out_dir: str | Path | RunDir | None = None,
          resume: bool = False, progress: bool = False) -> TrainResult:
    """Train a Q-network through ``phases`` with deep Q-learning.

    Args:
        config: The configuration (:func:`~apf_physics.rl.config.preset`).
        phases: What to train on, in order (:func:`~apf_physics.rl.phases.phases_for_world`,
            :func:`~apf_physics.rl.phases.phases_for_curriculum`).
        out_dir: Folder for ``best.pt`` (the best evaluation's network: the one to use),
            ``last.pt`` (the training state), ``train.csv`` and ``train.png``; created if
            missing and locked while training (:class:`~apf_physics.rl.rundir.RunDir`; an open
            one is used as it is and left open). None: write nothing.
        resume: Continue from ``out_dir/last.pt`` (same configuration except
            :data:`~apf_physics.rl.config.RESUMABLE` fields, same phases). If that run has
            already stopped by its rules, nothing is trained or written
            (:attr:`TrainResult.already_finished`).
        progress: Show a progress bar on stderr when it is a terminal.

    Returns:
        The result. KeyboardInterrupt is raised again after a checkpoint is saved.

    Raises:
        UserError: Nothing to train, worlds of different fields, a folder locked by another run
            or holding a run already (without ``resume``), or ``resume`` without a usable checkpoint.
    """
    return run_training(_train, config, phases, out_dir, resume, progress)


def run_training(body: Callable[..., TrainResult], config: TrainConfig, phases: Sequence[Phase],
                 out_dir: str | Path | RunDir | None, resume: bool, progress: bool) -> TrainResult:
    """What every trainer's entry point does around its loop ``body(config, phases, run, resume, progress)``:
    check the phases (some, of one field) and the resume, open the run's folder (``run``, None
    without ``out_dir``) unless given open, and train on ``config.threads`` torch threads.
    """
    if not phases:
        raise UserError("nothing to train: no phases")
    fields = {tuple(w.field.as_dict().items()) for p in phases for w in (*p.worlds, *p.validation.worlds)}
    if len(fields) != 1:
        raise UserError("a model is trained for one field, but these worlds have different field parameters")
    if resume and out_dir is None:
        raise UserError("resuming needs the output folder of the run to continue")
    given = isinstance(out_dir, RunDir)
    run = out_dir if given else RunDir(out_dir, CSV_COLUMNS) if out_dir is not None else None
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    try:
        if run is not None and not resume and run.last.exists():
            raise UserError(f"{run.path} already holds a training run; resume it or train into another folder")
        return body(config, list(phases), run, resume, progress)
    finally:
        torch.set_num_threads(previous_threads)
        if run is not None and not given:
            run.close()


def _train(config: TrainConfig, phases: list[Phase], run: Optional[RunDir], resume: bool,
           progress: bool) -> TrainResult:
    rng = np.random.default_rng(config.seed)  # ε-greedy and minibatch sampling
    torch.manual_seed(config.seed)
    learner = Learner(config)
    q_network = learner.q_network
    collector = Collector(learner, config.reward_scale)
    c = Counters()
    evals = Evaluations()
    if resume:
        restore(run, config, phases, learner, collector, c, evals, rng)
        reason = stop_reason(config, phases, c, c.wall_time)
        if reason is not None:
            return TrainResult(config, c, learner.updates, evals.best, evals.latest, reason, True, run.path, [],
                               q_network, evals.best_state)
    if run is not None:
        run.start_log(c.global_step if resume else None)

    history: list[dict] = []
    bar = ProgressBar(config, phases, c) if progress else None
    elapsed_before, start = c.wall_time, time.perf_counter()
    next_eval = next_multiple(c.global_step, config.eval_every)
    next_log = next_multiple(c.global_step, config.log_every)
    next_checkpoint = next_multiple(c.global_step, config.checkpoint_every)
    epsilon, reason = config.epsilon_initial, None
    try:
        while reason is None:
            phase = phases[c.phase]
            worlds = list(phase.worlds)
            next_refresh = None
            if phase.pool:  # redrawn where the last pool would have been redrawn (also on resume)
                worlds += draw_pool(config, c.pool_draws)
                next_refresh = next_multiple(c.phase_steps, config.refresh_every)
            envs = TrainingEnvs(worlds, phase.starts, config, seed=(config.seed, c.global_step))
            collector.begin(envs.reset())
            while True:
                epsilon = epsilon_schedule(config, c.phase_episodes if config.restart_exploration else c.episodes)
                added, ended = collector.step(envs.step, epsilon, rng)
                c.global_step += added
                c.episodes += ended
                c.phase_steps += added
                c.phase_episodes += ended
                c.vector_steps += 1
                if learner.ready and c.vector_steps % config.train_frequency == 0:
                    for _ in range(config.gradient_steps):
                        learner.update(rng)

                phase_over = ((phase.episodes is not None and c.phase_episodes >= phase.episodes)
                              or (phase.steps is not None and c.phase_steps >= phase.steps))
                redraw = next_refresh is not None and c.phase_steps >= next_refresh
                if phase_over:
                    c.phase, c.phase_steps, c.phase_episodes = c.phase + 1, 0, 0
                elif redraw:
                    c.pool_draws += 1
                c.wall_time = elapsed_before + time.perf_counter() - start

                summary = None
                if c.global_step >= next_eval:
                    next_eval = next_multiple(c.global_step, config.eval_every)
                    summary = evaluate(q_network, config, phase)
                    c.wall_time = elapsed_before + time.perf_counter() - start
                    if evals.record(summary, c, q_network, config):
                        save_best(run, q_network, config, phases, c, evals.best, learner.updates)
                if summary is not None or c.global_step >= next_log:
                    next_log = next_multiple(c.global_step, config.log_every)
                    history.append(log_row(run, c, phase, epsilon, collector, learner, summary))
                if bar is not None:
                    bar.update(c, phase, epsilon, evals.latest)

                reason = stop_reason(config, phases, c, c.wall_time)
                if reason is not None or phase_over or redraw or c.global_step >= next_checkpoint:
                    break
            envs.close()
            if reason is None:  # a segment ends at a checkpoint
                save_checkpoint(run, config, phases, learner, collector, c, rng, evals)
                save_curve(run)
                next_checkpoint = next_multiple(c.global_step, config.checkpoint_every)
        if c.last_eval_step != c.global_step:  # a last evaluation, so the end of the run can be the best
            phase = phases[min(c.phase, len(phases) - 1)]
            summary = evaluate(q_network, config, phase)
            if evals.record(summary, c, q_network, config):
                save_best(run, q_network, config, phases, c, evals.best, learner.updates)
            history.append(log_row(run, c, phase, epsilon, collector, learner, summary))
        c.wall_time = elapsed_before + time.perf_counter() - start
        save_checkpoint(run, config, phases, learner, collector, c, rng, evals)
    except KeyboardInterrupt:
        c.wall_time = elapsed_before + time.perf_counter() - start
        save_checkpoint(run, config, phases, learner, collector, c, rng, evals)
        raise
    finally:
        if bar is not None:
            bar.close()
    save_curve(run)
    return TrainResult(config, c, learner.updates, evals.best, evals.latest, reason, False,
                       None if run is None else run.path, [] if run is None else list(run.written), q_network,
                       evals.best_state, history)


def evaluate(network: QNetwork, config: TrainConfig, phase: Phase) -> dict[str, float]:
    """The figures of the network on the phase's validation set (and ``random_success`` on its random starts)."""
    observer = config.observer
    summary = evaluation.summarise(evaluation.run(network, observer, phase.validation, config.eval_shield),
                                   phase.validation)
    if phase.random_validation is not None:
        episodes = evaluation.run(network, observer, phase.random_validation, config.eval_shield)
        summary["random_success"] = evaluation.summarise(episodes, phase.random_validation)["success"]
    return summary


def log_row(run: Optional[RunDir], c: Counters, phase: Phase, epsilon: float, collector: Collector,
            learner: Learner, summary: Optional[dict]) -> dict:
    """A row of ``train.csv``, written if there is a folder."""
    mean_return, success_rate = collector.means()
    loss = learner.mean_loss()
    s = {k: "" if v is None else round(v, 4) for k, v in (summary or {}).items()}
    row = {
        "global_step": c.global_step, "episodes": c.episodes, "phase": phase.name, "epsilon": round(epsilon, 5),
        "mean_return": mean_return, "success_rate": success_rate, "loss": "" if loss is None else round(loss, 6),
        "eval_success": s.get("success", ""), "eval_trap_success": s.get("trap_success", ""),
        "eval_collisions": s.get("collisions", ""), "eval_length_ratio": s.get("length_ratio", ""),
        "eval_spl": s.get("spl", ""), "eval_random_success": s.get("random_success", ""),
        "pool_draws": c.pool_draws, "wall_time": round(c.wall_time, 3),
    }
    if run is not None:
        run.log(row)
    return row


# ----------------------------------------------------------------------------------------
# Files


def _meta(network: QNetwork, config: TrainConfig, phases: Sequence[Phase], c: Counters, best: Optional[dict],
          updates: int) -> dict:
    first = phases[0]
    training = {"phases": [p.name for p in phases], "global_step": c.global_step, "episodes": c.episodes,
                "updates": updates, "wall_time": c.wall_time, "evaluation": best, "evaluation_step": c.best_step,
                "validation": [w.name for w in first.validation.worlds]}
    if len(phases) == 1 and len(first.worlds) == 1:
        world = first.worlds[0]
        training["world"] = {"name": world.name, "source": None if world.source is None else str(world.source)}
    return model_meta(network, first.validation.worlds[0].field, config.to_dict(), training, config.observer)


def save_best(run: Optional[RunDir], network: QNetwork, config: TrainConfig, phases: Sequence[Phase], c: Counters,
              best: dict, updates: int) -> None:
    if run is not None:
        save_model(run.best, network, _meta(network, config, phases, c, best, updates))
        run.wrote(run.best)


def save_curve(run: Optional[RunDir]) -> None:
    """Draw ``train.csv`` to ``train.png``."""
    if run is not None:
        plot_training_curve(run.csv, run.png)
        run.wrote(run.png)


def save_checkpoint(run: Optional[RunDir], config: TrainConfig, phases: Sequence[Phase], learner: Learner,
                    collector: Collector, c: Counters, rng: np.random.Generator, evals: Evaluations) -> None:
    """Write ``last.pt``: everything a resumed run needs to go on."""
    if run is None:
        return
    meta = _meta(learner.q_network, config, phases, c, evals.best, learner.updates)
    meta["kind"] = "checkpoint"
    meta["trainer"] = {"counters": dataclasses.asdict(c), "updates": learner.updates, "loss_count": learner._loss_count,
                       "best": evals.best, "latest": evals.latest, "numpy_rng": rng.bit_generator.state,
                       "collector": collector.state()}
    tensors = {**learner.tensors(buffer=config.save_buffer), "torch_rng": torch.get_rng_state()}
    if evals.best_state is not None:
        tensors["best_state"] = evals.best_state
    write_file(run.last, meta, tensors)
    run.wrote(run.last)


def load_checkpoint_config(path: str | Path) -> TrainConfig:
    """The configuration stored in a checkpoint or model file (for ``--resume``)."""
    meta, _ = read_file(path)
    return TrainConfig.from_dict(meta["config"])


def restore(run: RunDir, config: TrainConfig, phases: Sequence[Phase], learner: Learner, collector: Collector,
            c: Counters, evals: Evaluations, rng: np.random.Generator) -> None:
    """Load ``last.pt`` into the learner, collector, counters, evaluations and ``rng``."""
    if not run.last.is_file():
        raise UserError(f"{run.last}: nothing to resume (no checkpoint there)")
    meta, tensors = read_file(run.last)
    if meta.get("kind") != "checkpoint" or "trainer" not in meta:
        raise UserError(f"{run.last}: not a training checkpoint of this version")
    differ = differing_fields(TrainConfig.from_dict(meta["config"]), config)
    if differ:
        raise UserError(f"{run.last}: was trained with different options ({', '.join(differ)}); "
                        "resume with the same preset and options")
    saved_phases = meta["training"]["phases"]
    if saved_phases != [p.name for p in phases]:
        raise UserError(f"{run.last}: was trained through the phases {', '.join(saved_phases)}, "
                        f"not {', '.join(p.name for p in phases)}; resume with the same world or curriculum")
    state = meta["trainer"]
    learner.load(tensors, state["updates"], state["loss_count"])
    collector.load(state["collector"])
    for name, value in state["counters"].items():
        setattr(c, name, value)
    evals.best, evals.latest, evals.best_state = state["best"], state["latest"], tensors.get("best_state")
    rng.bit_generator.state = state["numpy_rng"]
    torch.set_rng_state(tensors["torch_rng"])


# ----------------------------------------------------------------------------------------
# Progress


class ProgressBar:
    """A tqdm bar on stderr (only when it is a terminal) measuring the stop rule that applies.

    The bar counts transitions (``total_steps``), searches (``total_episodes``, or the stages'
    ``stage_episodes``), or seconds (``time_limit``); a ``target_success`` run shows its budget and
    says it stops earlier at the target. The postfix shows ε, the recent training success and
    the latest greedy evaluation's success.
    """

    def __init__(self, config: TrainConfig, phases: Sequence[Phase], c: Counters):
        self.budgets = [p.episodes for p in phases]
        if config.total_steps is not None:
            self.measure, total, unit = "steps", config.total_steps, "step"
        elif config.total_episodes is not None:
            self.measure, total, unit = "episodes", config.total_episodes, "search"
        elif config.time_limit is not None:
            self.measure, total, unit = "seconds", config.time_limit, "s"
        elif all(b is not None for b in self.budgets):
            self.measure, total, unit = "stage_episodes", sum(self.budgets), "search"
        else:
            self.measure, total, unit = "steps", None, "step"
        self.multi = len(phases) > 1
        target = "" if config.target_success is None else f"until {config.target_success:.0%} of the validation starts"
        self.bar = tqdm(total=total, initial=self._value(c), unit=unit, desc=target or None, dynamic_ncols=True,
                        smoothing=0.05, file=sys.stderr, disable=None)  # disable=None: off unless a terminal
        self._desc = target

    def _value(self, c: Counters) -> float:
        if self.measure == "steps":
            return c.global_step
        if self.measure == "episodes":
            return c.episodes
        if self.measure == "seconds":
            return round(c.wall_time, 1)
        return sum(b for b in self.budgets[:c.phase]) + c.phase_episodes

    def update(self, c: Counters, phase: Phase, epsilon: float, latest: Optional[dict]) -> None:
        if self.bar.disable:
            return
        if self.multi:
            desc = f"{phase.name}" + (f", {self._desc}" if self._desc else "")
            if desc != self.bar.desc:
                self.bar.set_description_str(desc, refresh=False)
        self.bar.set_postfix_str(f"ε {epsilon:.2f}, eval {'-' if latest is None else format(latest['success'], '.0%')}",
                                 refresh=False)
        value = self._value(c) if self.bar.total is None else min(self._value(c), self.bar.total)
        self.bar.update(value - self.bar.n)

    def close(self) -> None:
        self.bar.close()
