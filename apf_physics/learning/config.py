"""The training configuration: a frozen :class:`TrainConfig` of one section per concern, and its presets.

A configuration has a section for each concern, each a frozen dataclass whose fields are
documented where they are declared, with their units:

=================  =====================  ===================================================================
section            class                  what it holds
=================  =====================  ===================================================================
``env``            :class:`EnvConfig`     the training environments: observation, reward, starts, episodes
``network``        :class:`NetworkConfig` the network and its optimiser (both learners)
``dqn``            :class:`DQNConfig`     deep Q-learning: TD rule, experience pool, ε-greedy exploration
``imitation``      :class:`ImitationConfig` the map network learning A*'s moves
``schedule``       :class:`ScheduleConfig`  what is trained in what order and when the run stops
``evaluation``     :class:`EvalConfig`    the greedy evaluations that pick ``best.pt``
``run``            :class:`RunConfig`     checkpoints, logs, threads, seed
=================  =====================  ===================================================================

``method`` says which learner trains (``"dqn"`` or ``"imitation"``). Every option is checked
once, when the configuration is built: its type, its allowed values (``Literal`` options), its
range, and how options of different sections fit together; an unknown name is an error that
suggests the nearest one. Option names are unique across sections, so an option is named
either by its name (``learning_rate``) or by its path (``network.learning_rate``), in
:func:`preset`, :func:`replace`, ``apf-physics train --set`` and sweep files alike. A
configuration saves to and loads from YAML (:meth:`TrainConfig.to_yaml`,
:func:`load_config`); a model file keeps it as :meth:`TrainConfig.to_dict`.

The presets (:data:`PRESETS`) reproduce the thesis's tables and the project's recipes:

========================  ==========  ===============================================================
preset                    trains on   what it is
========================  ==========  ===============================================================
``thesis-fixed``          a world     Table 3 as written (11×11 window, filters 10/10/20, m = 7, MSE,
                                      no target network, raw observations, 30,000 searches from the
                                      world's starts).
``thesis-general-world``  a world     Table 4's network and weights (9×9, filters 4/4, 150 searches)
                                      on one world.
``fast``                  a world     the Table 3 network trained the way it learns one world well fastest
                                      here (64 envs, four updates of 128 per step, 5-step returns,
                                      double DQN, Huber loss, soft target, rewards ÷ 1000, signed-log
                                      relative observations, random reachable starts, half of them
                                      where training fails, ε over 1,500 searches), validated on 1,000 random free starts never trained on,
                                      stopped when 99 % of them and all the world's own starts succeed
                                      in one evaluation (or after 300,000 steps).
``thesis-general``        curriculum  Table 4 through the curriculum's stages, 150 searches each, with
                                      rehearsal (Model §2), ε restarting every stage.
``general``               curriculum  ``fast``'s learner on a randomised pool of generated worlds plus
                                      the curriculum's worlds, 25 min.
``general-memory``        curriculum  ``general`` with the visit-memory channel, half the envs at the
                                      worlds' own starts.
``general-revisit``       curriculum  ``general-memory`` with the ``general`` reward (revisit and length
                                      terms): the shipped ``general.pt``; the default for a curriculum.
``moving``                curriculum  ``general-revisit`` with the previous-field channel, on moving
                                      obstacles too: the shipped ``moving.pt``.
``map``                   curriculum  the map network by imitation of A* on generated worlds of three
                                      sizes: the shipped ``map.pt``.
========================  ==========  ===============================================================

``thesis-general`` is the Table 4 *curriculum* (what the thesis trained with Table 4);
``thesis-general-world`` is the same network and weights on a single world.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional, Union

import yaml

from apf_physics.envs.reward import REWARD_PRESETS, RewardWeights
from apf_physics.errors import UserError, did_you_mean
from apf_physics.world.generate import FAMILIES, MOVING_FAMILIES, SCALED_FAMILIES, STRUCTURE_FAMILIES
from apf_physics.world.kinematics import MOVE_KINDS
from apf_physics.models.network import OBS_TRANSFORMS
from apf_physics.sensing.observation import SCALES, ObserverConfig
from apf_physics.common.safefile import atomic_path, read_text_file

N_ACTIONS = 9
"""Actions of Model Table 1."""
Method = Literal["dqn", "imitation"]
"""Which learner trains: deep Q-learning of the window network, or the map network by imitation."""
TrainStarts = Literal["world", "random", "reachable", "lattice"]
TRAIN_STARTS = typing.get_args(TrainStarts)
"""Values of :attr:`EnvConfig.train_starts`."""
ObsScale = Literal[SCALES]
ObsTransform = Literal[OBS_TRANSFORMS]
Loss = Literal["mse", "huber"]
TargetUpdate = Literal["none", "hard", "soft"]
EvalNetwork = Literal["online", "target"]
MoveSet = Literal[tuple(MOVE_KINDS)]
EVAL_FIGURES = ("success", "trap_success", "collisions", "length_ratio", "spl", "world_starts_success",
                "world_starts_collisions")
"""Figures of an evaluation that :attr:`EvalConfig.select` may name: on the validation starts (the first five,
``validation_*`` in ``train.csv``; see :mod:`apf_physics.learning.validation`), and on a world's own starts."""
HELDOUT_SEED = 100
"""Seed of the project's held-out generated test set; training and validation never use it."""
TRAIN_FAMILIES = FAMILIES + MOVING_FAMILIES + STRUCTURE_FAMILIES + SCALED_FAMILIES
"""Generator families a training pool may draw from (single-robot worlds)."""
RESUMABLE = frozenset({"total_steps", "total_episodes", "time_limit", "target_success", "threads", "eval_every",
                       "checkpoint_every", "log_every", "save_buffer", "loss_limit"})
"""Options that may differ when a run is resumed (how long it runs and how often it reports)."""


def _check(checks: list[tuple[bool, str]]) -> None:
    for ok, message in checks:
        if not ok:
            raise UserError(f"invalid training configuration: {message}")


@dataclass(frozen=True)
class EnvConfig:
    """The training environments: what a robot observes, its reward, where its searches start."""

    obs_size: int = 11
    """k: side of the observation window [points, spacing 1 world unit]."""
    obs_resolution: int = 4
    """Raster nodes per world unit the window is sampled from."""
    memory: bool = False
    """Add the robot's visit memory as a second observation channel (needs ``obs_transform``
    ``"relative-log-memory"`` or ``"raw"``)."""
    memory_cap: int = 4
    """Visits at which a memory cell reads 1."""
    previous: bool = False
    """Add the window of the field one step earlier (where moving obstacles were) as the channel
    after the potential (needs ``obs_transform`` ``"relative-log-previous"`` or ``"raw"``)."""
    obs_scale: ObsScale = "raw"
    """How the observer scales the potential (:class:`~apf_physics.sensing.observation.ObserverConfig`)."""
    reward: Union[str, dict] = "thesis-fixed"
    """Reward preset name (:data:`~apf_physics.envs.reward.REWARD_PRESETS`) or a dict of
    :class:`~apf_physics.envs.reward.RewardWeights` fields (W1–W6, β of Model §2)."""
    max_episode_steps: int = 100
    """tt: moves per search before it is cut off [control steps]."""
    train_starts: TrainStarts = "world"
    """Where training searches start: ``"world"`` (one of the world's starts, drawn), ``"random"`` (any
    free position away from the targets), ``"reachable"`` (random free positions from which the
    integer moves can end within the goal tolerance) or ``"lattice"`` (the free points at integer
    offsets from the target). The last two need a single training world."""
    world_start_fraction: float = 0.0
    """Share of the environments whose searches start at the worlds' own starts; the others use
    ``train_starts``."""
    failure_starts: float = 0.0
    """Share of the training starts drawn where recent training searches failed (weighted by the
    failures of the one-unit cell each start lies in, redrawn every 100 vector steps); the rest are
    drawn as ``train_starts`` says (0: all of them). One world only."""
    num_envs: int = 1
    """Environments stepped in parallel (one vector step adds up to this many transitions)."""

    def __post_init__(self):
        reward_ok = (self.reward in REWARD_PRESETS if isinstance(self.reward, str)
                     else isinstance(self.reward, dict) and _reward_dict_ok(self.reward))
        _check([
            (self.obs_size >= 3 and self.obs_size % 2 == 1, "obs_size must be odd and at least 3"),
            (reward_ok, f"reward must be one of {', '.join(REWARD_PRESETS)} or a dict of RewardWeights fields"),
            (0.0 <= self.world_start_fraction <= 1.0, "world_start_fraction must be in [0, 1]"),
            (0.0 <= self.failure_starts <= 1.0, "failure_starts must be in [0, 1]"),
            (min(self.num_envs, self.obs_resolution, self.memory_cap, self.max_episode_steps) >= 1,
             "num_envs, obs_resolution, memory_cap and max_episode_steps must be positive"),
        ])

    @property
    def observer(self) -> ObserverConfig:
        """How observations are built (saved in every model file)."""
        return ObserverConfig.of(self.obs_size, self.obs_resolution, previous=self.previous, memory=self.memory,
                                 memory_cap=self.memory_cap, scale=self.obs_scale)

    @property
    def reward_weights(self) -> RewardWeights:
        """The reward's weights."""
        return REWARD_PRESETS[self.reward] if isinstance(self.reward, str) else RewardWeights(**self.reward)


@dataclass(frozen=True)
class NetworkConfig:
    """The network (saved with the model) and its optimiser, for either learner."""

    filters: tuple[int, ...] = (10, 10, 20)
    """The window network: output channels of each 2×2 convolution."""
    hidden: tuple[int, ...] = (32, 32)
    """Widths of the hidden fully connected layers."""
    negative_slope: float = 0.001
    """Leaky ReLU slope λ."""
    obs_transform: ObsTransform = "raw"
    """Applied inside the window network: ``"raw"``, ``"relative-log"`` (signed log of U − U at the
    robot's cell), ``"relative-log-memory"`` (the same on the potential channel only) or
    ``"relative-log-previous"`` (the same on the potential and previous channels, both relative to
    the robot's cell now)."""
    learning_rate: float = 1e-3
    """η: Adam's learning rate."""
    max_grad_norm: Optional[float] = None
    """Clip the gradient's global norm to this (None: no clipping; the map network clips at 10)."""

    def __post_init__(self):
        _check([(self.learning_rate > 0, "learning_rate must be positive"),
                (self.max_grad_norm is None or self.max_grad_norm > 0, "max_grad_norm must be positive or null"),
                (all(n >= 1 for n in (*self.filters, *self.hidden)), "filters and hidden widths must be positive")])


@dataclass(frozen=True)
class DQNConfig:
    """Deep Q-learning (Model eq. 32–35) and its ε-greedy exploration (eq. 34: ε_s = max(ε_i·(ts − s)/ts, ε_f))."""

    gamma: float = 0.95
    """γ: discount rate."""
    n_step: int = 1
    """Rewards summed into each TD target before bootstrapping (1: eq. 32 as written)."""
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
    loss: Loss = "mse"
    """TD loss: ``"mse"`` (the thesis, eq. 35) or ``"huber"`` (less sensitive to outliers)."""
    double_dqn: bool = False
    """Choose the next action with the online network, value it with the target network."""
    target_update: TargetUpdate = "none"
    """``"none"`` (TD targets from the online network, as the thesis), ``"hard"`` (copy every
    ``target_update_every`` updates) or ``"soft"`` (Polyak averaging with ``tau`` every update)."""
    target_update_every: int = 1000
    """Updates between copies of a hard target network."""
    tau: float = 0.01
    """Soft target update rate: target ← (1 − τ)·target + τ·online."""
    eval_network: EvalNetwork = "online"
    """The network evaluated and kept as ``best.pt``: ``"online"`` (the one being updated) or ``"target"``
    (with soft updates, the average of the online weights over about 1/τ updates: its greedy choices
    change smoothly from one evaluation to the next, where the online network's jump)."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this before learning (logged returns are unscaled)."""
    epsilon_initial: float = 0.95
    """ε_i."""
    epsilon_final: float = 0.05
    """ε_f."""
    exploration_episodes: int = 30_000
    """ts: searches over which ε decays."""
    restart_exploration: bool = True
    """Count s from the start of each phase (the thesis: ε decays anew over every stage), not of the run."""

    def __post_init__(self):
        _check([
            (0 < self.tau <= 1, "tau must be in (0, 1]"),
            (self.eval_network == "online" or self.target_update != "none",
             "eval_network 'target' needs a target network (target_update 'soft' or 'hard')"),
            (0 <= self.gamma <= 1, "gamma must be in [0, 1]"),
            (0 <= self.epsilon_final <= 1 and 0 <= self.epsilon_initial <= 1, "epsilons must be in [0, 1]"),
            (min(self.batch_size, self.buffer_size, self.exploration_episodes, self.train_frequency,
                 self.gradient_steps, self.target_update_every, self.n_step) >= 1,
             "batch_size, buffer_size, exploration_episodes, train_frequency, gradient_steps, "
             "target_update_every and n_step must be positive"),
        ])


@dataclass(frozen=True)
class ImitationConfig:
    """The map network (:class:`~apf_physics.models.mapnet.MapNetwork`) learning A*'s moves (:mod:`apf_physics.learning.imitation`)."""

    map_resolution: int = 2
    """Nodes per unit of the map network's view."""
    map_channels: int = 8
    """Hidden channels of the map network's cost map."""
    map_moves: MoveSet = "fine"
    """The network's moves (:data:`~apf_physics.world.kinematics.MOVE_KINDS`: a fixed set, or "nodes")."""
    map_dv_clip: float = 4.0
    """|ΔV| the map network's head reads is clipped to this (:attr:`~apf_physics.models.mapnet.MapNetwork.dv_clip`)."""
    map_least_resolution: Optional[int] = None
    """Moves onto nodes: the graph the network learns and plans on has at least this many nodes per
    step (:func:`~apf_physics.sim.nodegraph.resolution_for`; None: ``map_resolution``)."""
    grad_iterations: int = 24
    """Value-iteration (Bellman) updates back-propagated through, after the fixed point."""
    demo_positions: int = 256
    """Robot positions labelled by the teacher per world and update."""
    label_temperature: float = 0.1
    """The teacher's move probabilities are ``softmax(−cost to go after the move / T)``."""

    def __post_init__(self):
        _check([(1 <= self.map_resolution <= 8, "map_resolution must be 1 to 8"),
                (self.map_channels >= 1 and self.demo_positions >= 1, "map_channels and demo_positions must be positive"),
                (self.grad_iterations >= 0, "grad_iterations must not be negative"),
                (0 < self.map_dv_clip <= 1e3, "map_dv_clip must be from 0 to 1,000"),
                (self.map_least_resolution is None or 1 <= self.map_least_resolution <= 16,
                 "map_least_resolution must be 1 to 16"),
                (self.label_temperature > 0, "label_temperature must be positive")])


@dataclass(frozen=True)
class ScheduleConfig:
    """What is trained in what order (a world is one phase; a curriculum one phase per stage, then the
    pool), and when the run stops: whichever limit comes first."""

    stage_episodes: Optional[int] = None
    """Searches per curriculum stage (the thesis: 150). None with ``stage_steps`` None: the stages
    are not trained one by one; their worlds only join the generated pool."""
    stage_steps: Optional[int] = None
    """Steps (transitions; imitation: updates) per curriculum stage (instead of ``stage_episodes``)."""
    families: tuple[str, ...] = ()
    """Generator families of the randomised pool that follows the stages; empty: no pool."""
    map_sizes: tuple[float, ...] = (50.0,)
    """Map sizes of generated worlds (pool and validation), cycled [steps]."""
    pool_size: int = 80
    """Generated worlds in the pool at a time."""
    pool_starts: int = 6
    """Starts per generated world (behind its obstacles, where gradient descent gets trapped)."""
    refresh_every: int = 500_000
    """Steps between redraws of the pool."""
    total_episodes: Optional[int] = 30_000
    """Searches in all (None: no limit)."""
    total_steps: Optional[int] = None
    """Steps in all: transitions of DQN, updates of imitation (None: no limit)."""
    time_limit: Optional[float] = None
    """Seconds of training over all resumed sessions (None: no limit)."""
    target_success: Optional[float] = None
    """Stop once a greedy evaluation succeeds from this share of the validation starts (None: never early).
    An evaluation that meets it (and ``target_world_starts``) is preferred as ``best.pt`` over one that does not."""
    target_world_starts: Optional[float] = None
    """Where the world's own starts are evaluated beside random validation starts (``eval_random_starts``
    > 0): stop only once the same evaluation also succeeds from this share of the world starts, and prefer
    such an evaluation as ``best.pt`` (None: the world starts only break ties; without ``target_success``
    it has no effect)."""
    loss_limit: Optional[float] = 1e12
    """Stop, as diverged, when a logged mean loss exceeds this (a non-finite loss always stops; None:
    no limit)."""

    def __post_init__(self):
        _check([
            (bool(self.map_sizes) and all(20 <= s <= 500 for s in self.map_sizes), "map_sizes must be in [20, 500]"),
            (all(f in TRAIN_FAMILIES for f in self.families), f"families must be among {', '.join(TRAIN_FAMILIES)}"),
            (min(self.pool_size, self.pool_starts, self.refresh_every) >= 1,
             "pool_size, pool_starts and refresh_every must be positive"),
            (all(v is None or v >= 1 for v in (self.stage_episodes, self.stage_steps, self.total_episodes,
                                               self.total_steps)), "budgets must be positive or null"),
            (self.time_limit is None or self.time_limit > 0, "time_limit must be positive or null"),
            (all(t is None or 0 < t <= 1 for t in (self.target_success, self.target_world_starts)),
             "target_success and target_world_starts must be in (0, 1] or null"),
            (self.loss_limit is None or self.loss_limit > 0, "loss_limit must be positive or null"),
        ])


@dataclass(frozen=True)
class EvalConfig:
    """The greedy evaluations made while training, through the physics as ``eval`` runs them: they pick ``best.pt``."""

    eval_every: int = 10_000
    """Steps between greedy evaluations."""
    eval_shield: bool = False
    """Evaluate with the DQN planner's shield (``apf-physics eval --planner dqn``) rather than the
    network's choices as they are (``dqn-unshielded``)."""
    select: tuple[str, ...] = ("success", "world_starts_success")
    """Which evaluation is best: one that meets the run's targets (``target_success``, with
    ``target_world_starts``) before one that does not, then compared figure by figure, in this order
    (a leading ``-``: lower is better; figures of :data:`EVAL_FIGURES`, rounded to 6 decimals); the
    first of equals is kept."""
    eval_random_starts: int = 0
    """On a world: the validation starts (which choose ``best.pt``) are this many random free starts
    that can reach a target, drawn once from a generator of their own and never trained from; the
    world's own starts are evaluated beside them (0: the world's own starts are the validation starts)."""
    validation_worlds: int = 30
    """On a curriculum: generated worlds of the validation set (all families in turn)."""
    validation_starts: int = 4
    """On a curriculum: starts per validation world."""
    validation_seed: int = 1
    """On a curriculum: seed of the validation set; never :data:`HELDOUT_SEED`."""

    def __post_init__(self):
        _check([
            (bool(self.select) and all(n.lstrip("-") in EVAL_FIGURES for n in self.select),
             f"select must name figures among {', '.join(EVAL_FIGURES)} (a leading '-': lower is better)"),
            (self.validation_seed != HELDOUT_SEED, f"validation_seed must not be the held-out seed {HELDOUT_SEED}"),
            (self.eval_random_starts >= 0, "eval_random_starts must not be negative"),
            (min(self.eval_every, self.validation_worlds, self.validation_starts) >= 1,
             "eval_every, validation_worlds and validation_starts must be positive"),
        ])


@dataclass(frozen=True)
class RunConfig:
    """Bookkeeping of a run: checkpoints, logs, threads and the seed."""

    checkpoint_every: int = 50_000
    """Steps between ``last.pt`` checkpoints."""
    log_every: int = 2_000
    """Steps between rows of ``train.csv``."""
    save_buffer: bool = False
    """Store the experience pool in ``last.pt`` (large). Needed for a resumed run to continue exactly
    as an uninterrupted one; without it a resumed run refills the pool first."""
    threads: int = 1
    """torch intra-op threads. More than 1 helps only on an idle machine: on busy cores the threads
    wait on each other."""
    seed: int = 0
    """Seed of the environments, the network's initial weights, ε-greedy and minibatch sampling."""

    def __post_init__(self):
        _check([(min(self.checkpoint_every, self.log_every, self.threads) >= 1,
                 "checkpoint_every, log_every and threads must be positive")])


SECTIONS: dict[str, type] = {"env": EnvConfig, "network": NetworkConfig, "dqn": DQNConfig,
                             "imitation": ImitationConfig, "schedule": ScheduleConfig, "evaluation": EvalConfig,
                             "run": RunConfig}
"""The sections of :class:`TrainConfig`, by attribute name."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run, one section per concern. Build one with :func:`preset`."""

    preset: str = "custom"
    """Name of the preset this configuration started from (informational)."""
    method: Method = "dqn"
    """``"dqn"``: deep Q-learning of the window network (:mod:`apf_physics.learning.dqn`); ``"imitation"``:
    the map network learns A*'s moves on generated worlds (:mod:`apf_physics.learning.imitation`)."""
    env: EnvConfig = field(default_factory=EnvConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    dqn: DQNConfig = field(default_factory=DQNConfig)
    imitation: ImitationConfig = field(default_factory=ImitationConfig)
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    evaluation: EvalConfig = field(default_factory=EvalConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def __post_init__(self):
        env, transform = self.env, self.network.obs_transform
        _check([
            (self.method in typing.get_args(Method), f"method must be one of {', '.join(typing.get_args(Method))}"),
            (not env.memory or transform in ("raw", "relative-log-memory", "relative-log-previous"),
             "memory needs obs_transform 'relative-log-memory' (or 'raw'): 'relative-log' would transform "
             "the memory channel too"),
            ((transform == "relative-log-previous") == env.previous or transform == "raw",
             "previous needs obs_transform 'relative-log-previous' (or 'raw'), and that transform needs previous"),
        ])

    @property
    def observer(self) -> ObserverConfig:
        """How the window network's observations are built (:attr:`EnvConfig.observer`)."""
        return self.env.observer

    def option(self, name: str) -> Any:
        """The value of an option, by its name or path (``"learning_rate"``, ``"network.learning_rate"``)."""
        section, leaf = _locate(name)
        return getattr(self, leaf) if section is None else getattr(getattr(self, section), leaf)

    def options(self) -> dict[str, Any]:
        """Every option by its name (tuples as they are), sections flattened."""
        return {name: self.option(name) for name in OPTIONS}

    def to_dict(self) -> dict[str, Any]:
        """Plain values by section (tuples as lists), for JSON and YAML."""
        def plain(value: Any) -> Any:
            return list(value) if isinstance(value, tuple) else value
        out: dict[str, Any] = {"preset": self.preset, "method": self.method}
        for name in SECTIONS:
            out[name] = {k: plain(v) for k, v in dataclasses.asdict(getattr(self, name)).items()}
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "TrainConfig":
        """Inverse of :meth:`to_dict`; also reads the flat form of model files written before sections.

        Raises:
            UserError: An unknown option (with the nearest name) or an unusable value.
        """
        if not isinstance(data, dict):
            raise UserError(f"a training configuration must be a mapping of options, got {type(data).__name__}")
        return replace(cls(), **data)

    def to_yaml(self, path: str | Path) -> Path:
        """Write the configuration to a YAML file (atomically), to be read back by :func:`load_config`."""
        path = Path(path)
        with atomic_path(path) as tmp:
            tmp.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False), encoding="utf-8")
        return path


OPTIONS: dict[str, Optional[str]] = {"preset": None, "method": None}
"""Every option's name → its section (None: :class:`TrainConfig` itself)."""
for _section, _cls in SECTIONS.items():
    for _field in dataclasses.fields(_cls):
        assert _field.name not in OPTIONS, f"option {_field.name} is in two sections"
        OPTIONS[_field.name] = _section
_HINTS = {name: typing.get_type_hints(cls) for name, cls in SECTIONS.items()}
_HINTS[None] = {k: v for k, v in typing.get_type_hints(TrainConfig).items() if k in OPTIONS}


def _locate(name: str) -> tuple[Optional[str], str]:
    """``(section, option)`` of an option's name or ``section.option`` path."""
    section, dot, leaf = name.rpartition(".")
    if not dot:
        if name in OPTIONS:
            return OPTIONS[name], name
    elif section in SECTIONS and OPTIONS.get(leaf, "") == section:
        return section, leaf
    paths = list(OPTIONS) + [f"{s}.{n}" for n, s in OPTIONS.items() if s is not None]
    hint = (f" (did you mean '{OPTIONS[leaf]}.{leaf}'?)" if dot and OPTIONS.get(leaf) else
            did_you_mean(name, [p for p in paths if "." in p] if dot else paths))
    raise UserError(f"unknown training option {name!r}{hint}; the options are the fields "
                    "of apf_physics.learning.TrainConfig's sections (env, network, dqn, imitation, schedule, "
                    "evaluation, run)")


def _reward_dict_ok(data: dict) -> bool:
    try:
        RewardWeights(**data)
    except TypeError:
        return False
    return True


def _coerce(name: str, hint: Any, value: Any) -> Any:
    """``value`` (from YAML, JSON or Python) as type ``hint`` of option ``name``; a clear error if it cannot be."""
    optional = type(None) in typing.get_args(hint)
    if value is None:
        if optional:
            return None
        raise UserError(f"training option {name} cannot be null")
    base = next((a for a in typing.get_args(hint) if a is not type(None)), hint) if optional else hint
    origin = typing.get_origin(base)
    if origin is Literal:
        choices = typing.get_args(base)
        if value in choices:
            return value
        raise UserError(f"training option {name} must be one of {', '.join(map(str, choices))}, got {value!r}"
                        f"{did_you_mean(value, choices) if isinstance(value, str) else ''}")
    if origin is Union:  # reward: a preset name or a dict of weights
        if isinstance(value, (str, dict)):
            return dict(value) if isinstance(value, dict) else value
    elif origin is tuple:
        (item,) = {a for a in typing.get_args(base) if a is not Ellipsis}
        if isinstance(value, str):
            value = [value]
        numbers = (int, float) if item is float else item        # a whole number is a float too
        if isinstance(value, (list, tuple)) and all(isinstance(v, numbers) and not isinstance(v, bool) for v in value):
            return tuple(float(v) if item is float else v for v in value)
        kind = f"a list of {getattr(item, '__name__', item)}" + (" or null" if optional else "")
        raise UserError(f"training option {name} must be {kind}, got {value!r}")
    elif base is bool:
        if isinstance(value, bool):
            return value
    elif base is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
    elif base is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isnan(value):
            return float(value)
    elif isinstance(value, base):
        return value
    kind = getattr(base, "__name__", str(base)) + (" or null" if optional else "")
    raise UserError(f"training option {name} must be {kind}, got {value!r}")


def replace(config: TrainConfig, **overrides: Any) -> TrainConfig:
    """``config`` with some options changed; values are converted to the options' types and checked.

    Args:
        config: The configuration to start from.
        **overrides: Options by name (``learning_rate=3e-4``), by path (``**{"network.learning_rate": 3e-4}``)
            or whole sections as mappings (``network={"learning_rate": 3e-4}``).

    Raises:
        UserError: An unknown option (with the nearest name) or an unusable value.
    """
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        if key in SECTIONS:
            if not isinstance(value, dict):
                raise UserError(f"training option section {key} must be a mapping of options, got {value!r}")
            flat.update({f"{key}.{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    top: dict[str, Any] = {}
    sections: dict[str, dict[str, Any]] = {}
    for key, value in flat.items():
        section, leaf = _locate(key)
        coerced = _coerce(leaf, _HINTS[section][leaf], value)
        if section is None:
            top[leaf] = coerced
        else:
            sections.setdefault(section, {})[leaf] = coerced
    parts = {name: dataclasses.replace(getattr(config, name), **changes) for name, changes in sections.items()}
    return dataclasses.replace(config, **top, **parts)


def load_config(path: str | Path) -> TrainConfig:
    """A configuration from a YAML file of options (by section, as :meth:`TrainConfig.to_yaml` writes, or flat).

    Raises:
        UserError: The file cannot be read, is not YAML, or holds an unknown option or an unusable value
            (the message names the file).
    """
    text = read_text_file(path, "training configuration")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise UserError(f"{path}: not a YAML file ({str(error).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: a training configuration must be a mapping of options")
    try:
        return TrainConfig.from_dict(data)
    except UserError as error:
        raise UserError(f"{path}: {error}") from None


LAYERS: dict[str, tuple[str | None, dict[str, Any], str]] = {
    # name: (the layer it changes, its changes by option name, what it is). The defaults of
    # TrainConfig are Table 3's: thesis-fixed changes nothing.
    "thesis-fixed": (None, {}, "Table 3 as written"),
    "fast learner": (None, dict(
        obs_transform="relative-log", train_starts="lattice", num_envs=64, batch_size=64, learning_starts=2_000,
        loss="huber", double_dqn=True, target_update="soft", tau=0.01, max_grad_norm=10.0, reward_scale=1e-3),
        "the learner that learns a world fastest here (shared by fast and the general presets)"),
    "fast": ("fast learner", dict(
        train_starts="reachable", failure_starts=0.5, batch_size=128, gradient_steps=4, n_step=5,
        learning_rate=5e-4, eval_network="target", eval_random_starts=1000, select=("success", "world_starts_success"),
        exploration_episodes=1_500, total_episodes=None, total_steps=300_000, eval_every=3_200,
        target_success=0.99, target_world_starts=1.0, checkpoint_every=128_000, log_every=6_400),
        "a world, learnt fastest; validated on random starts, stopped by steps"),
    "thesis-general-world": (None, dict(
        obs_size=9, filters=(4, 4), reward="thesis-general", exploration_episodes=150, total_episodes=150,
        eval_every=2_000, checkpoint_every=5_000, log_every=500), "Table 4's network and weights on one world"),
    "thesis-general": (None, dict(
        obs_size=9, filters=(4, 4), reward="thesis-general", exploration_episodes=150, stage_episodes=150,
        restart_exploration=True, total_episodes=None, eval_every=5_000, eval_shield=True,
        select=("-collisions", "spl", "success"), log_every=2_000, checkpoint_every=20_000),
        "Table 4 through a curriculum, with rehearsal"),
    "general": ("fast learner", dict(
        train_starts="random", max_episode_steps=200, batch_size=128, buffer_size=300_000, learning_starts=10_000,
        num_envs=32, exploration_episodes=12_000, epsilon_final=0.03, families=FAMILIES, pool_size=80, pool_starts=6,
        refresh_every=500_000, world_start_fraction=0.25, total_episodes=None, time_limit=1500.0,
        eval_every=150_000, eval_shield=True, select=("-collisions", "spl", "success"), log_every=25_000,
        checkpoint_every=150_000), "the window network on generated worlds and a curriculum"),
    "general-memory": ("general", dict(obs_transform="relative-log-memory", memory=True, world_start_fraction=0.5),
                       "general with the visit-memory channel"),
    "general-revisit": ("general-memory", dict(reward="general"),
                        "general-memory with revisit and length reward terms: the shipped general.pt"),
    "moving": ("general-revisit", dict(obs_transform="relative-log-previous", previous=True,
                                       families=FAMILIES + MOVING_FAMILIES * len(FAMILIES), time_limit=2400.0),
               "general-revisit with the field a step earlier, half its pool moving: the shipped moving.pt"),
    "map": (None, dict(
        method="imitation", reward="thesis-general", families=FAMILIES + STRUCTURE_FAMILIES + SCALED_FAMILIES,
        map_sizes=(50.0, 100.0, 250.0), map_moves="nodes", map_dv_clip=8.0, pool_size=48, refresh_every=600,
        learning_rate=3e-3, total_episodes=None, total_steps=1_250, time_limit=5_400.0, eval_every=125, eval_shield=False,
        select=("-collisions", "success", "spl"), validation_worlds=24, validation_starts=2, validation_seed=1,
        log_every=50, checkpoint_every=250, hidden=(32, 32), negative_slope=0.01),
        "the map network by imitation of A*: the shipped map.pt"),
}
"""Each preset as the layer of changes it makes to another (or to :class:`TrainConfig`'s defaults,
which are Table 3's). ``apf-physics train --show-config`` prints every option of a preset with the
layer each value comes from (:func:`explain`). Layers with a space in their name are shared parts,
not presets."""


def _flattened(name: str) -> dict[str, Any]:
    base, changes, _ = LAYERS[name]
    return {**(_flattened(base) if base is not None else {}), **changes}


PRESETS: dict[str, dict[str, Any]] = {name: _flattened(name) for name in LAYERS if " " not in name}
"""Every preset's changes to :class:`TrainConfig`'s defaults, its layers merged, by option name."""
WORLD_DEFAULT = "fast"
"""What ``apf-physics train --world`` trains without ``--preset``."""
CURRICULUM_DEFAULT = "general-revisit"
"""What ``apf-physics train --curriculum`` trains without ``--preset``: the shipped general model's recipe."""


def preset(name: str, **overrides: Any) -> TrainConfig:
    """A named configuration with some options changed.

    Args:
        name: One of :data:`PRESETS`.
        **overrides: Options to change, as :func:`replace` takes them.

    Raises:
        UserError: Unknown preset or option (with the nearest name), or an invalid value.
    """
    if name not in PRESETS:
        raise UserError(f"unknown training preset {name!r}{did_you_mean(name, PRESETS)}; "
                        f"choose one of {', '.join(PRESETS)}")
    return replace(TrainConfig(preset=name), **{**PRESETS[name], **overrides})


def explain(name: str, overrides: dict[str, Any] | None = None) -> list[tuple[str, Any, str]]:
    """Every option of preset ``name`` (with ``overrides``): ``(section.option, value, where it comes from)``,
    the source being ``"--set"``, the preset layer that set it (:data:`LAYERS`), or ``"default"``.

    Raises:
        UserError: As :func:`preset`.
    """
    config = preset(name, **(overrides or {}))
    source: dict[str, str] = {}
    layer: str | None = name
    while layer is not None:
        base, changes, _ = LAYERS[layer]
        for option in changes:
            source.setdefault(option, f"preset {layer}" if " " not in layer else f"{layer} (in {name})")
        layer = base
    given = {_locate(key)[1] for key in (overrides or {})}
    rows = []
    for option, value in config.options().items():
        section = OPTIONS[option]
        where = ("--set" if option in given else "the preset chosen" if option == "preset"
                 else source.get(option, "default"))
        rows.append((option if section is None else f"{section}.{option}", value, where))
    return rows


def epsilon_schedule(config: TrainConfig | DQNConfig, episodes: int) -> float:
    """ε after ``episodes`` finished searches: ``max(ε_i·(ts − s)/ts, ε_f)`` (Model eq. 34)."""
    dqn = config.dqn if isinstance(config, TrainConfig) else config
    ts = dqn.exploration_episodes
    return max(dqn.epsilon_initial * (ts - episodes) / ts, dqn.epsilon_final)


def differing_fields(saved: TrainConfig, config: TrainConfig) -> list[str]:
    """Options, other than :data:`RESUMABLE`, in which two configurations differ."""
    a, b = saved.options(), config.options()
    return [name for name in OPTIONS if name not in RESUMABLE and a[name] != b[name]]
