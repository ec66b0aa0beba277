"""Training the planners' networks: one typed configuration, phases, one loop, two learners.

- :mod:`~apf_physics.rl.config`: :class:`TrainConfig` (a section per concern) and its named presets.
- :mod:`~apf_physics.rl.phases`: what is trained, in order (a world is one phase; a curriculum
  one per stage, then generated worlds).
- :mod:`~apf_physics.rl.trainer`: the loop, :func:`train`, for every learner.
- :mod:`~apf_physics.rl.learner`: what the loop asks of a learner; :mod:`~apf_physics.rl.dqn`
  (deep Q-learning of the thesis's window network) and :mod:`~apf_physics.rl.imitation` (the
  map network taught by A*) are the two.
- :mod:`~apf_physics.rl.progress`: a bar on a terminal, plain lines elsewhere.
- :mod:`~apf_physics.rl.evaluation`: greedy evaluation through the physics, as ``eval`` runs it.
- :mod:`~apf_physics.rl.buffer`, :mod:`~apf_physics.rl.plot`, :mod:`~apf_physics.rl.rundir`: the
  experience pool, the training curve, the locked output folder.

The network, its files and the greedy policy are in :mod:`apf_physics.models`.

Typical use::

    from apf_physics import load_world
    from apf_physics.rl import phases_for_world, preset, train
    from apf_physics.models import DQNPolicy

    config = preset("fast", seed=1)
    result = train(config, phases_for_world(load_world("worlds/fixed20.yaml"), config), out_dir="runs/fixed20")
    policy = DQNPolicy.load("runs/fixed20/best.pt")
"""

from apf_physics.rl.buffer import ReplayBuffer, ReplayBufferSamples
from apf_physics.rl.config import (
    CURRICULUM_DEFAULT,
    PRESETS,
    WORLD_DEFAULT,
    DQNConfig,
    EnvConfig,
    EvalConfig,
    ImitationConfig,
    NetworkConfig,
    RunConfig,
    ScheduleConfig,
    TrainConfig,
    epsilon_schedule,
    load_config,
    preset,
)
from apf_physics.rl.phases import Phase, phases_for_curriculum, phases_for_world
from apf_physics.rl.plot import plot_training_curve
from apf_physics.rl.learner import Counters, Learner
from apf_physics.rl.trainer import TrainResult, load_checkpoint_config, train

__all__ = [
    "CURRICULUM_DEFAULT", "Counters", "DQNConfig", "EnvConfig", "EvalConfig", "ImitationConfig", "Learner",
    "NetworkConfig", "PRESETS", "Phase", "ReplayBuffer", "ReplayBufferSamples", "RunConfig", "ScheduleConfig",
    "TrainConfig", "TrainResult", "WORLD_DEFAULT", "epsilon_schedule", "load_checkpoint_config", "load_config",
    "phases_for_curriculum", "phases_for_world", "plot_training_curve", "preset", "train",
]
