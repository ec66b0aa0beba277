"""Training the planners' networks: one typed configuration, phases, one loop, two learners.

- :mod:`~apf_physics.learning.config`: :class:`TrainConfig` (a section per concern) and its named presets.
- :mod:`~apf_physics.learning.phases`: what is trained, in order (a world is one phase; a curriculum
  one per stage, then generated worlds).
- :mod:`~apf_physics.learning.trainer`: the loop, :func:`train`, for every learner.
- :mod:`~apf_physics.learning.learner`: what the loop asks of a learner; :mod:`~apf_physics.learning.dqn`
  (deep Q-learning of the thesis's window network) and :mod:`~apf_physics.learning.imitation` (the
  map network taught by A*) are the two.
- :mod:`~apf_physics.learning.progress`: a bar on a terminal, plain lines elsewhere.
- :mod:`~apf_physics.learning.validation`: greedy evaluation through the physics, as ``eval`` runs it.
- :mod:`~apf_physics.learning.buffer`, :mod:`~apf_physics.learning.plot`, :mod:`~apf_physics.learning.rundir`: the
  experience pool, the training curve, the locked output folder.

The network, its files and the greedy policy are in :mod:`apf_physics.models`.

Typical use::

    from apf_physics import load_world
    from apf_physics.learning import phases_for_world, preset, train
    from apf_physics.models import DQNPolicy

    config = preset("fast", seed=1)
    result = train(config, phases_for_world(load_world("worlds/fixed20.yaml"), config), out_dir="runs/fixed20")
    policy = DQNPolicy.load("runs/fixed20/best.pt")
"""

from apf_physics.learning.buffer import ReplayBuffer, ReplayBufferSamples
from apf_physics.learning.config import (
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
from apf_physics.learning.phases import Phase, phases_for_curriculum, phases_for_world
from apf_physics.learning.plot import plot_training_curve
from apf_physics.learning.learner import Counters, Learner
from apf_physics.learning.trainer import TrainResult, load_checkpoint_config, train

__all__ = [
    "CURRICULUM_DEFAULT", "Counters", "DQNConfig", "EnvConfig", "EvalConfig", "ImitationConfig", "Learner",
    "NetworkConfig", "PRESETS", "Phase", "ReplayBuffer", "ReplayBufferSamples", "RunConfig", "ScheduleConfig",
    "TrainConfig", "TrainResult", "WORLD_DEFAULT", "epsilon_schedule", "load_checkpoint_config", "load_config",
    "phases_for_curriculum", "phases_for_world", "plot_training_curve", "preset", "train",
]
