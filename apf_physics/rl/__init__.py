"""Deep Q-learning for potential-field navigation: the thesis's Q-network, its training and its files.

Typical use::

    from apf_physics import load_world
    from apf_physics.rl import preset, train, DQNPolicy

    result = train(preset("fast", seed=1), load_world("worlds/fixed20.yaml"), out_dir="runs/fixed20")
    policy = DQNPolicy.load(result.best_path)
    actions = policy.act(observations)          # (N, C, k, k) float32 -> (N,) int
"""

from apf_physics.rl.buffer import ReplayBuffer, ReplayBufferSamples
from apf_physics.models.files import FORMAT_VERSION, SavedModel, load_model, save_model
from apf_physics.rl.dqn import (
    PRESETS,
    DQNConfig,
    EvalResult,
    TrainResult,
    epsilon_schedule,
    evaluate_greedy,
    load_checkpoint_config,
    preset,
    train,
)
from apf_physics.models.network import QNetwork, max_pool_2x2_stride1, relative_log
from apf_physics.rl.plot import plot_training_curve
from apf_physics.models.policy import DQNPolicy

__all__ = [
    "DQNConfig", "DQNPolicy", "EvalResult", "FORMAT_VERSION", "PRESETS", "QNetwork", "ReplayBuffer",
    "ReplayBufferSamples", "SavedModel", "TrainResult", "epsilon_schedule", "evaluate_greedy",
    "load_checkpoint_config", "load_model", "max_pool_2x2_stride1", "plot_training_curve", "preset",
    "relative_log", "save_model", "train",
]
