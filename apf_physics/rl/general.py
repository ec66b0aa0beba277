"""General-field learning: curriculum with rehearsal, and domain randomisation (SPEC §2, thesis §6.3).

One Q-network is trained for every world of the ``thesis-general`` field, not for one map.
Two presets (:func:`general_preset`):

- ``thesis-general``: the thesis as written (Table 4: 9×9 window, filters 4/4, m = 7, MSE,
  no target network, γ = 0.95, raw observations, one environment, searches from the worlds'
  own starts) trained through the curriculum file's stages, 150 searches per stage, ε decaying
  anew over each stage's 150 searches. Stage ``i`` trains its worlds together with every
  earlier stage's worlds, one drawn at random per search (rehearsal).
- ``general``: domain randomisation. A pool of worlds freshly drawn with
  :func:`apf_physics.generate.generate_world` over all families, redrawn every
  ``refresh_every`` transitions, plus every world of the curriculum file, learned with the
  ``fast`` recipe of :mod:`apf_physics.rl.dqn` (the thesis-fixed network on an 11×11 window,
  signed-log relative observations, double DQN, Huber loss, soft target network, rewards
  scaled by 1/1000, starts drawn over all free positions) with 32 parallel environments, a
  quarter of them starting at the worlds' own starts behind their obstacles, and searches of
  up to 200 moves. Its rewards are Table 3's weights (W1 = −1000, W2 = 1000, W3 = −1,
  β = −4): with Table 4's (β = −20, W2 = 10) the potential term is hundreds of times the
  target reward in a 50×50 field, and because W4 = β·(U' − U) is not discounted like a
  potential-based shaping term (β·(γU' − U)), stepping down and back up again can pay more
  than reaching the target; a run with Table 4's weights reached no validation target in
  700,000 transitions (and one with γ = 0.99 and a 13×13 window diverged).
- ``general-memory``: ``general`` with a second observation channel, the robot's visit memory
  (``NavigateVectorEnv(memory=True)``, :class:`~apf_physics.observation.VisitMemory`), passed
  through the network untransformed (``obs_transform="relative-log-memory"``), and half of
  the environments (not a quarter) starting at the worlds' own starts, behind their
  obstacles where gradient descent gets trapped. A reactive policy on the potential alone
  cannot tell a well it has just left from one it has not tried; the memory can.
- ``general-revisit`` (recommended; the shipped ``general.pt``): ``general-memory`` with the
  reward preset ``"general"`` (:mod:`apf_physics.envs.reward`): Table 3's weights plus a
  revisit term (W5 = −50 per earlier visit of the cell entered, up to 4) and a length term
  (W6 = −40 per unit moved). With W4 alone, pacing in a well costs next to nothing (each step
  down pays back the step up) while climbing out costs at once, so the greedy policy learns to
  pace; W5 makes pacing cost. W3 charges a diagonal move like an axis move, so zigzagging on
  diagonals costs no more steps than going straight; W6 prefers the shorter path.

All keep the network with the best greedy evaluation on a fixed validation set of generated
worlds (``validation_seed``; it must differ from the held-out test seed, 100) in ``best.pt``:
fewest collisions, then the highest SPL (success weighted by path length), each episode run
as ``apf-physics eval --planner dqn`` runs it (through the physics, shielded). The full
training state goes to ``last.pt`` (resumable) and the log to ``train.csv``.

Usage::

    from apf_physics.rl.general import general_preset, train_general

    config = general_preset("general-revisit", seed=0, time_limit=1500)
    result = train_general(config, curriculum="worlds/curricula/thesis.yaml", out_dir="runs/general")
    print(result.best_validation)           # the best validation summary; the network is in best.pt

    # what `apf-physics train --curriculum FILE [--preset P] --out DIR [--resume]` runs
    run_curriculum_command("worlds/curricula/thesis.yaml", "thesis-general", "runs/thesis", seed=0)
"""

from __future__ import annotations

import csv
import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import torch

from apf_physics.curriculum import Stage, load_curriculum
from apf_physics.errors import UserError
from apf_physics.generate import FAMILIES, generate_world
from apf_physics.models.files import model_meta, read_file, save_model, write_file
from apf_physics.rl.dqn import Collector, DQNConfig, Learner, epsilon_schedule, start_csv
from apf_physics.rl.dqn import preset as dqn_preset
from apf_physics.world import World

N_ACTIONS = 9
HELDOUT_SEED = 100
"""Seed of the project's held-out generated test set; training and validation never use it."""
POOL_STREAM = 0x9E11
"""Tag mixed into the seed of every training-pool draw, so no pool equals a set drawn from an integer seed."""
CSV_COLUMNS = ("global_step", "episodes", "stage", "epsilon", "mean_return", "success_rate", "loss",
               "val_success", "val_trap_success", "val_length_ratio", "val_spl", "pool_draws", "wall_time")
"""Columns of ``train.csv``."""
STOP_FIELDS = {"total_steps", "time_limit", "eval_every", "log_every", "checkpoint_every", "threads"}
"""Fields that may change when resuming."""


@dataclass(frozen=True)
class GeneralConfig:
    """A general training run: the learner (:class:`DQNConfig`) and what it is trained on.

    The learner's own stopping and evaluation fields (``total_episodes``, ``total_steps``,
    ``eval_every``, ...) are not used; the fields below replace them.
    """

    preset: str = "custom"
    """Name of the preset this configuration started from (informational)."""
    dqn: DQNConfig = field(default_factory=lambda: dqn_preset("thesis-general"))
    """Network, environment options, learning rule and ε schedule."""

    # --- curriculum (SPEC §2: stage i trains its worlds with all earlier stages' worlds) ---
    stage_episodes: Optional[int] = None
    """Searches per curriculum stage (the thesis: 150). None with ``stage_steps`` None: the stages are
    not trained one by one; their worlds only join the randomised pool."""
    stage_steps: Optional[int] = None
    """Transitions per curriculum stage (alternative to ``stage_episodes``)."""
    restart_exploration: bool = True
    """Start the ε schedule again at every stage (the thesis: ε decays over each stage's searches)."""

    # --- domain randomisation (after the stages) ---
    families: tuple[str, ...] = ()
    """Generator families of the randomised pool; empty: no randomised phase."""
    pool_size: int = 80
    """Generated worlds in the pool at a time."""
    pool_starts: int = 6
    """Starts per generated world (behind its obstacles, where gradient descent gets trapped)."""
    refresh_every: int = 500_000
    """Transitions between redraws of the pool."""
    world_start_fraction: float = 0.0
    """Share of the environments whose searches begin at the worlds' own starts; the others use
    ``dqn.train_starts``."""
    memory: bool = False
    """Give the network a second observation channel, the robot's visit memory
    (``NavigateVectorEnv(memory=True)``); needs ``dqn.obs_transform`` ``"relative-log-memory"``
    or ``"raw"``."""
    total_steps: Optional[int] = None
    """Stop after this many transitions in all (None: no limit)."""
    time_limit: Optional[float] = None
    """Stop after this many seconds of training over all resumed sessions (None: no limit)."""

    # --- validation (keeps the best network) ---
    validation_worlds: int = 30
    """Generated worlds of the validation set (families in turn)."""
    validation_starts: int = 4
    """Starts per validation world."""
    validation_seed: int = 1
    """Seed of the validation set; must not be :data:`HELDOUT_SEED`."""
    eval_every: int = 100_000
    """Transitions between greedy evaluations on the validation set."""
    log_every: int = 20_000
    """Transitions between rows of ``train.csv``."""
    checkpoint_every: int = 200_000
    """Transitions between ``last.pt`` checkpoints."""

    def __post_init__(self):
        checks = [
            (self.validation_seed != HELDOUT_SEED, f"validation_seed must not be the held-out seed {HELDOUT_SEED}"),
            (all(f in FAMILIES for f in self.families), f"families must be among {', '.join(FAMILIES)}"),
            (0.0 <= self.world_start_fraction <= 1.0, "world_start_fraction must be in [0, 1]"),
            (min(self.pool_size, self.pool_starts, self.refresh_every, self.validation_worlds,
                 self.validation_starts, self.eval_every, self.log_every, self.checkpoint_every) >= 1,
             "sizes and intervals must be positive"),
            (not self.memory or self.dqn.obs_transform in ("raw", "relative-log-memory"),
             "memory needs obs_transform 'relative-log-memory' (or 'raw')"),
            (not self.families or self.total_steps is not None or self.time_limit is not None,
             "a randomised phase needs total_steps or time_limit"),
        ]
        for ok, message in checks:
            if not ok:
                raise UserError(f"invalid general training configuration: {message}")

    def to_dict(self) -> dict[str, Any]:
        """Plain values (the learner's as a nested dict), for JSON."""
        data = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "dqn"}
        data = {k: list(v) if isinstance(v, tuple) else v for k, v in data.items()}
        return {**data, "dqn": self.dqn.to_dict()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "GeneralConfig":
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        learner = DQNConfig.from_dict(data.pop("dqn"))
        return _replace(cls(dqn=learner), data)


PRESETS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    # name: (learner preset, learner overrides, GeneralConfig overrides)
    "thesis-general": ("thesis-general", dict(total_episodes=None, total_steps=None, target_success=1.0),
                       dict(stage_episodes=150, restart_exploration=True, eval_every=5_000, log_every=2_000,
                            checkpoint_every=20_000)),
    "general": ("fast", dict(
        train_starts="random", obs_size=11, reward="thesis-fixed", max_episode_steps=200, gamma=0.95,
        learning_rate=1e-3, buffer_size=300_000, learning_starts=10_000,
        num_envs=32, batch_size=128, reward_scale=1e-3, exploration_episodes=12_000, epsilon_final=0.03,
        total_steps=None, target_success=1.0,
    ), dict(
        families=FAMILIES, pool_size=80, pool_starts=6, refresh_every=500_000, world_start_fraction=0.25,
        time_limit=1500.0, eval_every=150_000, log_every=25_000, checkpoint_every=150_000,
    )),
}
PRESETS["general-memory"] = (PRESETS["general"][0], {**PRESETS["general"][1], "obs_transform": "relative-log-memory"},
                             {**PRESETS["general"][2], "memory": True, "world_start_fraction": 0.5})
PRESETS["general-revisit"] = (PRESETS["general-memory"][0], {**PRESETS["general-memory"][1], "reward": "general"},
                              PRESETS["general-memory"][2])
"""Presets: the learner preset of :mod:`apf_physics.rl.dqn` they start from and the changes."""
DEFAULT_PRESET = "general-revisit"
"""What ``apf-physics train --curriculum FILE`` trains without ``--preset``: the shipped model's recipe."""


def _replace(config: GeneralConfig, overrides: dict[str, Any]) -> GeneralConfig:
    """Apply overrides; keys of :class:`DQNConfig` go to the learner, unknown keys are an error."""
    mine = {f.name for f in dataclasses.fields(GeneralConfig)} - {"dqn"}
    learner_names = {f.name for f in dataclasses.fields(DQNConfig)}
    unknown = sorted(set(overrides) - mine - learner_names)
    if unknown:
        raise UserError(f"unknown training option(s) {', '.join(unknown)}")
    learner = {k: v for k, v in overrides.items() if k not in mine}
    own = {k: (tuple(v) if isinstance(v, list) else v) for k, v in overrides.items() if k in mine}
    for key in ("time_limit",):
        if isinstance(own.get(key), int):
            own[key] = float(own[key])
    dqn = dqn_preset(config.dqn.preset, **{**config.dqn.to_dict(), **learner}) if learner else config.dqn
    return dataclasses.replace(config, dqn=dqn, **own)


def general_preset(name: str, **overrides: Any) -> GeneralConfig:
    """A named general-training configuration with some fields changed.

    Args:
        name: ``"thesis-general"``, ``"general"``, ``"general-memory"`` or ``"general-revisit"``.
        **overrides: Fields of :class:`GeneralConfig` or of its learner (:class:`DQNConfig`),
            e.g. ``seed=1``, ``time_limit=600``, ``gamma=0.95``.

    Raises:
        UserError: Unknown preset or field, or an invalid value.
    """
    if name not in PRESETS:
        raise UserError(f"unknown general training preset {name!r}; choose one of {', '.join(PRESETS)}")
    learner_preset, learner, own = PRESETS[name]
    config = GeneralConfig(preset=name, dqn=dqn_preset(learner_preset, **learner), **own)
    return _replace(config, overrides)


# ----------------------------------------------------------------------------------------
# What is trained when


@dataclass(frozen=True)
class Phase:
    """One phase of training.

    Attributes:
        name: Stage name, or ``"randomised"`` for the domain-randomisation phase.
        worlds: Fixed worlds trained in this phase (a stage's rehearsal set).
        episodes: Searches in this phase (None: no limit of that kind).
        steps: Transitions in this phase (None: no limit of that kind; the last phase
            runs to the run's ``total_steps`` / ``time_limit``).
        randomised: Whether a generated pool joins ``worlds``.
    """

    name: str
    worlds: tuple[World, ...]
    episodes: Optional[int]
    steps: Optional[int]
    randomised: bool = False


def training_phases(stages: Sequence[Stage], config: GeneralConfig) -> list[Phase]:
    """The phases of a run: one per curriculum stage (with rehearsal), then the randomised one.

    Stage ``i``'s phase trains ``stages[i].training_worlds``: its own worlds and every
    earlier stage's (SPEC §2). With ``config.families`` a last phase trains a generated pool
    together with all the curriculum's worlds until the run stops.

    Raises:
        UserError: Nothing to train (no stages and no families).
    """
    phases: list[Phase] = []
    staged = config.stage_episodes is not None or config.stage_steps is not None
    if staged:
        for stage in stages:
            phases.append(Phase(stage.name, tuple(stage.training_worlds), config.stage_episodes, config.stage_steps))
    if config.families:
        everything = tuple(stages[-1].training_worlds) if stages else ()
        phases.append(Phase("randomised", everything, None, None, randomised=True))
    elif phases:  # the last stage runs on to the run's limit, if it has one
        last = phases[-1]
        if config.total_steps is not None or config.time_limit is not None:
            phases[-1] = dataclasses.replace(last, episodes=None, steps=None)
    if not phases:
        raise UserError("nothing to train: give a curriculum with stage_episodes/stage_steps, or families")
    return phases


def draw_pool(config: GeneralConfig, draw: int, size: float = 50) -> list[World]:
    """The ``draw``-th generated training pool (deterministic in the seed and ``draw``).

    Its generator is seeded with ``[POOL_STREAM, seed, draw]``, a sequence, so it never
    coincides with a set generated from an integer seed (the held-out or validation set).
    """
    rng = np.random.default_rng([POOL_STREAM, config.dqn.seed, draw])
    fams = config.families
    return [generate_world(fams[k % len(fams)], rng, size=size, n_starts=config.pool_starts,
                           name=f"pool{draw}_{fams[k % len(fams)]}_{k}") for k in range(config.pool_size)]


@dataclass(frozen=True)
class ValidationSet:
    """Generated worlds and per-start labels used to pick the best network.

    Attributes:
        worlds: The worlds (their starts are the evaluation starts).
        trapped: Per world, (S,) bool: gradient descent does not reach the target from the start.
        astar: Per world, (S,) float: A* path length from the start.
    """

    worlds: tuple[World, ...]
    trapped: tuple[np.ndarray, ...]
    astar: tuple[np.ndarray, ...]


def validation_set(config: GeneralConfig) -> ValidationSet:
    """Draw the validation worlds from ``validation_seed`` (all families in turn) and label them."""
    from apf_physics.generate import label_starts

    rng = np.random.default_rng(config.validation_seed)
    worlds, trapped, astar = [], [], []
    for k in range(config.validation_worlds):
        fam = FAMILIES[k % len(FAMILIES)]
        world = generate_world(fam, rng, n_starts=config.validation_starts, name=f"val_{fam}_{k}")
        labels = label_starts(world)
        worlds.append(world)
        trapped.append(np.array([s["gradient_trapped"] for s in labels]))
        astar.append(np.array([s["astar_length"] or np.nan for s in labels], float))
    return ValidationSet(tuple(worlds), tuple(trapped), tuple(astar))


def validate(network: torch.nn.Module, validation: ValidationSet) -> dict[str, float]:
    """Greedy rollouts (through the physics, as ``apf-physics eval``) from every validation start.

    Returns:
        ``success`` (share of starts reaching the target), ``trap_success`` (the same over the
        starts where gradient descent is trapped), ``collisions`` (count) and ``length_ratio``
        (mean path length over the mean A* length, both on the successes, as
        ``tools/eval_general.py`` reports it; inf without successes) and ``spl``, success
        weighted by path length (Anderson et al. 2018: the mean over all starts of
        ``A* length / max(path length, A* length)`` for a success and 0 otherwise), one
        figure for reaching the target by short paths.
    """
    from apf_physics.planners.dqn import DQNPlanner
    from apf_physics.models.policy import DQNPolicy
    from apf_physics.rollout import rollout

    was_training = network.training
    planner = DQNPlanner(policy=DQNPolicy(network))  # as `apf-physics eval --planner dqn` runs it
    success, trapped, lengths, spl, collisions = [], [], [], [], 0
    try:
        for world, trap, astar in zip(validation.worlds, validation.trapped, validation.astar):
            for episode, t, a in zip(rollout(world, planner, world.starts), trap, astar):
                success.append(episode.success)
                trapped.append(t)
                collisions += episode.outcome == "collision"
                efficient = episode.success and np.isfinite(a) and a > 0
                if efficient:
                    lengths.append((episode.path_length, a))
                spl.append(a / max(episode.path_length, a) if efficient else float(episode.success))
    finally:
        network.train(was_training)
    success, trapped = np.array(success), np.array(trapped)
    return {
        "success": float(success.mean()),
        "trap_success": float(success[trapped].mean()) if trapped.any() else float("nan"),
        "collisions": int(collisions),
        "length_ratio": float(np.divide(*np.sum(lengths, axis=0))) if lengths else float("inf"),
        "spl": float(np.mean(spl)),
    }


def _score(summary: dict[str, float]) -> tuple:
    """Order of validation summaries: fewer collisions, then higher SPL (success weighted by path length)."""
    return (-summary["collisions"], round(summary.get("spl", summary["success"]), 6), summary["success"])


# ----------------------------------------------------------------------------------------
# Environments


class _Envs:
    """One or two :class:`~apf_physics.envs.NavigateVectorEnv` stepped as one batch: the first
    starts as ``dqn.train_starts`` says, the second (``world_start_fraction``) at the worlds' starts."""

    def __init__(self, worlds: Sequence[World], config: GeneralConfig, seed: int):
        from apf_physics.envs import NavigateVectorEnv

        d = config.dqn
        n_world = int(round(config.world_start_fraction * d.num_envs))
        sizes = [(d.train_starts, d.num_envs - n_world), ("world", n_world)]
        self.envs = [NavigateVectorEnv(world=list(worlds), num_envs=n, starts=s, obs_size=d.obs_size,
                                       reward=d.reward, max_episode_steps=d.max_episode_steps,
                                       memory=config.memory)
                     for s, n in sizes if n > 0]
        self.seed = seed
        self.num_envs = d.num_envs

    def reset(self) -> np.ndarray:
        obs, offset = [], 0
        for env in self.envs:
            obs.append(env.reset(seed=self.seed + offset)[0])
            offset += env.num_envs
        return np.concatenate(obs)

    def step(self, actions: np.ndarray):
        out, offset = [], 0
        for env in self.envs:
            obs, reward, terminated, truncated, info = env.step(actions[offset:offset + env.num_envs])
            out.append((obs, reward, terminated, truncated, info["success"]))
            offset += env.num_envs
        return tuple(np.concatenate(parts) for parts in zip(*out))

    def close(self) -> None:
        for env in self.envs:
            env.close()


# ----------------------------------------------------------------------------------------
# Training


@dataclass
class GeneralResult:
    """What a general training run did.

    Attributes:
        config: The configuration.
        global_step: Transitions collected.
        episodes: Searches finished.
        updates: Gradient updates.
        wall_time: Seconds of training over all resumed sessions.
        phase: Index of the phase reached (``len(phases)`` when all finished).
        best_validation: Validation summary of the best network (None: never evaluated).
        best_step: Transition count at that evaluation.
        out_dir: Directory with ``best.pt``, ``last.pt``, ``train.csv`` (None: nothing written).
        network: The online network at the end.
        best_state: State dict of the best network (None: never evaluated).
        history: Rows of ``train.csv`` written in this session.
    """

    config: GeneralConfig
    global_step: int
    episodes: int
    updates: int
    wall_time: float
    phase: int
    best_validation: Optional[dict]
    best_step: Optional[int]
    out_dir: Optional[Path]
    network: torch.nn.Module
    best_state: Optional[dict]
    history: list = field(default_factory=list)


def train_general(
    config: GeneralConfig,
    curriculum: str | os.PathLike | Sequence[Stage] | None = None,
    out_dir: str | os.PathLike | None = None,
    seed: Optional[int] = None,
    resume: bool = False,
    progress: bool = False,
) -> GeneralResult:
    """Train one Q-network for the general field: curriculum stages, then domain randomisation.

    Args:
        config: The configuration (see :func:`general_preset`).
        curriculum: A curriculum file (or its loaded stages); None: only the randomised phase.
        out_dir: Directory for ``best.pt`` (best validation), ``last.pt`` (training state)
            and ``train.csv``; created if missing. None: write nothing.
        seed: Overrides ``config.dqn.seed``.
        resume: Continue from ``out_dir/last.pt`` (same configuration except the stopping
            and logging fields).
        progress: Print a line at every evaluation.

    Returns:
        The result.

    Raises:
        UserError: Unusable curriculum, configuration or checkpoint.
    """
    if seed is not None:
        config = _replace(config, {"seed": int(seed)})
    if curriculum is None:
        stages: list[Stage] = []
    elif isinstance(curriculum, (str, os.PathLike)):
        stages = load_curriculum(curriculum)
    else:
        stages = list(curriculum)
    phases = training_phases(stages, config)
    out = Path(out_dir) if out_dir is not None else None
    if resume and out is None:
        raise UserError("resuming needs the output directory of the run to continue")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(config.dqn.threads)
    try:
        return _train(config, phases, out, resume, progress)
    finally:
        torch.set_num_threads(previous_threads)


def _train(config: GeneralConfig, phases: list[Phase], out: Optional[Path], resume: bool,
           progress: bool) -> GeneralResult:
    d = config.dqn
    rng = np.random.default_rng(d.seed)  # ε-greedy and minibatch sampling
    torch.manual_seed(d.seed)
    channels = 2 if config.memory else 1
    obs_shape = (channels, d.obs_size, d.obs_size)
    learner = Learner(d, obs_shape)
    q_network = learner.q_network
    validation = validation_set(config)
    field_params = (phases[0].worlds[0] if phases[0].worlds else validation.worlds[0]).field

    # Counters, restored on resume.
    c = dict(global_step=0, episodes=0, phase=0, phase_steps=0, phase_episodes=0, pool_draws=0,
             wall_time=0.0, best_step=None)
    best_validation: Optional[dict] = None
    best_state: Optional[dict] = None
    csv_path = out / "train.csv" if out is not None else None
    if resume:
        last = out / "last.pt"
        meta, tensors = read_file(last)
        if meta.get("kind") != "checkpoint" or "general" not in meta:
            raise UserError(f"{last}: not a general training checkpoint")
        saved = GeneralConfig.from_dict(meta["config"])
        differ = [k for k, v in saved.to_dict().items() if k not in STOP_FIELDS and v != config.to_dict()[k]]
        differ += [f"dqn.{k}" for k, v in saved.dqn.to_dict().items()
                   if k not in STOP_FIELDS and v != d.to_dict()[k]]
        if differ:
            raise UserError(f"{last}: was trained with different options ({', '.join(differ)}); "
                            "resume with the same preset and options")
        counters = dict(meta["general"]["counters"])
        learner.load(tensors, counters.pop("updates"))
        c.update(counters)
        best_validation = meta["general"]["best_validation"]
        best_state = tensors.get("best_state")
        rng.bit_generator.state = meta["general"]["numpy_rng"]
        torch.set_rng_state(tensors["torch_rng"])
    start_csv(csv_path, CSV_COLUMNS, c["global_step"] if resume else None)

    start_time = time.perf_counter()
    elapsed_before = float(c["wall_time"])
    history: list[dict] = []
    collector = Collector(learner, d.reward_scale, window=200)

    def wall() -> float:
        return elapsed_before + time.perf_counter() - start_time

    def run_finished() -> bool:
        return ((config.total_steps is not None and c["global_step"] >= config.total_steps)
                or (config.time_limit is not None and wall() >= config.time_limit))

    def training_meta() -> dict:
        return {"curriculum": [p.name for p in phases], "global_step": c["global_step"], "episodes": c["episodes"],
                "updates": learner.updates, "wall_time": wall(), "validation": best_validation,
                "validation_step": c["best_step"], "validation_seed": config.validation_seed}

    def save_checkpoint() -> None:
        if out is None:
            return
        c["wall_time"] = wall()
        meta = model_meta(q_network, field_params, config.to_dict(), training_meta())
        meta["kind"] = "checkpoint"
        meta["general"] = {"counters": {**c, "updates": learner.updates}, "best_validation": best_validation,
                           "numpy_rng": rng.bit_generator.state}
        tensors = {**learner.tensors(), "torch_rng": torch.get_rng_state()}
        if best_state is not None:
            tensors["best_state"] = best_state
        write_file(out / "last.pt", meta, tensors)

    def evaluate_and_log(epsilon: float, evaluate: bool) -> None:
        nonlocal best_validation, best_state
        summary = None
        if evaluate:
            summary = validate(q_network, validation)
            if best_validation is None or _score(summary) > _score(best_validation):
                best_validation, c["best_step"] = summary, c["global_step"]
                best_state = {k: v.clone() for k, v in q_network.state_dict().items()}
                if out is not None:
                    save_model(out / "best.pt", q_network,
                               model_meta(q_network, field_params, config.to_dict(), training_meta()))
            if progress:
                print(f"[{wall():7.1f} s] step {c['global_step']:>9} phase {phases[min(c['phase'], len(phases) - 1)].name}"
                      f" eps {epsilon:.3f} train success {collector.means()[1] or 0:.2f}"
                      f" | validation {summary['success']:.3f} trap {summary['trap_success']:.3f}"
                      f" coll {summary['collisions']} ratio {summary['length_ratio']:.3f} spl {summary['spl']:.3f}"
                      f" | best spl {best_validation.get('spl', float('nan')):.3f}", flush=True)
        row = {
            "global_step": c["global_step"], "episodes": c["episodes"],
            "stage": phases[min(c["phase"], len(phases) - 1)].name, "epsilon": round(epsilon, 5),
            "mean_return": collector.means()[0],
            "success_rate": collector.means()[1],
            "loss": "" if (loss := learner.mean_loss()) is None else round(loss, 6),
            "val_success": round(summary["success"], 4) if summary else "",
            "val_trap_success": round(summary["trap_success"], 4) if summary else "",
            "val_length_ratio": round(summary["length_ratio"], 4) if summary else "",
            "val_spl": round(summary["spl"], 4) if summary else "",
            "pool_draws": c["pool_draws"], "wall_time": round(wall(), 3),
        }
        history.append(row)
        if csv_path is not None:
            with open(csv_path, "a", newline="") as f:
                csv.DictWriter(f, CSV_COLUMNS).writerow(row)

    def next_multiple(value: int, every: int) -> int:
        return (value // every + 1) * every

    next_eval = next_multiple(c["global_step"], config.eval_every)
    next_log = next_multiple(c["global_step"], config.log_every)
    next_checkpoint = next_multiple(c["global_step"], config.checkpoint_every)
    epsilon = d.epsilon_initial
    try:
        while c["phase"] < len(phases) and not run_finished():
            phase = phases[c["phase"]]
            worlds = list(phase.worlds)
            next_refresh = None
            if phase.randomised:
                # redraw the pool where the last one would have been redrawn (also on resume)
                worlds += draw_pool(config, c["pool_draws"])
                next_refresh = next_multiple(c["phase_steps"], config.refresh_every)
            envs = _Envs(worlds, config, seed=d.seed + c["global_step"])
            collector.begin(envs.reset())
            phase_done = redraw = False
            while not (phase_done or redraw or run_finished()):
                episodes_for_epsilon = c["phase_episodes"] if config.restart_exploration else c["episodes"]
                epsilon = epsilon_schedule(d, episodes_for_epsilon)
                added, ended = collector.step(envs.step, epsilon, rng)
                c["episodes"] += ended
                c["phase_episodes"] += ended
                c["global_step"] += added
                c["phase_steps"] += added

                if learner.ready:
                    for _ in range(d.gradient_steps):
                        learner.update(rng)

                phase_done = ((phase.episodes is not None and c["phase_episodes"] >= phase.episodes)
                              or (phase.steps is not None and c["phase_steps"] >= phase.steps))
                if phase_done:
                    c["phase"] += 1
                    c["phase_steps"] = c["phase_episodes"] = 0
                if next_refresh is not None and c["phase_steps"] >= next_refresh:
                    c["pool_draws"] += 1
                    redraw = True
                evaluate = c["global_step"] >= next_eval
                if evaluate:
                    next_eval = next_multiple(c["global_step"], config.eval_every)
                if evaluate or c["global_step"] >= next_log:
                    next_log = next_multiple(c["global_step"], config.log_every)
                    evaluate_and_log(epsilon, evaluate)
                if c["global_step"] >= next_checkpoint or phase_done or redraw:
                    next_checkpoint = next_multiple(c["global_step"], config.checkpoint_every)
                    save_checkpoint()
            envs.close()
    except KeyboardInterrupt:
        save_checkpoint()  # an interrupted run resumes from here
        raise

    # A last evaluation, so the end of the run can be the best.
    if c["global_step"] > 0 and (not history or history[-1]["val_success"] == ""):
        evaluate_and_log(epsilon, True)
    save_checkpoint()
    return GeneralResult(
        config=config, global_step=c["global_step"], episodes=c["episodes"], updates=learner.updates,
        wall_time=wall(), phase=c["phase"], best_validation=best_validation, best_step=c["best_step"],
        out_dir=out, network=q_network, best_state=best_state, history=history,
    )


def run_curriculum_command(curriculum_path: str | os.PathLike | None, preset: Optional[str], out: str | os.PathLike,
                           seed: Optional[int] = None, resume: bool = False,
                           overrides: Optional[dict[str, Any]] = None, progress: bool = True) -> int:
    """``apf-physics train --curriculum FILE --out DIR [--preset P] [--seed S] [--set K=V] [--resume]``.

    Args:
        curriculum_path: The curriculum file (None: only the randomised phase of ``general``).
        preset: ``"general-revisit"`` (default), ``"general-memory"``, ``"general"`` or
            ``"thesis-general"``; on resume, the saved one.
        out: Output directory.
        seed: Random seed (default: the preset's, 0).
        resume: Continue the run in ``out``.
        overrides: Option changes (``--set``), fields of :class:`GeneralConfig` or :class:`DQNConfig`.
        progress: Print a line per evaluation.

    Returns:
        Exit status 0.

    Raises:
        UserError: Unusable arguments, files or checkpoint.
    """
    out = Path(out)
    overrides = dict(overrides or {})
    if resume:
        last = out / "last.pt"
        if not last.is_file():
            raise UserError(f"{last}: nothing to resume (no checkpoint there)")
        meta, _ = read_file(last)
        if "general" not in meta:
            raise UserError(f"{last}: not a general (curriculum) training checkpoint")
        saved = GeneralConfig.from_dict(meta["config"])
        if preset is not None and preset != saved.preset:
            raise UserError(f"{last}: was trained with preset {saved.preset!r}, not {preset!r}")
        config = _replace(saved, overrides)
    else:
        if (out / "last.pt").exists():
            raise UserError(f"{out} already holds a training run; use --resume to continue it or another --out")
        config = general_preset(preset or DEFAULT_PRESET, **overrides)
    result = train_general(config, curriculum=curriculum_path, out_dir=out, seed=seed, resume=resume,
                           progress=progress)
    best = result.best_validation
    summary = ("never evaluated" if best is None else
               f"{best['success']:.1%} of the validation starts ({best['trap_success']:.1%} of the trap starts), "
               f"{best['collisions']} collisions, path {best['length_ratio']:.2f}x A*, SPL {best['spl']:.3f}")
    print(f"trained {result.global_step} steps, {result.episodes} episodes, {result.updates} updates "
          f"in {result.wall_time:.1f} s; best validation: {summary}; network in {out / 'best.pt'}")
    return 0
