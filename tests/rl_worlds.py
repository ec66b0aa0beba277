"""A tiny world for the trainer's tests: 8×8, one wall between most starts and the target.

Small enough that the ``fast`` recipe, scaled down, learns it in seconds, and with starts
from which gradient descent is trapped behind the wall, so learning it is not just descent.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from apf_physics.world.core import World
from apf_physics.world.io.worldfile import world_from_dict

TINY = {
    "name": "tiny",
    "size": [8, 8],
    "robot_radius": 0.25,
    "goal_tolerance": 0.75,
    "field": {"katt": 2, "krep": 20, "kstr": 8, "p0": 0.5, "ps": 8, "u_max": 100},
    "obstacles": [{"polygon": [[3.5, 1.5], [4.5, 1.5], [4.5, 5.5], [3.5, 5.5]]}],
    "targets": [[6.5, 4.5]],
    "starts": [[1.5, 4.5], [1.5, 1.5], [1.5, 6.5], [2.5, 3.5], [6.5, 0.5], [5.5, 7.5]],
}
"""The world; from its first, second and fourth starts gradient descent is trapped behind the wall."""

TINY_OPTIONS = dict(obs_size=5, filters=(8, 8), num_envs=16, batch_size=64, learning_starts=200,
                    exploration_episodes=300, max_episode_steps=30, train_starts="random",
                    total_steps=3_000, eval_every=1_000, log_every=500, checkpoint_every=1_000,
                    eval_random_starts=0, select=("success", "world_starts_success"), target_success=1.0)
"""The ``fast`` preset scaled to the tiny world."""


def tiny_world() -> World:
    return world_from_dict(TINY)


def write_tiny_world(folder: Path) -> Path:
    path = Path(folder) / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY), encoding="utf-8")
    return path
