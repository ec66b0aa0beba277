"""The training loop: one loop over a list of phases, for every learner.

:func:`train` takes a :class:`~apf_physics.learning.config.TrainConfig` and the phases to train
(:mod:`apf_physics.learning.phases`: one world is one phase, a curriculum several) and returns a
:class:`TrainResult`. The configuration's ``method`` picks the
:class:`~apf_physics.learning.learner.Learner`: deep Q-learning (:mod:`apf_physics.learning.dqn`) or the
map network's imitation of A* (:mod:`apf_physics.learning.imitation`). Each step the learner
collects and updates; every ``eval_every`` steps its network is run as the DQN planner through
the physics on the phase's validation set (:mod:`apf_physics.learning.validation`), and the best
evaluation so far is written to ``best.pt``.

The run goes in segments. A segment ends at a checkpoint (``last.pt``: the learner's state,
counters, random states), at the end of a phase and when the pool of generated worlds is
redrawn; every segment starts afresh (DQN: new environments seeded from ``(seed, steps so
far)``). So a run resumed from any checkpoint it wrote on its own continues exactly as the
uninterrupted run (DQN: with ``save_buffer``); a run resumed after an interrupt (Ctrl-C saves
a checkpoint where it stopped) continues from there.

A run stops at the first of its limits (:class:`~apf_physics.learning.config.ScheduleConfig`), and
as diverged when a logged mean loss is not finite or exceeds ``loss_limit``. Its targets are met by
one evaluation: ``target_success`` of the validation starts and, where the world's own starts are
evaluated beside them, ``target_world_starts`` of those; ``best.pt`` is the best evaluation that
met them (by ``select``), or the best by ``select`` if none did.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch

from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import evaluate as run_planner
from apf_physics.models.files import model_meta, read_file, save_model, write_file
from apf_physics.learning import validation
from apf_physics.learning.config import TrainConfig, differing_fields
from apf_physics.learning.dqn import DQNLearner
from apf_physics.learning.imitation import ImitationLearner
from apf_physics.learning.learner import Counters, Learner
from apf_physics.learning.phases import Phase, draw_pool
from apf_physics.learning.plot import plot_training_curve
from apf_physics.learning.progress import Progress
from apf_physics.learning.rundir import RunDir

VALIDATION_FIGURES = ("success", "trap_success", "collisions", "length_ratio", "spl")
"""Figures of an evaluation on the validation starts (``validation_*`` in ``train.csv``)."""
WORLD_STARTS_FIGURES = ("world_starts_success", "world_starts_collisions")
"""Figures of an evaluation on a world's own starts (a run on one world)."""
CSV_COLUMNS = ("global_step", "episodes", "phase", "epsilon", "mean_return", "training_success", "loss",
               *(f"validation_{name}" for name in VALIDATION_FIGURES), *WORLD_STARTS_FIGURES, "pool_draws",
               "wall_time")
"""Columns of ``train.csv``: ``training_success`` and ``mean_return`` of the recent training episodes
(ε-greedy); ``validation_*`` and ``world_starts_*``: the greedy evaluation made at that step, if any."""

LEARNERS: dict[str, type[Learner]] = {"dqn": DQNLearner, "imitation": ImitationLearner}
"""The learner of each ``method``."""


@dataclass
class Evaluations:
    """The best and the latest evaluation of a run, and the best network's weights."""

    best: Optional[dict] = None
    latest: Optional[dict] = None
    best_state: Optional[dict] = None

    def record(self, summary: dict, c: Counters, network: torch.nn.Module, config: TrainConfig) -> bool:
        """Note an evaluation made at ``c.global_step``; returns whether it is the best so far: an evaluation
        that meets the run's targets (:func:`meets_targets`) is better than one that does not, then
        ``select`` decides."""
        self.latest = summary
        c.last_eval_step = c.global_step
        if meets_world_starts_target(summary, config):
            c.top_success = max(c.top_success or 0.0, summary["success"])
        if c.time_to_target is None and meets_targets(summary, config):
            c.time_to_target = c.wall_time
        if self.best is not None and best_key(summary, config) <= best_key(self.best, config):
            return False
        self.best, c.best_step = summary, c.global_step
        self.best_state = {k: v.clone() for k, v in network.state_dict().items()}
        return True


def meets_world_starts_target(summary: dict, config: TrainConfig) -> bool:
    """Whether an evaluation succeeded from ``target_world_starts`` of the world starts; True where that target
    does not apply (none set, no world starts evaluated, or the world starts are the validation starts)."""
    target, world = config.schedule.target_world_starts, summary.get("world_starts_success")
    return target is None or world is None or not config.evaluation.eval_random_starts or world >= target


def meets_targets(summary: dict, config: TrainConfig) -> bool:
    """Whether an evaluation met the run's targets: ``target_success`` of the validation starts and, where it
    applies, ``target_world_starts`` of the world starts (False without ``target_success``)."""
    target = config.schedule.target_success
    return target is not None and summary["success"] >= target and meets_world_starts_target(summary, config)


def best_key(summary: dict, config: TrainConfig) -> tuple:
    """The sort key of an evaluation for ``best.pt``: whether it meets the targets, then ``select``'s figures."""
    return (meets_targets(summary, config), *validation.score(summary, config.evaluation.select))


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
        network: The network at the end.
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
    network: torch.nn.Module
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
        """Stopped because an evaluation met the targets (``target_success``, with ``target_world_starts``)."""
        return self.stop_reason is not None and self.stop_reason.startswith("target")

    @property
    def diverged(self) -> bool:
        """Stopped because the loss diverged."""
        return self.counters.diverged is not None


def stop_reason(config: TrainConfig, phases: Sequence[Phase], c: Counters, wall: float) -> Optional[str]:
    """Why the run must stop now (None: it goes on)."""
    s = config.schedule
    if c.diverged is not None:
        return (f"diverged: the mean loss reached {c.diverged:.3g}"
                + ("" if s.loss_limit is None or not math.isfinite(c.diverged) else f" (over loss_limit {s.loss_limit:g})")
                + "; lower learning_rate, or use loss=huber, reward_scale=1e-3 and max_grad_norm=10 as the fast "
                  "preset does")
    if c.phase >= len(phases):
        return "every phase finished"
    if s.total_steps is not None and c.global_step >= s.total_steps:
        return f"total_steps {s.total_steps} reached"
    if s.total_episodes is not None and c.episodes >= s.total_episodes:
        return f"total_episodes {s.total_episodes} reached"
    if s.time_limit is not None and wall >= s.time_limit:
        return f"time_limit {s.time_limit:g} s reached"
    if s.target_success is not None and c.top_success is not None and c.top_success >= s.target_success:
        reason = f"target_success {s.target_success:g} of the validation starts reached"
        if s.target_world_starts is not None and world_starts_apart(config, phases[min(c.phase, len(phases) - 1)]):
            reason += f" with target_world_starts {s.target_world_starts:g} of the world starts"
        return reason
    return None


def world_starts_apart(config: TrainConfig, phase: Phase) -> bool:
    """Whether the phase's world starts are evaluated beside its validation starts (and not as them)."""
    return bool(config.evaluation.eval_random_starts) and phase.world_starts is not None \
        and phase.world_starts is not phase.validation


def next_multiple(value: int, every: int) -> int:
    return (value // every + 1) * every


def train(config: TrainConfig, phases: Sequence[Phase], out_dir: str | Path | RunDir | None = None,
          resume: bool = False, progress: bool = False) -> TrainResult:
    """Train the configuration's network through ``phases`` with its ``method``'s learner.

    Args:
        config: The configuration (:func:`~apf_physics.learning.config.preset`).
        phases: What to train on, in order (:func:`~apf_physics.learning.phases.phases_for_world`,
            :func:`~apf_physics.learning.phases.phases_for_curriculum`).
        out_dir: Folder for ``best.pt`` (the best evaluation's network: the one to use),
            ``last.pt`` (the training state), ``train.csv`` and ``train.png``; created if
            missing and locked while training (:class:`~apf_physics.learning.rundir.RunDir`; an open
            one is used as it is and left open). None: write nothing.
        resume: Continue from ``out_dir/last.pt`` (same configuration except
            :data:`~apf_physics.learning.config.RESUMABLE` options, same phases). If that run has
            already stopped by its rules, nothing is trained or written
            (:attr:`TrainResult.already_finished`).
        progress: Show progress on stderr: a bar on a terminal, else a line per row of ``train.csv``.

    Returns:
        The result. KeyboardInterrupt is raised again after a checkpoint is saved.

    Raises:
        UserError: Nothing to train, worlds of different fields, a folder locked by another run
            or holding a run already (without ``resume``), or ``resume`` without a usable checkpoint.
    """
    check_phases(phases)
    if resume and out_dir is None:
        raise UserError("resuming needs the output folder of the run to continue")
    given = isinstance(out_dir, RunDir)
    run = out_dir if given else RunDir(out_dir, CSV_COLUMNS) if out_dir is not None else None
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(config.run.threads)
    try:
        if run is not None and not resume and run.last.exists():
            raise UserError(f"{run.path} already holds a training run; resume it or train into another folder")
        return _train(config, list(phases), run, resume, progress)
    finally:
        torch.set_num_threads(previous_threads)
        if run is not None and not given:
            run.close()


def check_phases(phases: Sequence[Phase]) -> None:
    """Refuse phases that cannot be trained: none, or worlds of different fields (one model serves one field).

    Raises:
        UserError: Saying which.
    """
    if not phases:
        raise UserError("nothing to train: no phases")
    fields = {tuple(w.field.as_dict().items()) for p in phases for w in (*p.worlds, *p.validation.worlds)}
    if len(fields) != 1:
        raise UserError("a model is trained for one field, but these worlds have different field parameters")


def _train(config: TrainConfig, phases: list[Phase], run: Optional[RunDir], resume: bool,
           progress: bool) -> TrainResult:
    rng = np.random.default_rng(config.run.seed)  # every draw of the learner: exploration, minibatches, positions
    torch.manual_seed(config.run.seed)
    learner = LEARNERS[config.method](config)
    c, evals = Counters(), Evaluations()
    if resume:
        restore(run, config, phases, learner, c, evals, rng)
        reason = stop_reason(config, phases, c, c.wall_time)
        if reason is not None:
            return TrainResult(config, c, learner.updates, evals.best, evals.latest, reason, True, run.path, [],
                               learner.network, evals.best_state)
    if run is not None:
        run.start_log(c.global_step if resume else None)
    every = config.evaluation.eval_every, config.run.log_every, config.run.checkpoint_every
    next_eval, next_log, next_checkpoint = (next_multiple(c.global_step, n) for n in every)
    history: list[dict] = []
    shown = Progress(config, phases, c) if progress else None
    elapsed_before, start = c.wall_time, time.perf_counter()
    reason = None
    try:
        while reason is None:
            phase = phases[c.phase]
            worlds = list(phase.worlds) + (draw_pool(config, c.pool_draws) if phase.pool else [])
            next_refresh = next_multiple(c.phase_steps, config.schedule.refresh_every) if phase.pool else None
            learner.begin(worlds, phase, seed=(config.run.seed, c.global_step))
            while True:
                c.advance(*learner.collect(c, rng))
                learner.update(c, rng)
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
                    next_eval = next_multiple(c.global_step, config.evaluation.eval_every)
                    summary = evaluate(learner, config, phase)
                    c.wall_time = elapsed_before + time.perf_counter() - start
                    if evals.record(summary, c, learner.network, config):
                        save_best(run, learner, config, phases, c, evals.best)
                if summary is not None or c.global_step >= next_log:
                    next_log = next_multiple(c.global_step, config.run.log_every)
                    history.append(log_row(run, config, c, phase, learner, summary, shown, evals.latest))
                if shown is not None:
                    shown.update(c, phase, learner.epsilon, evals.latest)
                reason = stop_reason(config, phases, c, c.wall_time)
                if reason is not None or phase_over or redraw or c.global_step >= next_checkpoint:
                    break
            learner.end()
            if reason is None:  # a segment ends at a checkpoint
                save_checkpoint(run, config, phases, learner, c, rng, evals)
                save_curve(run)
                next_checkpoint = next_multiple(c.global_step, config.run.checkpoint_every)
        if c.last_eval_step != c.global_step and c.diverged is None:  # the end of the run may be the best
            phase = phases[min(c.phase, len(phases) - 1)]
            summary = evaluate(learner, config, phase)
            if evals.record(summary, c, learner.network, config):
                save_best(run, learner, config, phases, c, evals.best)
            history.append(log_row(run, config, c, phase, learner, summary, shown, evals.latest))
            if shown is not None:
                shown.update(c, phase, learner.epsilon, evals.latest)
        c.wall_time = elapsed_before + time.perf_counter() - start
        save_checkpoint(run, config, phases, learner, c, rng, evals)
    except KeyboardInterrupt:
        c.wall_time = elapsed_before + time.perf_counter() - start
        save_checkpoint(run, config, phases, learner, c, rng, evals)
        raise
    finally:
        if shown is not None:
            shown.close()
    save_curve(run)
    return TrainResult(config, c, learner.updates, evals.best, evals.latest, reason, False,
                       None if run is None else run.path, [] if run is None else list(run.written),
                       learner.network, evals.best_state, history)


def evaluate(learner: Learner, config: TrainConfig, phase: Phase) -> dict[str, Optional[float]]:
    """The figures of the learner's network on the phase's validation starts (and its world starts),
    run as ``apf-physics eval --planner dqn`` runs it."""
    shield, network = config.evaluation.eval_shield, learner.network
    was_training = network.training
    try:
        summary = validation.summarise(run_planner(learner.planner(shield), phase.validation.worlds).episodes,
                                       phase.validation)
        if phase.world_starts is not None:
            world = summary if phase.world_starts is phase.validation else validation.summarise(
                run_planner(learner.planner(shield), phase.world_starts.worlds).episodes, phase.world_starts)
            summary["world_starts_success"], summary["world_starts_collisions"] = world["success"], world["collisions"]
    finally:
        network.train(was_training)
    return summary


def log_row(run: Optional[RunDir], config: TrainConfig, c: Counters, phase: Phase, learner: Learner,
            summary: Optional[dict], shown: Optional[Progress] = None, latest: Optional[dict] = None) -> dict:
    """A row of ``train.csv``, written if there is a folder and shown as a line without a terminal; notes a
    diverged loss in the counters."""
    values = learner.log_values(c)
    loss = values["loss"]
    limit = config.schedule.loss_limit
    if loss is not None and (not math.isfinite(loss) or (limit is not None and loss > limit)):
        c.diverged = loss
    s = {k: "" if v is None else round(v, 4) for k, v in (summary or {}).items()}
    row = {
        "global_step": c.global_step, "episodes": c.episodes, "phase": phase.name, "epsilon": values["epsilon"],
        "mean_return": values["mean_return"], "training_success": values["training_success"],
        "loss": "" if loss is None else round(loss, 6),
        **{f"validation_{name}": s.get(name, "") for name in VALIDATION_FIGURES},
        **{name: s.get(name, "") for name in WORLD_STARTS_FIGURES},
        "pool_draws": c.pool_draws, "wall_time": round(c.wall_time, 3),
    }
    if run is not None:
        run.log(row)
    if shown is not None:
        shown.line(row, latest, c.phase)
    return row


# ----------------------------------------------------------------------------------------
# Files


def _meta(learner: Learner, config: TrainConfig, phases: Sequence[Phase], c: Counters, best: Optional[dict]) -> dict:
    first = phases[0]
    training = {"phases": [p.name for p in phases], "global_step": c.global_step, "episodes": c.episodes,
                "updates": learner.updates, "wall_time": c.wall_time, "evaluation": best,
                "evaluation_step": c.best_step, "validation": [w.name for w in first.validation.worlds]}
    if len(phases) == 1 and len(first.worlds) == 1:
        world = first.worlds[0]
        training["world"] = {"name": world.name, "source": None if world.source is None else str(world.source)}
    return model_meta(learner.network, first.validation.worlds[0].field, config.to_dict(), training, learner.observer)


def save_best(run: Optional[RunDir], learner: Learner, config: TrainConfig, phases: Sequence[Phase], c: Counters,
              best: dict) -> None:
    if run is not None:
        save_model(run.best, learner.network, _meta(learner, config, phases, c, best))
        run.wrote(run.best)


def save_curve(run: Optional[RunDir]) -> None:
    """Draw ``train.csv`` to ``train.png``."""
    if run is not None:
        plot_training_curve(run.csv, run.png)
        run.wrote(run.png)


def save_checkpoint(run: Optional[RunDir], config: TrainConfig, phases: Sequence[Phase], learner: Learner,
                    c: Counters, rng: np.random.Generator, evals: Evaluations) -> None:
    """Write ``last.pt`` (atomically): everything a resumed run needs to go on."""
    if run is None:
        return
    state, tensors = learner.state(with_buffer=config.run.save_buffer)
    meta = _meta(learner, config, phases, c, evals.best)
    meta["kind"] = "checkpoint"
    meta["trainer"] = {"method": config.method, "counters": dataclasses.asdict(c), "learner": state,
                       "best": evals.best, "latest": evals.latest, "numpy_rng": rng.bit_generator.state}
    tensors = {**tensors, "torch_rng": torch.get_rng_state()}
    if evals.best_state is not None:
        tensors["best_state"] = evals.best_state
    write_file(run.last, meta, tensors)
    run.wrote(run.last)


def load_checkpoint_config(path: str | Path) -> TrainConfig:
    """The configuration stored in a checkpoint or model file (for ``--resume``)."""
    meta, _ = read_file(path)
    try:
        return TrainConfig.from_dict(meta["config"])
    except UserError as error:
        raise UserError(f"{path}: {error}") from None


def restore(run: RunDir, config: TrainConfig, phases: Sequence[Phase], learner: Learner, c: Counters,
            evals: Evaluations, rng: np.random.Generator) -> None:
    """Load ``last.pt`` into the learner, counters, evaluations and ``rng``."""
    if not run.last.is_file():
        raise UserError(f"{run.last}: nothing to resume (no checkpoint there)")
    meta, tensors = read_file(run.last)
    if meta.get("kind") != "checkpoint" or "learner" not in meta.get("trainer", {}):
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
    learner.load(state["learner"], tensors)
    for name, value in state["counters"].items():
        setattr(c, name, value)
    evals.best, evals.latest, evals.best_state = state["best"], state["latest"], tensors.get("best_state")
    rng.bit_generator.state = state["numpy_rng"]
    torch.set_rng_state(tensors["torch_rng"])
