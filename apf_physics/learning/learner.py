"""What the training loop asks of a learning method: :class:`Learner`, and where a run stands (:class:`Counters`).

The loop (:func:`apf_physics.learning.trainer.train`) is the same for every method: it walks the
phases, redraws the generated pool, evaluates, keeps ``best.pt``, writes checkpoints, logs and
decides when to stop. A method plugs in as a :class:`Learner`: it collects experience, learns
from it, gives its network as a planner to evaluate, and saves and restores its own state.
The two learners are :class:`apf_physics.learning.dqn.DQNLearner` (deep Q-learning of the window
network) and :class:`apf_physics.learning.imitation.ImitationLearner` (the map network taught by A*).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np
import torch

from apf_physics.sensing.observation import ObserverConfig
from apf_physics.planners.dqn import DQNPlanner
from apf_physics.learning.phases import Phase
from apf_physics.world.core import World


@dataclass
class Counters:
    """Where a run stands (saved in every checkpoint)."""

    global_step: int = 0
    """Steps: transitions collected (DQN) or updates made (imitation)."""
    episodes: int = 0
    """Searches finished (imitation: positions labelled)."""
    vector_steps: int = 0
    """Calls of :meth:`Learner.collect`."""
    phase: int = 0
    """Index of the current phase (``len(phases)``: all done)."""
    phase_steps: int = 0
    phase_episodes: int = 0
    pool_draws: int = 0
    wall_time: float = 0.0
    """Seconds of training over all sessions, up to the checkpoint."""
    best_step: Optional[int] = None
    """Steps at the best evaluation."""
    top_success: Optional[float] = None
    """Highest success on the validation starts of an evaluation that also met ``target_world_starts`` where it
    applies (what ``target_success`` is compared with)."""
    time_to_target: Optional[float] = None
    """Wall time at which an evaluation first met the targets (``target_success``, with ``target_world_starts``)."""
    last_eval_step: Optional[int] = None
    diverged: Optional[float] = None
    """The logged mean loss that stopped the run as diverged (None: it has not)."""

    def advance(self, steps: int, episodes: int) -> None:
        """Count what one :meth:`Learner.collect` added."""
        self.global_step += steps
        self.episodes += episodes
        self.phase_steps += steps
        self.phase_episodes += episodes
        self.vector_steps += 1


class Learner(abc.ABC):
    """A learning method, as the training loop drives it.

    Per step of the loop: :meth:`collect` then :meth:`update`. A segment of steps (from one
    checkpoint, phase change or pool redraw to the next) is opened by :meth:`begin` and closed
    by :meth:`end`. Both learners draw every random number from the ``rng`` the loop passes
    (and torch's global generator), which the checkpoints save, so a resumed run continues as
    the uninterrupted one.
    """

    network: torch.nn.Module
    """The network being trained (what ``best.pt`` holds)."""
    observer: Optional[ObserverConfig]
    """How its observations are built, saved in model files (None: the network reads the world's map)."""

    updates: int
    """Gradient updates made."""
    epsilon: Optional[float] = None
    """The exploration rate of the latest step, for the progress display (None: the learner does not explore)."""

    @abc.abstractmethod
    def begin(self, worlds: Sequence[World], phase: Phase, seed: tuple[int, int]) -> None:
        """A segment starts on ``worlds`` (the phase's and the generated pool's); ``seed`` seeds its environments."""

    @abc.abstractmethod
    def collect(self, c: Counters, rng: np.random.Generator) -> tuple[int, int]:
        """Gather experience for one step; returns the steps and the episodes it adds to the counters."""

    @abc.abstractmethod
    def update(self, c: Counters, rng: np.random.Generator) -> None:
        """Learn from what was collected (after the counters have advanced)."""

    def end(self) -> None:
        """A segment ends (close its environments)."""

    @abc.abstractmethod
    def planner(self, shield: bool) -> DQNPlanner:
        """The network as ``apf-physics eval --planner dqn`` (or ``dqn-unshielded``) runs it."""

    @abc.abstractmethod
    def log_values(self, c: Counters) -> dict[str, Any]:
        """``epsilon``, ``mean_return`` and ``training_success`` (of the recent training episodes) and
        ``loss`` (mean since the last call; None: no updates) for a row of ``train.csv``; ``""`` where the
        method has no such figure."""

    @abc.abstractmethod
    def state(self, with_buffer: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        """What a checkpoint keeps: plain values (JSON) and tensors (``with_buffer``: the experience pool too)."""

    @abc.abstractmethod
    def load(self, state: dict[str, Any], tensors: dict[str, Any]) -> None:
        """Restore from :meth:`state`'s output."""
