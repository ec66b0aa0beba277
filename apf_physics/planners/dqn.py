"""The learned planners: greedy moves of a trained network, checked by the shield.

Two kinds of network (:func:`~apf_physics.models.load_policy` tells them apart): the
thesis's deep Q-network, on a window of the potential (and the visit memory), with the nine
unit moves (planner ``window-dqn``); and the map network (:mod:`apf_physics.models.mapnet`,
planner ``mapnet``), which plans on a view of the whole map and scores the nine moves and
eight half-length ones. Planner ``dqn`` takes the best shipped one for the world's field.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from apf_physics.control.shield import (ACTIONS, HORIZON, PREDICTIONS, SAFETY, move_clearance, shield_over_time,
                                 shielded_argmax)
from apf_physics.errors import ModelError
from apf_physics.models import NETWORKS, DQNPolicy, MapPolicy, load_policy, resolve_model, shipped_model_for
from apf_physics.models.policy import move_inputs, robot_move_inputs
from apf_physics.sensing.observation import Observer
from apf_physics.common.transforms import signed_log
from apf_physics.control.fleet import STAY, Lattice, goal_columns
from apf_physics.planners.base import Planner
from apf_physics.world.core import Moment, World


class DQNPlanner(Planner):
    """Each control step, the move with the highest Q-value for the robot's window.

    Args:
        model: A model file, or a shipped model's name (``general``, ``moving``, ...); by
            default the shipped model trained for the world's field.
        shield: Choose only among the moves that keep the robot :data:`~apf_physics.control.shield.SAFETY`
            clear of every obstacle and the map's edge all along the move, the moving obstacles
            where they are predicted at each moment of it, and that some continuation keeps
            clear for :data:`~apf_physics.control.shield.HORIZON` steps
            (:func:`~apf_physics.control.shield.shield_over_time`); when no move is, the one that puts
            contact off longest. Among static obstacles alone it is the shield of one step
            (:func:`~apf_physics.control.shield.move_clearance`). False: the network's choice as it is
            (planner name ``dqn-unshielded``).
        prediction: How the shield predicts the moving obstacles (:data:`~apf_physics.control.shield.PREDICTIONS`):
            ``velocity`` (default: constant velocity from the last two steps, within
            :data:`~apf_physics.control.shield.SENSING_RADIUS`) or ``known`` (the world file's motion:
            planner name ``dqn-known``).
        horizon: Steps the shield looks ahead; 0: the shield of one step (each move against the
            obstacles where they are along it, no look-ahead; ``dqn-one-step``, for comparison).
        policy: An in-memory policy to use instead of a model file (e.g. a network while it
            trains); its field is not checked against the world's.
        network: ``"map"`` or ``"window"``: only that kind of network (planners ``mapnet`` and
            ``window-dqn``: the shipped one of that kind by default, and a model file of another
            kind is refused); None: any (``dqn``: the best shipped one for the field).

    Observations are built by an :class:`~apf_physics.sensing.observation.Observer` with the model's
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
                 policy: DQNPolicy | MapPolicy | None = None, prediction: str = "velocity",
                 horizon: int = HORIZON, network: str | None = None):
        if prediction not in PREDICTIONS:
            raise ValueError(f"unknown prediction {prediction!r} (known: {', '.join(PREDICTIONS)})")
        if network is not None and network not in NETWORKS:
            raise ValueError(f"unknown network {network!r} (known: {', '.join(NETWORKS)})")
        self.network = network
        self.model_path = resolve_model(model) if model is not None else None
        self.shield = bool(shield)
        self.prediction = prediction
        self.horizon = int(horizon)
        family = {None: "dqn", "map": "mapnet", "window": "window-dqn"}[network]
        if not self.shield:
            self.name = f"{family}-unshielded"
        elif self.horizon == 0:
            self.name = f"{family}-one-step"
        else:
            self.name = family if prediction == "velocity" else f"{family}-{prediction}"
        self._policy = policy
        self._loaded = None if policy is None else "given"

    def reset(self, world: World, positions: np.ndarray) -> None:
        super().reset(world, positions)
        if self._loaded != "given":
            path = self.model_path or shipped_model_for(world, self.network)
            if self._policy is None or self._loaded != (path, id(world)):
                self._policy = load_policy(path, expect_field=world.field.as_dict())
                self._loaded = (path, id(world))
                kind = "map" if isinstance(self._policy, MapPolicy) else "window"
                if self.network is not None and kind != self.network:
                    raise ModelError(f"{path}: holds {NETWORKS[kind]}, not {NETWORKS[self.network]} "
                                     f"(planner {self.name}); use --planner dqn for any kind")
        positions = np.asarray(positions, dtype=float).reshape(-1, 2)
        if isinstance(self._policy, MapPolicy):
            self.observer = None
            self.trap_window = self.MEMORY_TRAP_WINDOW
            return
        self.observer = Observer(self._policy.observer, len(positions), [world])
        self.observer.reset(np.arange(len(positions)), positions, [world] * len(positions))
        self.trap_window = self.MEMORY_TRAP_WINDOW if self._policy.observer.memory else None
        self._started = False

    def describe(self) -> str:
        """Which network ran, for tables: e.g. ``"dqn: the map network (map.pt)"``."""
        if self._loaded is None:
            return f"{self.name}: no model loaded yet"
        source = "a network in memory" if self._loaded == "given" else Path(self._loaded[0]).name
        return f"{self.name}: {NETWORKS[self.network_kind]} ({source})"

    @property
    def policy(self) -> DQNPolicy | MapPolicy | None:
        """The greedy policy of the network loaded (None before :meth:`reset`)."""
        return self._policy

    @property
    def network_kind(self) -> str | None:
        """``"map"`` or ``"window"``: the kind of network loaded (None before :meth:`reset`)."""
        if self._policy is None:
            return None
        return "map" if isinstance(self._policy, MapPolicy) else "window"

    def act(self, positions: np.ndarray, active: np.ndarray, moment: Moment | None = None) -> np.ndarray:
        moment = self._moment(moment)
        if self.observer is None:
            return self._act_on_map(positions, active, moment)
        if self._started:  # the first call sees the starts, which reset() counted already
            self.observer.visit(positions)
        self._started = True
        obs = self.observer.observe(positions, t=moment.t, discs=moment.world.others)
        if not self.shield:
            return ACTIONS[self._policy.act(obs)] * active[:, None]
        q = self._policy.q_values(obs)
        if self.horizon == 0:   # each move against the obstacles where they are along it, no look-ahead
            room = move_clearance(moment, positions) - (self.world.robot_radius + SAFETY)
            return ACTIONS[shielded_argmax(q, room)] * active[:, None]
        return ACTIONS[shield_over_time(moment, positions, ACTIONS, q, self.prediction, self.horizon)] * active[:, None]


    def fleet_values(self, lattice: Lattice, nodes: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """The map network's action values of the nine unit moves of each robot of a fleet, toward its
        own goal: its values for that goal (planned once per goal, read at the lattice's nodes and kept
        within the budget of :meth:`goal_tables`), the room of each move on the lattice and the change of
        the robot's own U, scored by the network's head. No robot consults a search while it acts.

        Raises:
            ModelError: The model is a window network (it sees one robot's field in a window; a fleet's
                values are the map network's).
        """
        if not isinstance(self._policy, MapPolicy):
            raise ModelError(f"{self.describe()}: a fleet is driven by the map network (--model map, the "
                             "default on Table 4's field), not a window network")
        policy = self._policy
        everywhere = lattice.points(np.arange(lattice.count))
        tables = self.goal_tables(lattice)
        build = lambda goal: policy.node_values(lattice.world, lattice.points([goal])[0], everywhere)  # noqa: E731
        there = goal_columns(tables, nodes, goals, build)
        here = there[:, STAY]
        ends = lattice.ends(nodes)
        u = lattice.potential(ends, goals)
        du = signed_log(u - u[:, STAY:STAY + 1]) / 4.0
        return policy.move_scores(here, there, ACTIONS, lattice.room[nodes], du)

    def _act_on_map(self, positions: np.ndarray, active: np.ndarray, moment: Moment) -> np.ndarray:
        """A map network's move: its best-valued one (with the shield: among the safe ones)."""
        policy = self._policy
        if policy.on_nodes:
            return self._act_on_nodes(positions, active, moment)
        moves = policy.moves
        room, du = move_inputs(moment, positions, moves)
        q = policy.q_values(self.world, positions, room, du)
        if not self.shield:
            return moves[q.argmax(axis=1)] * active[:, None]
        if not self.world.moving or self.horizon == 0:   # its room input is the one-step shield's
            return moves[shielded_argmax(q, room)] * active[:, None]
        return moves[shield_over_time(moment, positions, moves, q, self.prediction, self.horizon)] * active[:, None]

    def _act_on_nodes(self, positions: np.ndarray, active: np.ndarray, moment: Moment) -> np.ndarray:
        """A node-graph network's move: each robot's own moves (to the nodes within one step of it)
        scored, the best taken (with the shield: among the safe ones)."""
        policy = self._policy
        positions = np.asarray(positions, float).reshape(-1, 2)
        candidates = moves, usable, _ = policy.candidates(self.world, positions)
        room, du = robot_move_inputs(moment, positions, moves)
        room = np.where(usable, room, -np.inf)
        q = policy.q_values(self.world, positions, room, du, candidates)
        rows = np.arange(len(positions))
        if not self.shield:
            choice = q.argmax(axis=1)
        elif not self.world.moving or self.horizon == 0:
            choice = shielded_argmax(q, room)
        else:   # the shield over time takes one set of moves: robots with the same ones together
            choice = np.zeros(len(positions), np.intp)
            key = np.round(moves.reshape(len(positions), -1), 6)
            _, group = np.unique(key, axis=0, return_inverse=True)
            for g in np.unique(group):
                members = np.flatnonzero(group.ravel() == g)
                choice[members] = shield_over_time(moment, positions[members], moves[members[0]], q[members],
                                                   self.prediction, self.horizon)
        return moves[rows, choice] * active[:, None]


__all__ = ["DQNPlanner", "shielded_argmax"]
