"""The crossing family (:data:`FORMATION_FAMILIES`): several formations whose routes cross.

2–4 formations of 3 robots (a line or a wedge) whose routes cross near the middle of the map,
each from its start to a target across it, among 2–4 obstacles kept off the crossing (the
world file's ``formations:``).
"""

from __future__ import annotations

import math

import numpy as np

from apf_physics.errors import UserError
from apf_physics.world.generate.common import GOAL_TOLERANCE, MAX_ATTEMPTS, ROBOT_RADIUS, inside_map, round_coordinates
from apf_physics.world.generate.shapes import disc, random_box
from apf_physics.world.search import reachable
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import world_from_dict

FORMATION_FAMILIES = ("crossing",)


def crossing_world(rng: np.random.Generator, size: float, field: str, name: str | None) -> World:
    """2–4 formations whose straight routes cross near the middle, among a few obstacles off the crossing."""
    scale = size / 50.0
    for _ in range(MAX_ATTEMPTS):
        centre = size / 2 + rng.uniform(-4, 4, 2) * scale
        count = int(rng.integers(2, 5))
        angles = rng.uniform(0, 2 * math.pi) + np.arange(count) * 2 * math.pi / count + rng.uniform(-0.3, 0.3, count)
        formations, ends = [], []
        for angle in angles:
            u = np.array([math.cos(angle), math.sin(angle)])
            v = np.array([-u[1], u[0]])
            start = centre + rng.uniform(15, 20) * scale * u + rng.uniform(-2, 2) * scale * v
            target = centre - rng.uniform(15, 20) * scale * u + rng.uniform(-2, 2) * scale * v
            shape = "line" if rng.random() < 0.5 else "wedge"
            formations.append({"start": np.round(start, 3).tolist(), "target": np.round(target, 3).tolist(),
                               "followers": 2, "shape": shape, "spacing": 1.0, "comm_range": 3.0})
            ends += [start, target]
        ends = np.array(ends)
        if ends.min() < 3 or ends.max() > size - 3:
            continue
        if np.min(np.hypot(*(ends[:, None] - ends[None]).transpose(2, 0, 1)) + 99 * np.eye(len(ends))) < 4:
            continue
        obstacles = []
        for _ in range(int(rng.integers(2, 5))):
            p = centre + rng.uniform(-14, 14, 2) * scale
            if np.hypot(*(p - centre)) < 5 * scale or np.min(np.hypot(*(ends - p).T)) < 5:
                continue   # off the crossing, and off every start and target
            obstacles.append(disc(p, rng.uniform(0.5, 2.0)) if rng.random() < 0.5 else random_box(rng, p))
        if not all(inside_map(o, size, 0.5) for o in obstacles):
            continue
        data = {"name": name or "crossing", "size": [size, size], "robot_radius": ROBOT_RADIUS,
                "goal_tolerance": GOAL_TOLERANCE, "field": field, "obstacles": round_coordinates(obstacles),
                "formations": formations}
        try:
            world = world_from_dict(data, source="<generated crossing>")
        except UserError:
            continue
        if all(world.clearance(task.start[None])[0] >= 2.0 and reachable(world.formation_world(f), task.start)
               for f, task in enumerate(world.formations)):
            return world
    raise UserError(f"no valid 'crossing' world found in {MAX_ATTEMPTS} draws on a {size:g} x {size:g} map")
