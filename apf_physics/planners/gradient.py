"""Gradient descent in the potential field (Model eq. 13–14), the classic baseline."""

from __future__ import annotations

import numpy as np

from apf_physics.control.fleet import Lattice
from apf_physics.planners.base import Planner
from apf_physics.world.core import Moment


class GradientPlanner(Planner):
    """Each control step, a unit step along the force ``−∇U/‖∇U‖``.

    When the unit step would not lower U, half and quarter steps are tried; when none does,
    the robot is at a local minimum of U (at this resolution) and the planner reports it
    trapped through :meth:`stuck`.

    It gets trapped wherever the field has a minimum that is not a target (thesis Fig. 1,
    Fig. 22); the rollout detects that with the ``"descent"`` trap rule.
    """

    name = "gradient"
    trap_rule = "descent"
    backtracking = (1.0, 0.5, 0.25)  # step lengths tried, longest first

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
        for factor in self.backtracking:
            if not pending.any():
                break
            scale[pending] = factor
            there = moment.potential(positions[pending] + factor * step[pending])
            idx = np.flatnonzero(pending)
            pending[idx[there < here[idx]]] = False
        self._stuck = active & (pending | ~moving)
        step *= scale[:, None]
        step[self._stuck] = 0.0
        return step
