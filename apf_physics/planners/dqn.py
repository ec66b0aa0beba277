"""The DQN planner: greedy actions of a trained Q-network on the robot's observation.

Two kinds of network (:func:`~apf_physics.models.load_policy` tells them apart): the
thesis's, on a window of the potential (and the visit memory), with the nine unit moves; and
the map network (:mod:`apf_physics.models.mapnet`), which plans on a view of the whole map
and scores the nine moves and eight half-length ones.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from apf_physics.actions import ACTIONS, SAFETY, move_clearance
from apf_physics.models import DQNPolicy, MapPolicy, load_policy, resolve_model, shipped_model_for
from apf_physics.models.policy import move_inputs
from apf_physics.observation import Observer
from apf_physics.planners.base import Planner
from apf_physics.world import Moment, World


class DQNPlanner(Planner):
    """Each control step, the move with the highest Q-value for the robot's window.

    Args:
        model: A model file, or a shipped model's name (``general``, ``moving``, ...); by
            default the shipped model trained for the world's field.
        shield: Choose only among the moves that keep the robot :data:`~apf_physics.actions.SAFETY`
            clear of every obstacle and the map's edge all along the move
            (:func:`~apf_physics.actions.move_clearance`); when no move is, the one with the
            most room. False: the network's choice as it is (planner name ``dqn-unshielded``).
        policy: An in-memory policy to use instead of a model file (e.g. a network while it
            trains); its field is not checked against the world's.

    Observations are built by an :class:`~apf_physics.observation.Observer` with the model's
    own configuration, exactly as the environment built them in training (a model with the
    visit-memory channel gets each robot's memory, kept over the rollout and cleared in
    :meth:`reset`). A planner with a memory is declared trapped only after
    :data:`MEMORY_TRAP_WINDOW` steps around one spot.
    """

    name = "dqn"
    trap_rule = "oscillation"
    MEMORY_TRAP_WINDOW = 40
    """Trap window of a planner with a visit memory (control steps)."""

    def __init__(self, model: str | Path | None = None, shield: bool = True,
                 policy: DQNPolicy | MapPolicy | None = None):
        self.model_path = resolve_model(model) if model is not None else None
        self.shield = bool(shield)
        self.name = "dqn" if self.shield else "dqn-unshielded"
        self._policy = policy
        self._loaded = None if policy is None else "given"

    def reset(self, world: World, positions: np.ndarray) -> None:
        super().reset(world, positions)
        if self._loaded != "given":
            path = self.model_path or shipped_model_for(world)
            if self._policy is None or self._loaded != (path, id(world)):
                self._policy = load_policy(path, expect_field=world.field.as_dict())
                self._loaded = (path, id(world))
        positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        if isinstance(self._policy, MapPolicy):
            self.observer = None
            self.trap_window = self.MEMORY_TRAP_WINDOW
            return
        self.observer = Observer(self._policy.observer, len(positions), [world])
        self.observer.reset(np.arange(len(positions)), positions, [world] * len(positions))
        self.trap_window = self.MEMORY_TRAP_WINDOW if self._policy.observer.memory else None
        self._started = False

    def act(self, positions: np.ndarray, active: np.ndarray, moment: Moment | None = None) -> np.ndarray:
        moment = self._moment(moment)
        if self.observer is None:
            return self._act_on_map(positions, active, moment)
        if self._started:  # the first call sees the starts, which reset() counted already
            self.observer.visit(positions)
        self._started = True
        obs = self.observer.observe(positions, t=moment.t, discs=moment.world.crowd)
        if not self.shield:
            return ACTIONS[self._policy.act(obs)] * active[:, None]
        room = move_clearance(moment, positions) - (self.world.robot_radius + SAFETY)
        return ACTIONS[shielded_argmax(self._policy.q_values(obs), room)] * active[:, None]


    def _act_on_map(self, positions: np.ndarray, active: np.ndarray, moment: Moment) -> np.ndarray:
        """A map network's move: its best-valued one (with the shield: among the safe ones)."""
        policy = self._policy
        moves = policy.moves
        room, du = move_inputs(moment, positions, moves)
        q = policy.q_values(self.world, positions, room, du)
        chosen = shielded_argmax(q, room) if self.shield else q.argmax(axis=1)
        return moves[chosen] * active[:, None]


def shielded_argmax(q: np.ndarray, room: np.ndarray) -> np.ndarray:
    """(N,) indices of the highest ``q`` among the moves with ``room >= 0``; rows without any: the most room."""
    safe = room >= 0
    best = np.where(safe, q, -np.inf).argmax(axis=1)
    return np.where(safe.any(axis=1), best, room.argmax(axis=1))
