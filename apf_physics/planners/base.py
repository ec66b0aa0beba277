"""The planner interface: a policy that turns robot positions into velocity commands.

Planners know nothing of the physics. :func:`apf_physics.experiments.rollout.rollout` asks a planner
for one displacement per robot each control step, giving it the world at that step (a
:class:`~apf_physics.world.Moment`, built once per step), and hands the displacements to the
engine (:class:`~apf_physics.sim.engine.Stepper`) as velocity commands; the engine decides when
an episode ends.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from apf_physics.control.fleet import GOAL_TABLE_BUDGET, GoalTables, Lattice
from apf_physics.errors import UserError
from apf_physics.sim.engine import TrapRule
from apf_physics.world.core import Moment, World


class Planner:
    """Base class of all planners.

    Attributes:
        name: Short name used on the command line and in result tables.
        trap_rule: How the rollout decides that a robot is trapped. ``"descent"``: the
            potential stopped decreasing or the robot oscillates over a window (gradient
            descent). ``"oscillation"``: only when the robot stays within a small region
            over a window (planners that may climb the potential on purpose).
        trap_window: Control steps the trap rule looks back over; None: the rollout's
            detector's own (:class:`~apf_physics.sim.engine.TrapDetector`, 10). A planner that
            remembers where it has been sets a longer one: for it, circling one spot for a
            while is part of getting out, not proof of being stuck.
    """

    name: ClassVar[str] = "planner"
    trap_rule: ClassVar[TrapRule] = "oscillation"
    trap_window: int | None = None

    def reset(self, world: World, positions: np.ndarray) -> None:
        """Prepare for a batch of episodes in ``world`` starting at ``positions`` (N, 2)."""
        self.world = world

    def stuck(self) -> np.ndarray | None:
        """(N,) bool: robots for which the planner itself gives up (it knows it is trapped), or None."""
        return None

    def act(self, positions: np.ndarray, active: np.ndarray, moment: Moment | None = None) -> np.ndarray:
        """Return the displacement each robot should make during this control step.

        Args:
            positions: (N, 2) current robot centres in world coordinates.
            active: (N,) bool, False for robots whose episode already ended (their
                command is ignored).
            moment: The world at the control step the episodes are at (``world.at(t)``:
                where the moving obstacles are; the move is made during ``t → t + 1``), built
                once per step by the caller and used for every query of the step (its step is
                ``moment.t``). None: ``self.world.at(0)``.

        Returns:
            (N, 2) float displacements in world units per control step; each component
            in [-1, 1] (a unit move along an axis or a diagonal).
        """
        raise NotImplementedError

    def fleet_values(self, lattice: Lattice, nodes: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """(N, 9) the value of each unit move (:data:`~apf_physics.world.kinematics.ACTIONS`) of
        robots on ``lattice``'s ``nodes`` (N,), each toward its own goal node ``goals[i]`` (higher is
        better): what a fleet's rule (:func:`~apf_physics.control.fleet.fleet_moves`) ranks each
        robot's moves by. Planners that can drive a fleet override it.

        Raises:
            UserError: This planner cannot drive a fleet.
        """
        raise UserError(f"--planner {self.name}: cannot drive a fleet (fleets: dqn, mapnet, astar, gradient)")

    def goal_tables(self, lattice: Lattice) -> GoalTables:
        """This planner's per-goal tables for a fleet on ``lattice``, within
        :data:`~apf_physics.control.fleet.GOAL_TABLE_BUDGET` (new ones for another lattice)."""
        tables = self.__dict__.get("_goal_tables")
        if tables is None or tables.lattice is not lattice:
            tables = self._goal_tables = GoalTables(lattice, GOAL_TABLE_BUDGET)
        return tables

    def _moment(self, moment: Moment | None) -> Moment:
        """``moment``, or the world at step 0 when None."""
        return self.world.at(0.0) if moment is None else moment
