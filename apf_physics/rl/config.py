"""The training configuration: one flat, frozen :class:`TrainConfig`, and its named presets.

Every field is documented where it is declared, with its unit. A configuration is built from
a preset (:func:`preset`) and keyword overrides; an unknown key is an error that suggests the
nearest field name. The presets (:data:`PRESETS`) reproduce the thesis's tables and the
project's recipes:

========================  ==========  ===============================================================
preset                    trains on   what it is
========================  ==========  ===============================================================
``thesis-fixed``          a world     Table 3 as written (11×11 window, filters 10/10/20, m = 7, MSE,
                                      no target network, raw observations, 30,000 searches from the
                                      world's starts).
``thesis-general-world``  a world     Table 4's network and weights (9×9, filters 4/4, 150 searches)
                                      on one world.
``fast``                  a world     the Table 3 network trained the way it learns one world fastest
                                      here (64 envs, batch 64, double DQN, Huber loss, soft target,
                                      rewards ÷ 1000, signed-log relative observations, lattice starts),
                                      stopped when every start of the world succeeds.
``thesis-general``        curriculum  Table 4 through the curriculum's stages, 150 searches each, with
                                      rehearsal (Model §2), ε restarting every stage.
``general``               curriculum  ``fast``'s learner on a randomised pool of generated worlds plus
                                      the curriculum's worlds, 25 min.
``general-memory``        curriculum  ``general`` with the visit-memory channel, half the envs at the
                                      worlds' own starts.
``general-revisit``       curriculum  ``general-memory`` with the ``general`` reward (revisit and length
                                      terms): the shipped ``general.pt``; the default for a curriculum.
========================  ==========  ===============================================================

``thesis-general`` is the Table 4 *curriculum* (what the thesis trained with Table 4);
``thesis-general-world`` is the same network and weights on a single world.
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from dataclasses import dataclass
from typing import Any, Optional, Union

from apf_physics.actions import MOVE_SETS
from apf_physics.envs.reward import REWARD_PRESETS, RewardWeights
from apf_physics.errors import UserError
from apf_physics.generate import FAMILIES, MOVING_FAMILIES, STRUCTURE_FAMILIES
from apf_physics.models.network import OBS_TRANSFORMS, QNetwork
from apf_physics.observation import SCALES, ObserverConfig

N_ACTIONS = 9
"""Actions of Model Table 1."""
TRAIN_STARTS = ("world", "random", "reachable", "lattice")
"""Values of :attr:`TrainConfig.train_starts`."""
EVAL_FIGURES = ("success", "trap_success", "collisions", "length_ratio", "spl", "random_success")
"""Figures of an evaluation that :attr:`TrainConfig.select` may name (see :mod:`apf_physics.rl.evaluation`)."""
HELDOUT_SEED = 100
"""Seed of the project's held-out generated test set; training and validation never use it."""
RESUMABLE = frozenset({"total_steps", "total_episodes", "time_limit", "target_success", "threads", "eval_every",
                       "checkpoint_every", "log_every", "save_buffer"})
"""Fields that may differ when a run is resumed (how long it runs and how often it reports)."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run. Build one with :func:`preset`."""

    preset: str = "custom"
    """Name of the preset this configuration started from (informational)."""

    # --- observation (saved with every model as an ObserverConfig) ---
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
    obs_scale: str = "raw"
    """How the observer scales the potential: ``"raw"`` or ``"log"`` (:class:`~apf_physics.observation.ObserverConfig`)."""

    # --- network (saved with the model) ---
    filters: tuple[int, ...] = (10, 10, 20)
    """Output channels of each 2×2 convolution."""
    hidden: tuple[int, ...] = (32, 32)
    """Widths of the hidden fully connected layers."""
    negative_slope: float = 0.001
    """Leaky ReLU slope λ."""
    obs_transform: str = "raw"
    """Applied inside the network: ``"raw"``, ``"relative-log"`` (signed log of U − U at the robot's cell)
    ``"relative-log-memory"`` (the same on the potential channel only) or ``"relative-log-previous"``
    (the same on the potential and previous channels, both relative to the robot's cell now)."""

    # --- environment ---
    reward: Union[str, dict] = "thesis-fixed"
    """Reward preset name (:data:`~apf_physics.envs.reward.REWARD_PRESETS`) or a dict of
    :class:`~apf_physics.envs.reward.RewardWeights` fields (W1–W6, β of Model §2)."""
    max_episode_steps: int = 100
    """tt: moves per search before it is cut off [control steps]."""
    train_starts: str = "world"
    """Where training searches start: ``"world"`` (one of the world's starts, drawn), ``"random"`` (any
    free position away from the targets), ``"reachable"`` (random free positions from which the
    integer moves can end within the goal tolerance) or ``"lattice"`` (the free points at integer
    offsets from the target). The last two need a single training world."""
    world_start_fraction: float = 0.0
    """Share of the environments whose searches start at the worlds' own starts; the others use
    ``train_starts``."""
    num_envs: int = 1
    """Environments stepped in parallel (one vector step adds up to this many transitions)."""

    # --- learning (Model eq. 32–35) ---
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
    ``target_update_every`` updates) or ``"soft"`` (Polyak averaging with ``tau`` every update)."""
    target_update_every: int = 1000
    """Updates between copies of a hard target network."""
    tau: float = 0.01
    """Soft target update rate: target ← (1 − τ)·target + τ·online."""
    max_grad_norm: Optional[float] = None
    """Clip the gradient's global norm to this (None: no clipping)."""
    reward_scale: float = 1.0
    """Rewards are multiplied by this before learning (logged returns are unscaled)."""

    # --- exploration (Model eq. 34: ε_s = max(ε_i·(ts − s)/ts, ε_f) over searches s) ---
    epsilon_initial: float = 0.95
    """ε_i."""
    epsilon_final: float = 0.05
    """ε_f."""
    exploration_episodes: int = 30_000
    """ts: searches over which ε decays."""
    restart_exploration: bool = True
    """Count s from the start of each phase (the thesis: ε decays anew over every stage), not of the run."""

    # --- method ---
    method: str = "dqn"
    """``"dqn"``: deep Q-learning of the window network (:mod:`apf_physics.rl.trainer`);
    ``"imitation"``: the map network (:class:`~apf_physics.models.mapnet.MapNetwork`) learns
    A*'s moves on generated worlds (:mod:`apf_physics.rl.imitation`)."""
    map_resolution: int = 2
    """Imitation: nodes per unit of the map network's view."""
    map_channels: int = 8
    """Imitation: hidden channels of the map network's cost map."""
    map_moves: str = "fine"
    """Imitation: the network's move set (:data:`~apf_physics.actions.MOVE_SETS`)."""
    grad_iterations: int = 24
    """Imitation: value-iteration sweeps back-propagated through, after the fixed point."""
    demo_positions: int = 256
    """Imitation: robot positions labelled by the teacher per world and update."""
    label_temperature: float = 0.1
    """Imitation: the teacher's move probabilities are ``softmax(−cost to go after the move / T)``."""
    map_sizes: tuple[float, ...] = (50.0,)
    """Map sizes of generated worlds (pool and validation), cycled."""

    # --- phases (a world is one phase; a curriculum one phase per stage, then the pool) ---
    stage_episodes: Optional[int] = None
    """Searches per curriculum stage (the thesis: 150). None with ``stage_steps`` None: the stages
    are not trained one by one; their worlds only join the generated pool."""
    stage_steps: Optional[int] = None
    """Transitions per curriculum stage (instead of ``stage_episodes``)."""
    families: tuple[str, ...] = ()
    """Generator families of the randomised pool that follows the stages; empty: no pool."""
    pool_size: int = 80
    """Generated worlds in the pool at a time."""
    pool_starts: int = 6
    """Starts per generated world (behind its obstacles, where gradient descent gets trapped)."""
    refresh_every: int = 500_000
    """Transitions between redraws of the pool."""

    # --- when to stop (whichever comes first) ---
    total_episodes: Optional[int] = 30_000
    """Searches in all (None: no limit)."""
    total_steps: Optional[int] = None
    """Transitions in all (None: no limit)."""
    time_limit: Optional[float] = None
    """Seconds of training over all resumed sessions (None: no limit)."""
    target_success: Optional[float] = None
    """Stop once a greedy evaluation reaches this share of the validation starts (None: never early)."""

    # --- evaluation (picks best.pt) ---
    eval_every: int = 10_000
    """Transitions between greedy evaluations."""
    eval_shield: bool = False
    """Evaluate with the DQN planner's shield (``apf-physics eval --planner dqn``) rather than the
    network's choices as they are (``dqn-unshielded``)."""
    select: tuple[str, ...] = ("success", "random_success")
    """Which evaluation is best: compared figure by figure, in this order (a leading ``-``: lower is
    better; figures of :data:`EVAL_FIGURES`, rounded to 6 decimals); the first of equals is kept."""
    eval_random_starts: int = 0
    """On a world: also evaluate from this many random free starts that can reach a target, drawn
    once from a generator of their own (their success is the figure ``random_success``)."""
    validation_worlds: int = 30
    """On a curriculum: generated worlds of the validation set (all families in turn)."""
    validation_starts: int = 4
    """On a curriculum: starts per validation world."""
    validation_seed: int = 1
    """On a curriculum: seed of the validation set; never :data:`HELDOUT_SEED`."""

    # --- bookkeeping ---
    checkpoint_every: int = 50_000
    """Transitions between ``last.pt`` checkpoints."""
    log_every: int = 2_000
    """Transitions between rows of ``train.csv``."""
    save_buffer: bool = False
    """Store the experience pool in ``last.pt`` (large). Needed for a resumed run to continue exactly
    as an uninterrupted one; without it a resumed run refills the pool first."""
    threads: int = 1
    """torch intra-op threads. More than 1 helps only on an idle machine: on busy cores the threads
    wait on each other."""
    seed: int = 0
    """Seed of the environments, the network's initial weights, ε-greedy and minibatch sampling."""

    def __post_init__(self):
        reward_ok = (self.reward in REWARD_PRESETS if isinstance(self.reward, str)
                     else isinstance(self.reward, dict) and _reward_dict_ok(self.reward))
        select_names = [s.lstrip("-") for s in self.select]
        checks = [
            (self.obs_transform in OBS_TRANSFORMS, f"obs_transform must be one of {', '.join(OBS_TRANSFORMS)}"),
            (self.obs_scale in SCALES, f"obs_scale must be one of {', '.join(SCALES)}"),
            (self.obs_size >= 3 and self.obs_size % 2 == 1, "obs_size must be odd and at least 3"),
            (not self.memory or self.obs_transform in ("raw", "relative-log-memory", "relative-log-previous"),
             "memory needs obs_transform 'relative-log-memory' (or 'raw'): 'relative-log' would transform "
             "the memory channel too"),
            ((self.obs_transform == "relative-log-previous") == self.previous or self.obs_transform == "raw",
             "previous needs obs_transform 'relative-log-previous' (or 'raw'), and that transform needs previous"),
            (reward_ok, f"reward must be one of {', '.join(REWARD_PRESETS)} or a dict of RewardWeights fields"),
            (self.loss in ("mse", "huber"), "loss must be 'mse' or 'huber'"),
            (self.target_update in ("none", "hard", "soft"), "target_update must be 'none', 'hard' or 'soft'"),
            (self.train_starts in TRAIN_STARTS, f"train_starts must be one of {', '.join(TRAIN_STARTS)}"),
            (0.0 <= self.world_start_fraction <= 1.0, "world_start_fraction must be in [0, 1]"),
            (self.method in ("dqn", "imitation"), "method must be 'dqn' or 'imitation'"),
            (self.map_moves in MOVE_SETS, f"map_moves must be one of {', '.join(MOVE_SETS)}"),
            (1 <= self.map_resolution <= 8 and self.map_channels >= 1 and self.grad_iterations >= 0
             and self.demo_positions >= 1 and self.label_temperature > 0,
             "map_resolution must be 1 to 8; map_channels, demo_positions positive; grad_iterations not negative; "
             "label_temperature positive"),
            (bool(self.map_sizes) and all(20 <= s <= 500 for s in self.map_sizes), "map_sizes must be in [20, 500]"),
            (all(f in TRAIN_FAMILIES for f in self.families),
             f"families must be among {', '.join(TRAIN_FAMILIES)}"),
            (bool(self.select) and all(n in EVAL_FIGURES for n in select_names),
             f"select must name figures among {', '.join(EVAL_FIGURES)} (a leading '-': lower is better)"),
            (self.validation_seed != HELDOUT_SEED, f"validation_seed must not be the held-out seed {HELDOUT_SEED}"),
            (0 < self.tau <= 1, "tau must be in (0, 1]"),
            (self.eval_random_starts >= 0, "eval_random_starts must not be negative"),
            (min(self.num_envs, self.batch_size, self.threads, self.buffer_size, self.exploration_episodes,
                 self.obs_resolution, self.memory_cap) >= 1,
             "num_envs, batch_size, threads, buffer_size, exploration_episodes, obs_resolution and memory_cap "
             "must be positive"),
            (min(self.eval_every, self.checkpoint_every, self.log_every, self.train_frequency, self.gradient_steps,
                 self.target_update_every, self.max_episode_steps, self.pool_size, self.pool_starts,
                 self.refresh_every, self.validation_worlds, self.validation_starts) >= 1,
             "intervals, counts and sizes must be positive"),
            (all(v is None or v >= 1 for v in (self.stage_episodes, self.stage_steps, self.total_episodes,
                                               self.total_steps)), "budgets must be positive or null"),
            (self.time_limit is None or self.time_limit > 0, "time_limit must be positive or null"),
        ]
        for ok, message in checks:
            if not ok:
                raise UserError(f"invalid training configuration: {message}")

    @property
    def observer(self) -> ObserverConfig:
        """How observations are built (saved in every model file)."""
        channels = ("potential",) + (("previous",) if self.previous else ()) + (("memory",) if self.memory else ())
        return ObserverConfig(size=self.obs_size, resolution=self.obs_resolution, channels=channels,
                              memory_cap=self.memory_cap, scale=self.obs_scale)

    @property
    def reward_weights(self) -> RewardWeights:
        """The reward's weights."""
        return REWARD_PRESETS[self.reward] if isinstance(self.reward, str) else RewardWeights(**self.reward)

    def network(self) -> QNetwork:
        """A freshly initialised Q-network for this configuration."""
        return QNetwork(obs_shape=self.observer.shape, filters=self.filters, hidden=self.hidden, n_actions=N_ACTIONS,
                        negative_slope=self.negative_slope, obs_transform=self.obs_transform)

    def to_dict(self) -> dict[str, Any]:
        """Plain values (tuples as lists), for JSON."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "TrainConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        return replace(cls(), **data)


def _reward_dict_ok(data: dict) -> bool:
    try:
        RewardWeights(**data)
    except TypeError:
        return False
    return True


TRAIN_FAMILIES = FAMILIES + MOVING_FAMILIES + STRUCTURE_FAMILIES
"""Generator families a training pool may draw from (single-robot worlds)."""

PRESETS: dict[str, dict[str, Any]] = {
    "thesis-fixed": dict(),  # the defaults are Table 3
    "thesis-general-world": dict(
        obs_size=9, filters=(4, 4), reward="thesis-general",
        exploration_episodes=150, total_episodes=150, eval_every=2_000, checkpoint_every=5_000, log_every=500,
    ),
    "fast": dict(
        obs_transform="relative-log", train_starts="lattice", num_envs=64, batch_size=64,
        learning_starts=2_000, loss="huber", double_dqn=True, target_update="soft", tau=0.01,
        max_grad_norm=10.0, reward_scale=1e-3, exploration_episodes=3_000,
        total_episodes=None, total_steps=3_000_000, eval_every=3_200, target_success=1.0,
        checkpoint_every=128_000, log_every=6_400,
    ),
    "thesis-general": dict(
        obs_size=9, filters=(4, 4), reward="thesis-general", exploration_episodes=150,
        stage_episodes=150, restart_exploration=True, total_episodes=None,
        eval_every=5_000, eval_shield=True, select=("-collisions", "spl", "success"),
        log_every=2_000, checkpoint_every=20_000,
    ),
}
PRESETS["general"] = {
    **PRESETS["fast"],
    "train_starts": "random", "max_episode_steps": 200, "batch_size": 128, "buffer_size": 300_000,
    "learning_starts": 10_000,
    "num_envs": 32, "exploration_episodes": 12_000, "epsilon_final": 0.03,
    "families": FAMILIES, "pool_size": 80, "pool_starts": 6, "refresh_every": 500_000, "world_start_fraction": 0.25,
    "total_steps": None, "time_limit": 1500.0, "target_success": None,
    "eval_every": 150_000, "eval_shield": True, "select": ("-collisions", "spl", "success"),
    "log_every": 25_000, "checkpoint_every": 150_000,
}
PRESETS["general-memory"] = {**PRESETS["general"], "obs_transform": "relative-log-memory", "memory": True,
                             "world_start_fraction": 0.5}
PRESETS["general-revisit"] = {**PRESETS["general-memory"], "reward": "general"}
PRESETS["moving"] = {**PRESETS["general-revisit"], "obs_transform": "relative-log-previous", "previous": True,
                     "families": FAMILIES + MOVING_FAMILIES * len(FAMILIES), "time_limit": 2400.0}
PRESETS["map"] = {
    "method": "imitation", "reward": "thesis-general", "families": FAMILIES + STRUCTURE_FAMILIES,
    "map_sizes": (50.0, 100.0, 250.0), "pool_size": 48, "refresh_every": 600, "learning_rate": 3e-3,
    "total_episodes": None, "total_steps": 1_000, "time_limit": 1_800.0, "eval_every": 125, "eval_shield": False,
    "select": ("-collisions", "success", "spl"), "validation_worlds": 24, "validation_starts": 2, "validation_seed": 1,
    "log_every": 50, "checkpoint_every": 250, "hidden": (32, 32), "negative_slope": 0.01,
}
"""Changes to :class:`TrainConfig`'s defaults (which are Table 3's) for each preset."""
WORLD_DEFAULT = "fast"
"""What ``apf-physics train --world`` trains without ``--preset``."""
CURRICULUM_DEFAULT = "general-revisit"
"""What ``apf-physics train --curriculum`` trains without ``--preset``: the shipped general model's recipe."""


def _did_you_mean(name: str, choices: typing.Iterable[str]) -> str:
    close = difflib.get_close_matches(name, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


_FIELDS = {f.name: f for f in dataclasses.fields(TrainConfig)}
_HINTS = typing.get_type_hints(TrainConfig)


def _coerce(name: str, value: Any) -> Any:
    """``value`` (from YAML, JSON or Python) as the type of field ``name``; a clear error if it cannot be."""
    hint = _HINTS[name]
    optional = type(None) in typing.get_args(hint)
    if value is None:
        if optional:
            return None
        raise UserError(f"training option {name} cannot be null")
    base = next((a for a in typing.get_args(hint) if a is not type(None)), hint) if optional else hint
    if name == "reward":
        if isinstance(value, (str, dict)):
            return dict(value) if isinstance(value, dict) else value
    elif typing.get_origin(base) is tuple:
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
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif isinstance(value, base):
        return value
    kind = getattr(base, "__name__", str(base)) + (" or null" if optional else "")
    raise UserError(f"training option {name} must be {kind}, got {value!r}")


def replace(config: TrainConfig, **overrides: Any) -> TrainConfig:
    """``config`` with some fields changed; values are converted to the fields' types.

    Raises:
        UserError: An unknown field (with the nearest name) or an unusable value.
    """
    for key in overrides:
        if key not in _FIELDS:
            raise UserError(f"unknown training option {key!r}{_did_you_mean(key, _FIELDS)}; "
                            f"the options are the fields of apf_physics.rl.TrainConfig")
    return dataclasses.replace(config, **{k: _coerce(k, v) for k, v in overrides.items()})


def preset(name: str, **overrides: Any) -> TrainConfig:
    """A named configuration with some fields changed.

    Args:
        name: One of :data:`PRESETS`.
        **overrides: :class:`TrainConfig` fields to change.

    Raises:
        UserError: Unknown preset or field (with the nearest name), or an invalid value.
    """
    if name not in PRESETS:
        raise UserError(f"unknown training preset {name!r}{_did_you_mean(name, PRESETS)}; "
                        f"choose one of {', '.join(PRESETS)}")
    return replace(TrainConfig(preset=name), **{**PRESETS[name], **overrides})


def epsilon_schedule(config: TrainConfig, episodes: int) -> float:
    """ε after ``episodes`` finished searches: ``max(ε_i·(ts − s)/ts, ε_f)`` (Model eq. 34)."""
    ts = config.exploration_episodes
    return max(config.epsilon_initial * (ts - episodes) / ts, config.epsilon_final)


def differing_fields(saved: TrainConfig, config: TrainConfig) -> list[str]:
    """Fields, other than :data:`RESUMABLE`, in which two configurations differ."""
    return [name for name in _FIELDS if name not in RESUMABLE and getattr(saved, name) != getattr(config, name)]
