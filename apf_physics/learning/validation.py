"""Greedy evaluation of a network while it trains: the planner run through the physics, as ``eval`` runs it.

A network is evaluated as :class:`~apf_physics.planners.dqn.DQNPlanner` on an
:class:`EvalSet` (worlds, each with its starts, and a label per start) by
:func:`apf_physics.experiments.evaluate.evaluate`, the same episodes ``apf-physics eval --planner dqn``
(or ``dqn-unshielded``) would give for that network. :func:`summarise` turns the episodes
into the figures of :data:`~apf_physics.learning.config.EVAL_FIGURES`, and :func:`score` orders
summaries by :attr:`~apf_physics.learning.config.TrainConfig.select`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from apf_physics.experiments.evaluate import evaluate, figures
from apf_physics.models.network import QNetwork
from apf_physics.models.policy import DQNPolicy
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.experiments.rollout import Episode
from apf_physics.world.core import World
from apf_physics.experiments.worldsets import label_starts


@dataclass(frozen=True)
class EvalSet:
    """Worlds a network is evaluated on, from each world's own starts, with a label per start (or none).

    Attributes:
        worlds: The worlds (names unique).
        trapped: (N,) bool over all starts in order: gradient descent does not reach the target
            (None: not labelled; no ``trap_success``).
        astar: (N,) float: the A* path length from the start (nan: none; None: not labelled, no
            ``length_ratio`` or ``spl``).
    """

    worlds: tuple[World, ...]
    trapped: Optional[np.ndarray]
    astar: Optional[np.ndarray]

    @classmethod
    def of(cls, worlds: Sequence[World]) -> "EvalSet":
        """Label every start of ``worlds`` (:func:`~apf_physics.experiments.worldsets.label_starts`: a gradient rollout and A*)."""
        labels = [label for world in worlds for label in label_starts(world)]
        return cls(tuple(worlds), np.array([s["gradient_trapped"] for s in labels], bool),
                   np.array([np.nan if s["astar_length"] is None else s["astar_length"] for s in labels], float))

    @classmethod
    def unlabelled(cls, worlds: Sequence[World]) -> "EvalSet":
        """The starts of ``worlds`` without labels: only ``success`` and ``collisions`` are figured
        (labelling a thousand starts costs seconds of A* and gradient rollouts)."""
        return cls(tuple(worlds), None, None)

    @property
    def starts(self) -> int:
        return len(self.trapped) if self.trapped is not None else sum(len(w.starts) for w in self.worlds)


def run(network: QNetwork, observer: ObserverConfig, evalset: EvalSet, shield: bool) -> list[Episode]:
    """One greedy episode from every start, through the physics (``apf-physics eval --planner dqn``)."""
    was_training = network.training
    planner = DQNPlanner(policy=DQNPolicy(network, observer), shield=shield)
    try:
        return evaluate(planner, evalset.worlds).episodes
    finally:
        network.train(was_training)


def summarise(episodes: Sequence[Episode], evalset: EvalSet) -> dict[str, Optional[float]]:
    """The figures of one evaluation.

    Returns:
        ``success`` (share of starts reaching the target), ``trap_success`` (the same over the
        starts where gradient descent is trapped; None without any), ``collisions`` (episodes
        ending in one), ``length_ratio`` (summed path length over summed A* length, both over
        the successes; None without any) and ``spl``, success weighted by path length (Anderson
        et al. 2018: the mean over all starts of ``A* / max(path, A*)`` for a success, else 0):
        :func:`apf_physics.experiments.evaluate.figures` with the A* lengths and trap labels
        (an unlabelled set: ``trap_success``, ``length_ratio`` and ``spl`` are None).
    """
    scored = figures(episodes, optimal=evalset.astar, trapped=evalset.trapped)
    return {
        "success": scored.success_rate,
        "trap_success": scored.trap_success,
        "collisions": scored.collisions,
        "length_ratio": scored.length_ratio,
        "spl": scored.spl,
    }


def score(summary: dict[str, Optional[float]], select: Sequence[str]) -> tuple[float, ...]:
    """The sort key of a summary: each figure of ``select`` (``-name``: negated), rounded; a missing figure ranks lowest."""
    key = []
    for name in select:
        sign = -1.0 if name.startswith("-") else 1.0
        value = summary.get(name.lstrip("-"))
        key.append(-np.inf if value is None else round(sign * float(value), 6))
    return tuple(key)
