"""Gradient descent in the potential field (Model eq. 13–14), the classic baseline."""

from __future__ import annotations

import numpy as np

from apf_physics.control.fleet import Lattice
from apf_physics.planners.base import Planner
from apf_physics.world.core import Moment


class GradientPlanner(Planner):
    """Each control step, a unit step along the force ``−∇U/‖∇U‖``.

    A step is taken when U is lower all along it (at :data:`SAMPLES` points, its end included)
    than where it starts; when the unit step is not, half and quarter steps are tried; when none
    is, the robot is at a local minimum of U (at this resolution) and the planner reports it
    trapped through :meth:`stuck`. The field reads its cap wherever the robot would touch an
    obstacle (Model §1): a step that would graze a corner on its way is not a descent.

    It gets trapped wherever the field has a minimum that is not a target (thesis Fig. 1,
    Fig. 22); the rollout detects that with the ``"descent"`` trap rule.
    """

    name = "gradient"
    trap_rule = "descent"
    backtracking = (1.0, 0.5, 0.25)  # step lengths tried, longest first
    SAMPLES = 4
    """Points along a step (evenly spaced, its end the last) where U must be below its start's."""

    def reset(self, world, positions):
        super().reset(world, positions)
        self._stuck = np.zeros(len(positions), bool)

    def stuck(self) -> np.ndarray:
        """Robots whose next unit step would not lower the potential: a local minimum at this step size."""
        return self._stuck

    def fleet_values(self, lattice: Lattice, nodes: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """Gradient descent on a fleet's lattice: the moves that lower each robot's own U the most
        (its target's attraction and well, the static obstacles' repulsion) rank first."""
        return -lattice.potential(lattice.ends(nodes), goals)

    def act(self, positions: np.ndarray, active: np.ndarray, moment: Moment | None = None) -> np.ndarray:
        moment = self._moment(moment)
        grad = moment.gradient(positions)
        norm = np.hypot(grad[:, 0], grad[:, 1])
        step = np.zeros_like(grad)
        moving = active & (norm > 1e-12)
        step[moving] = -grad[moving] / norm[moving, None]
        # Eq. 14 stops making progress where a unit step no longer lowers U: in front of an
        # obstacle that the target lies behind, the step would land in its repulsion. Before
        # calling that trapped, halve the step (backtracking) so that a minimum that is a
        # target, a little off the unit lattice, is still reached.
        here = moment.potential(positions)
        scale = np.ones(len(positions))
        pending = moving.copy()
        along = np.arange(1, self.SAMPLES + 1) / self.SAMPLES
        for factor in self.backtracking:
            if not pending.any():
                break
            scale[pending] = factor
            idx = np.flatnonzero(pending)
            points = positions[idx, None, :] + factor * along[None, :, None] * step[idx, None, :]
            there = moment.potential(points.reshape(-1, 2)).reshape(len(idx), -1)
            pending[idx[np.all(there < here[idx, None], axis=1)]] = False
        self._stuck = active & (pending | ~moving)
        step *= scale[:, None]
        step[self._stuck] = 0.0
        return step
