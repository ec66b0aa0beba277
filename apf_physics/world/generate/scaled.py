"""Families at every scale (:data:`SCALED_FAMILIES`): a robot of any size against its step, gaps barely wider than it.

The other families draw a robot of radius 0.25 or 0.3 steps. A robot that moves a tenth of its
radius per control step, or three radii, meets the same walls at another scale, and a learned
planner must work at all of them. Each world here is written in units of its own (the robot's
radius, or a lattice's pitch) with ``robot: {radius, step}``, the step drawn so that the robot's
radius is 0.1 to 3 steps (log-uniform, :data:`RADIUS_STEPS`), as a user's world in metres is.
``size`` bounds the map's longer side in steps (a draw that would be larger takes a smaller
robot-to-step ratio).

- ``pillars``: a field of discs on a square lattice, touching where they are neighbours, grown by
  a cellular automaton (fill 3–25 % left as it is, or 30–50 % smoothed 1–3 times); walls of touching discs along its
  sides and below it, now and then left out; the starts in an open stretch below the field, the
  target beyond it, in the open. The robot is 1.05–1.9 lattice pitches in radius, so gaps of
  three to five empty places are the ones that matter, as in BARN (Perille et al. 2020), whose
  worlds this family resembles; they are never read or trained on.
- ``doors``: a building of 2 × 2 up to 4 × 4 rooms filling the map, walls 0.2–1.2 radii thick,
  with doors only 0.15 to 1.5 radii wider than the robot (a spanning tree of doors, a few more for
  loops) at any place along their walls; the target in one room, the starts in the others.
- ``rescaled``: a world of one of the static or structure families, drawn at its own scale and
  written with a step that puts the robot's radius at 0.1–3 steps.

Every start is reachable on the A* grid at the world's scale (:mod:`apf_physics.world.search`).
"""

from __future__ import annotations

import math

import numpy as np

from apf_physics.errors import UserError
from apf_physics.world.generate.common import MAX_ATTEMPTS, round_coordinates
from apf_physics.world.generate.static import FAMILIES, static_world
from apf_physics.world.generate.structures import STRUCTURE_FAMILIES, structure_world
from apf_physics.world.search import SearchGrid
from apf_physics.world.core import World
from apf_physics.world.io.units import world_to_file
from apf_physics.world.io.worldfile import world_from_dict

SCALED_FAMILIES = ("pillars", "doors", "rescaled")
"""The families at every scale."""
RADIUS_STEPS = (0.1, 3.0)
"""The robot's radius in steps is drawn log-uniformly from this range."""


def _radius_steps(rng: np.random.Generator, longest: float, size: float) -> float:
    """A robot radius in steps from :data:`RADIUS_STEPS`, no larger than puts a map whose longer side
    is ``longest`` robot radii over ``size`` steps."""
    low, high = RADIUS_STEPS
    high = max(low, min(high, size / longest))
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _reachable_starts(world: World, candidates: np.ndarray, count: int) -> np.ndarray:
    """Up to ``count`` of ``candidates`` from which the A* grid reaches a target."""
    grid = SearchGrid.of(world)
    keep = []
    for p in candidates:
        if len(keep) == count:
            break
        if any(np.hypot(*(p - q)) < 2 * world.robot_radius for q in keep):
            continue
        if world.clearance(p[None])[0] >= world.robot_radius + 0.05 and grid.reachable(p):
            keep.append(p)
    return np.array(keep).reshape(-1, 2)


def _build(data: dict, count: int, candidates: np.ndarray, family: str) -> World | None:
    """The world of ``data`` with up to ``count`` reachable starts among ``candidates`` (file units), or None."""
    try:
        bare = world_from_dict({**data, "starts": []}, source=f"<generated {family}>")
    except UserError:
        return None
    frame = bare.frame
    inside = (candidates - np.asarray(frame.offset)) / frame.unit
    starts = _reachable_starts(bare, inside, count)
    if not len(starts):
        return None
    data["starts"] = round_coordinates(frame.to_file(starts).tolist())
    try:
        return world_from_dict(data, source=f"<generated {family}>")
    except UserError:
        return None


# -- pillars ----------------------------------------------------------------------------------------------
def _cave(rng: np.random.Generator, rows: int, cols: int) -> np.ndarray:
    """(rows, cols) bool: random fill smoothed by the cave rule (occupied when 5 of the 9 around are)."""
    rounds = int(rng.integers(0, 4))
    fill = rng.uniform(0.03, 0.25) if rounds == 0 else rng.uniform(0.3, 0.5)
    cells = rng.random((rows, cols)) < fill
    for _ in range(rounds):
        padded = np.pad(cells, 1).astype(int)
        around = sum(padded[1 + dr:1 + dr + rows, 1 + dc:1 + dc + cols] for dr in (-1, 0, 1) for dc in (-1, 0, 1))
        cells = around >= 5
    return cells


def pillars_world(rng: np.random.Generator, size: float, field: str, n_starts: int, name: str | None) -> World:
    """A ``pillars`` world (module docstring); lattice pitch 1."""
    for _ in range(MAX_ATTEMPTS):
        rows, cols = int(rng.integers(16, 37)), int(rng.integers(16, 37))
        below, beyond = int(rng.integers(4, 26)), float(rng.uniform(2.0, 20.0))
        radius = float(rng.uniform(1.05, 1.9))
        walls = rng.random() < 0.8
        cells = _cave(rng, rows, cols)
        centres = [(c, below + r) for r, c in zip(*np.nonzero(cells))]
        if walls:
            centres += [(x, y) for x in (-1, cols) for y in range(-1, below + rows)]
            centres += [(x, -1) for x in range(0, cols)]
        target = np.array([rng.uniform(0, cols - 1), below + rows - 1 + beyond])
        tolerance = float(rng.uniform(1.5, 6.0)) * radius
        margin = 2 * radius + float(rng.uniform(0.5, 4.0))
        lower = np.array([-1.5 - margin, -1.5 - margin])
        upper = np.array([cols + 0.5 + margin, target[1] + tolerance + margin])
        steps = _radius_steps(rng, float(np.max(upper - lower)) / radius, size)
        data = {"name": name or "pillars", "origin": lower.tolist(), "size": (upper - lower).tolist(),
                "robot": {"radius": radius, "step": radius / steps}, "goal_tolerance": tolerance, "field": field,
                "obstacles": [{"circle": {"center": [float(x), float(y)], "radius": 0.5}} for x, y in centres],
                "targets": [target.tolist()]}
        data = round_coordinates(data)
        candidates = np.column_stack([rng.uniform(radius, cols - 1 - radius, 16 * n_starts),
                                      rng.uniform(radius - 1, below - radius - 0.5, 16 * n_starts)])
        world = _build(data, n_starts, candidates, "pillars")
        if world is not None:
            return world
    raise UserError(f"no valid 'pillars' world found in {MAX_ATTEMPTS} draws")


# -- doors ------------------------------------------------------------------------------------------------
def doors_world(rng: np.random.Generator, size: float, field: str, n_starts: int, name: str | None) -> World:
    """A ``doors`` world (module docstring); the robot's radius is 1."""
    for _ in range(MAX_ATTEMPTS):
        nx, ny = int(rng.integers(2, 5)), int(rng.integers(2, 5))
        room = float(rng.uniform(6.0, 14.0))
        thick = float(rng.uniform(0.2, 1.2))
        side = (nx * room + (nx - 1) * thick, ny * room + (ny - 1) * thick)
        steps = _radius_steps(rng, max(side), size)
        step = 1.0 / steps
        width = 2.0 + max(float(rng.uniform(0.15, 1.5)), 0.15 * step)     # wide enough for the shield's margin

        def door(length: float) -> tuple[float, float]:
            lo = float(rng.uniform(0.2 * thick, length - width - 0.2 * thick))
            return lo, lo + width

        # walls between rooms: vertical ones at x = (i+1)·(room+thick) − thick, horizontal likewise
        links = [(("v", i, j), (i, j), (i + 1, j)) for i in range(nx - 1) for j in range(ny)]
        links += [(("h", i, j), (i, j), (i, j + 1)) for i in range(nx) for j in range(ny - 1)]
        order = rng.permutation(len(links))
        group = {(i, j): (i, j) for i in range(nx) for j in range(ny)}

        def root(a):
            while group[a] != a:
                a = group[a]
            return a

        opened = set()
        for k in order:
            key, a, b = links[k]
            if root(a) != root(b):
                group[root(a)] = root(b)
                opened.add(key)
            elif rng.random() < 0.25:
                opened.add(key)
        obstacles = []
        pitch = room + thick
        for (kind, i, j), _, _ in links:
            if kind == "v":
                x0, y0, length = (i + 1) * pitch - thick, j * pitch, room
                holes = [door(length)] if (kind, i, j) in opened else []
                spans = _spans(length, holes, j > 0, j < ny - 1, thick)
                obstacles += [[[x0, y0 + a], [x0 + thick, y0 + a], [x0 + thick, y0 + b], [x0, y0 + b]] for a, b in spans]
            else:
                x0, y0, length = i * pitch, (j + 1) * pitch - thick, room
                holes = [door(length)] if (kind, i, j) in opened else []
                spans = _spans(length, holes, i > 0, i < nx - 1, thick)
                obstacles += [[[x0 + a, y0], [x0 + b, y0], [x0 + b, y0 + thick], [x0 + a, y0 + thick]] for a, b in spans]
        # the squares where walls cross
        obstacles += [[[x, y], [x + thick, y], [x + thick, y + thick], [x, y + thick]]
                      for x in [(i + 1) * pitch - thick for i in range(nx - 1)]
                      for y in [(j + 1) * pitch - thick for j in range(ny - 1)]]
        goal_room = (int(rng.integers(nx)), int(rng.integers(ny)))
        target = (np.array(goal_room) + rng.uniform(0.3, 0.7, 2)) * pitch - thick / 2
        data = round_coordinates({"name": name or "doors", "size": list(side), "robot": {"radius": 1.0, "step": step},
                                  "goal_tolerance": float(rng.uniform(0.75, 2.5)), "field": field,
                                  "obstacles": [{"polygon": p} for p in obstacles], "targets": [target.tolist()]})
        others = [(i, j) for i in range(nx) for j in range(ny) if (i, j) != goal_room]
        picks = [others[k] for k in rng.integers(len(others), size=16 * n_starts)]
        candidates = (np.array(picks, float) + rng.uniform(0.15, 0.85, (len(picks), 2))) * pitch - thick / 2
        world = _build(data, n_starts, candidates, "doors")
        if world is not None:
            return world
    raise UserError(f"no valid 'doors' world found in {MAX_ATTEMPTS} draws")


def _spans(length: float, holes: list[tuple[float, float]], low_end: bool, high_end: bool,
           thick: float) -> list[tuple[float, float]]:
    """The pieces of a wall ``[0, length]`` around its doors (the ends meet the crossing squares)."""
    pieces, at = [], 0.0
    for a, b in sorted(holes):
        if a - at > 1e-6:
            pieces.append((at, a))
        at = b
    if length - at > 1e-6:
        pieces.append((at, length))
    return pieces


# -- rescaled ---------------------------------------------------------------------------------------------
def rescaled_world(rng: np.random.Generator, size: float, field: str, n_starts: int, name: str | None) -> World:
    """A ``rescaled`` world (module docstring)."""
    for _ in range(MAX_ATTEMPTS):
        family = (FAMILIES + STRUCTURE_FAMILIES)[int(rng.integers(len(FAMILIES) + len(STRUCTURE_FAMILIES)))]
        structure = family in STRUCTURE_FAMILIES
        radius = 0.3 if structure else 0.25
        steps = float(math.exp(rng.uniform(*np.log(RADIUS_STEPS))))
        unit = radius / steps                                   # file units per step
        side = min(50.0, size * unit)
        if side < (40.0 if family == "mixed" else 20.0):
            continue
        try:
            base = (structure_world(family, rng, side, field, n_starts, name) if structure
                    else static_world(family, rng, side, field, n_starts, name))
        except UserError:
            continue
        data = world_to_file(base)
        data["name"] = name or f"rescaled_{family}"
        data["robot"] = {"radius": radius, "step": unit}
        data["field"] = field
        world = _build(data, n_starts, np.asarray(data["starts"], float), "rescaled")
        if world is not None:
            return world
    raise UserError(f"no valid 'rescaled' world found in {MAX_ATTEMPTS} draws")


SCALED = {"pillars": pillars_world, "doors": doors_world, "rescaled": rescaled_world}


def scaled_world(family: str, rng: np.random.Generator, size: float, field: str, n_starts: int,
                 name: str | None) -> World:
    """A world of a family at every scale (:data:`SCALED_FAMILIES`)."""
    return SCALED[family](rng, size, field, n_starts, name)
