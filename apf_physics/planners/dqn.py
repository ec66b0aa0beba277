"""The DQN planner: greedy actions of a trained Q-network on the potential window."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from apf_physics.actions import ACTIONS, SAFETY, move_clearance
from apf_physics.errors import ModelError
from apf_physics.observation import VisitMemory, WindowSampler
from apf_physics.planners.base import Planner
from apf_physics.world import World

if TYPE_CHECKING:
    from apf_physics.rl.policy import DQNPolicy

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
        shield: Choose only among the moves that keep the robot :data:`~apf_physics.actions.SAFETY`
            clear of every obstacle and the map's edge all along the move
            (:func:`~apf_physics.actions.move_clearance`); when no move is, the one with the
            most room. False: the network's choice as it is (planner name ``dqn-unshielded``).
        policy: An in-memory policy to use instead of a model file (e.g. a network while it
            trains); its field is not checked against the world's.

    A model with two observation channels (trained with ``memory=True``) also gets each
    robot's visit memory (:class:`~apf_physics.observation.VisitMemory`), kept over the
    rollout and cleared in :meth:`reset`, exactly as the environment builds it. Such a
    planner is declared trapped only after :data:`MEMORY_TRAP_WINDOW` steps around one spot.
    """

    name = "dqn"
    trap_rule = "oscillation"
    MEMORY_TRAP_WINDOW = 40
    """Trap window of a planner with a visit memory (control steps)."""

    def __init__(self, model: str | Path | None = None, shield: bool = True, policy: "DQNPolicy | None" = None):
        self.model_path = Path(model) if model is not None else None
        self.shield = bool(shield)
        self.name = "dqn" if self.shield else "dqn-unshielded"
        self._policy = policy
        self._loaded = None if policy is None else "given"

    def reset(self, world: World, positions: np.ndarray) -> None:
        from apf_physics.rl.policy import DQNPolicy

        super().reset(world, positions)
        if self._loaded != "given":
            path = self.model_path or shipped_model_for(world)
            if self._policy is None or self._loaded != (path, id(world)):
                self._policy = DQNPolicy.load(path, expect_field=world.field.as_dict())
                self._loaded = (path, id(world))
        channels, size, _ = self._policy.obs_shape
        if channels not in (1, 2):
            raise ModelError(f"{self.model_path or 'model'}: expects {channels} observation channels; "
                             "the planner provides 1 or 2")
        self.sampler = WindowSampler([world], size)
        self.memory = None
        self.trap_window = None
        if channels == 2:
            positions = np.asarray(positions, dtype=float).reshape(-1, 2)
            self.memory = VisitMemory(len(positions), size)
            self.memory.reset(np.arange(len(positions)), positions, [world] * len(positions))
            self.trap_window = self.MEMORY_TRAP_WINDOW
        self._started = False

    def act(self, positions: np.ndarray, active: np.ndarray) -> np.ndarray:
        obs = observe(self.sampler, self.memory, positions, self._started)
        self._started = True
        if not self.shield:
            return ACTIONS[self._policy.act(obs)] * active[:, None]
        room = move_clearance(self.world, positions) - (self.world.robot_radius + SAFETY)
        return ACTIONS[shielded_argmax(self._policy.q_values(obs), room)] * active[:, None]


def shielded_argmax(q: np.ndarray, room: np.ndarray) -> np.ndarray:
    """(N,) indices of the highest ``q`` among the moves with ``room >= 0``; rows without any: the most room."""
    safe = room >= 0
    best = np.where(safe, q, -np.inf).argmax(axis=1)
    return np.where(safe.any(axis=1), best, room.argmax(axis=1))


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
