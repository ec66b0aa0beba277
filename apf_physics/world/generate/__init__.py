"""Random worlds where gradient descent tends to get trapped, for training and held-out tests.

Every family places its obstacles between the starts and the target, which is where APF
local minima arise (thesis Fig. 1). :func:`generate_world` draws a world of any family
(:data:`ALL_FAMILIES`); each kind of family has a module of its own:

- :mod:`~apf_physics.world.generate.static` (:data:`FAMILIES`): ``point``, ``line``, ``two_points``,
  ``concave``, ``bent_line``, ``clutter``: a few obstacles across an axis from the target
  toward the starts, the starts behind them.
- :mod:`~apf_physics.world.generate.moving` (:data:`MOVING_FAMILIES`): ``moving``, one of the
  static families plus 3–8 moving obstacles whose routes cross the axis.
- :mod:`~apf_physics.world.generate.crossing` (:data:`FORMATION_FAMILIES`): ``crossing``, 2–4
  formations whose routes cross near the middle of the map (the world file's ``formations:``).
- :mod:`~apf_physics.world.generate.scaled` (:data:`SCALED_FAMILIES`): ``pillars``, ``doors``,
  ``rescaled``: a robot of 0.1 to 3 steps in radius, worlds in units of their own (``robot:
  {radius, step}``); pillars on a lattice (BARN-like), doors barely wider than the robot, and
  the static and structure families at another scale.
- :mod:`~apf_physics.world.generate.structures` (:data:`STRUCTURE_FAMILIES`): ``rooms``,
  ``maze``, ``nested_cups``, ``narrow_gap``, ``dense_clutter``, ``mixed``: larger structures
  with every start out of the target's sight, built from the blocks of
  :mod:`~apf_physics.world.generate.blocks`.

The pieces they share: :mod:`~apf_physics.world.generate.common` (the robot, tolerances, attempts,
rounding and checks of obstacle mappings) and :mod:`~apf_physics.world.generate.shapes` (obstacle
shapes in an axis frame, thick polylines, clipping to the map).

Every world goes through :func:`~apf_physics.world.io.worldfile.world_from_dict` (so it honours the
world-file contract), and every start is reachable: a path with the robot's clearance
exists (:func:`apf_physics.world.search.reachable`). Generation is deterministic for a seed.

:func:`generate_world` is fast enough for domain randomisation during training (no
rollouts); :func:`apf_physics.experiments.worldsets.generate_set` writes files and a manifest that
labels each start with whether gradient descent reaches the target from it and the A* path
length.
"""

from __future__ import annotations

import numpy as np

from apf_physics.errors import UserError
from apf_physics.world.field import FIELD_PRESETS
from apf_physics.world.generate.blocks import CUP_SPACING, DOOR_WIDTH, TARGET_CLEARANCE
from apf_physics.world.generate.common import GOAL_TOLERANCE, MAX_ATTEMPTS, ROBOT_RADIUS, START_CLEARANCE
from apf_physics.world.generate.crossing import FORMATION_FAMILIES, crossing_world
from apf_physics.world.generate.moving import MOVING_FAMILIES, moving_world
from apf_physics.world.generate.scaled import SCALED_FAMILIES, scaled_world
from apf_physics.world.generate.static import FAMILIES, STATIC_FAMILIES, static_world
from apf_physics.world.generate.structures import (GAP_WIDTH, PATH_SHARE, START_SPACING, STRUCTURE_ATTEMPTS,
                                             STRUCTURE_FAMILIES, STRUCTURE_ROBOT_RADIUS, Drawn, step_limit,
                                             structure_world)
from apf_physics.world.core import World

__all__ = [
    "ALL_FAMILIES", "CUP_SPACING", "DOOR_WIDTH", "Drawn", "FAMILIES", "FORMATION_FAMILIES", "GAP_WIDTH",
    "GOAL_TOLERANCE", "MAX_ATTEMPTS", "MOVING_FAMILIES", "PATH_SHARE", "ROBOT_RADIUS", "SCALED_FAMILIES", "START_CLEARANCE",
    "START_SPACING", "STATIC_FAMILIES", "STRUCTURE_ATTEMPTS", "STRUCTURE_FAMILIES", "STRUCTURE_ROBOT_RADIUS",
    "TARGET_CLEARANCE", "generate_world", "step_limit",
]

ALL_FAMILIES = FAMILIES + MOVING_FAMILIES + FORMATION_FAMILIES + STRUCTURE_FAMILIES + SCALED_FAMILIES
"""Every family :func:`generate_world` draws."""


def generate_world(family: str, rng: np.random.Generator, size: float = 50, field: str = "thesis-general",
                   n_starts: int = 4, name: str | None = None) -> World:
    """Draw one world of ``family`` with ``n_starts`` reachable starts behind its obstacles.

    Fast (no rollouts, only the reachability check), so training can call it for domain
    randomisation.

    Args:
        family: One of :data:`ALL_FAMILIES`.
        rng: The random generator (the world is a deterministic function of its state).
        size: Width and height of the square map [units].
        field: A field preset name from :data:`~apf_physics.world.FIELD_PRESETS`.
        n_starts: Number of starts.
        name: The world's name (default: the family's name).

    Raises:
        UserError: unknown family or field preset, or no valid world found in
            :data:`MAX_ATTEMPTS` draws (the map is too small for the family).
    """
    if family not in ALL_FAMILIES:
        raise UserError(f"--family: unknown family {family!r} (known: {', '.join(ALL_FAMILIES)})")
    if family in FORMATION_FAMILIES:
        return crossing_world(rng, float(size), field, name)
    if field not in FIELD_PRESETS:
        raise UserError(f"--field: unknown field preset {field!r} (known: {', '.join(FIELD_PRESETS)})")
    if family in STRUCTURE_FAMILIES:
        return structure_world(family, rng, float(size), field, n_starts, name)
    if family in MOVING_FAMILIES:
        return moving_world(rng, float(size), field, n_starts, name)
    if family in SCALED_FAMILIES:
        return scaled_world(family, rng, float(size), field, n_starts, name)
    return static_world(family, rng, float(size), field, n_starts, name)
