"""Training the thesis's Q-network with deep Q-learning: one configuration, phases, one loop.

- :mod:`~apf_physics.rl.config`: :class:`TrainConfig` and its named presets.
- :mod:`~apf_physics.rl.phases`: what is trained, in order (a world is one phase; a curriculum
  one per stage, then generated worlds).
- :mod:`~apf_physics.rl.trainer`: the loop, :func:`train`.
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
    TrainConfig,
    epsilon_schedule,
    preset,
)
from apf_physics.rl.phases import Phase, phases_for_curriculum, phases_for_world
from apf_physics.rl.plot import plot_training_curve
from apf_physics.rl.trainer import TrainResult, load_checkpoint_config, train

__all__ = [
    "CURRICULUM_DEFAULT", "PRESETS", "Phase", "ReplayBuffer", "ReplayBufferSamples", "TrainConfig", "TrainResult",
    "WORLD_DEFAULT", "epsilon_schedule", "load_checkpoint_config", "phases_for_curriculum", "phases_for_world",
    "plot_training_curve", "preset", "train",
]
