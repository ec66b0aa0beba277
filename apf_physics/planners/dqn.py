"""The DQN planner: greedy actions of a trained Q-network on the potential window."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from apf_physics.actions import ACTIONS
from apf_physics.errors import ModelError
from apf_physics.observation import VisitMemory, WindowSampler
from apf_physics.planners.base import Planner
from apf_physics.world import World

MODELS = Path(__file__).resolve().parent.parent / "models"
#: Shipped models, by the field they were trained for (see apf_physics/models/README.md).
SHIPPED = {"thesis-fixed": MODELS / "fixed20.pt", "thesis-general": MODELS / "general.pt"}


def shipped_model_for(world: World) -> Path:
    """The shipped model whose training field equals the world's field."""
    from apf_physics.world import FIELD_PRESETS

    for preset, path in SHIPPED.items():
        if FIELD_PRESETS[preset] == {k: v for k, v in world.field.as_dict().items()}:
            if path.exists():
                return path
    raise ModelError(f"{world.source or world.name}: no shipped model for its field {world.field.as_dict()}; "
                     f"train one with `apf-physics train` and pass --model")


class DQNPlanner(Planner):
    """Each control step, the move with the highest Q-value for the robot's window.

    Args:
        model: A model file; by default the shipped model trained for the world's field.

    A model with two observation channels (trained with ``memory=True``) also gets each
    robot's visit memory (:class:`~apf_physics.observation.VisitMemory`), kept over the
    rollout and cleared in :meth:`reset`, exactly as the environment builds it.
    """

    name = "dqn"
    trap_rule = "oscillation"

    def __init__(self, model: str | Path | None = None):
        self.model_path = Path(model) if model is not None else None
        self._policy = None

    def reset(self, world: World, positions: np.ndarray) -> None:
        from apf_physics.rl.policy import DQNPolicy

        super().reset(world, positions)
        path = self.model_path or shipped_model_for(world)
        if self._policy is None or self._loaded != (path, id(world)):
            self._policy = DQNPolicy.load(path, expect_field=world.field.as_dict())
            self._loaded = (path, id(world))
        channels, size, _ = self._policy.obs_shape
        if channels not in (1, 2):
            raise ModelError(f"{path}: model expects {channels} observation channels; the planner provides 1 or 2")
        self.sampler = WindowSampler([world], size)
        self.memory = None
        if channels == 2:
            positions = np.asarray(positions, dtype=float).reshape(-1, 2)
            self.memory = VisitMemory(len(positions), size)
            self.memory.reset(np.arange(len(positions)), positions, [world] * len(positions))
        self._started = False

    def act(self, positions: np.ndarray, active: np.ndarray) -> np.ndarray:
        obs = observe(self.sampler, self.memory, positions, self._started)
        self._started = True
        actions = self._policy.act(obs)
        return ACTIONS[actions] * active[:, None]


def observe(sampler: WindowSampler, memory: VisitMemory | None, positions: np.ndarray, moved: bool) -> np.ndarray:
    """(N, C, k, k) float32 observations of robots at ``positions``, as the environment gives them.

    With a memory, the robots' cells are counted first unless this is the first control step
    (``moved`` False: :meth:`VisitMemory.reset` counted the start cells already).
    """
    window = sampler.sample(positions, 0).astype(np.float32)[:, None]
    if memory is None:
        return window
    if moved:
        memory.visit(positions)
    return np.concatenate([window, memory.window(positions)[:, None]], axis=1)
