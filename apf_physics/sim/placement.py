"""Placing robots: moved out of each other and off obstacles' edges, without crossing anything.

Starts come from users, generators and samplers; two robots of a formation or a crowd may be put
overlapping, or a robot closer to a wall than its radius. Chipmunk's solver would push them
apart at the first step, possibly through a thin wall; :func:`separate` moves them apart first,
in small steps that each keep the robot's radius from every obstacle and the map's edge.
"""

from __future__ import annotations

import numpy as np

from apf_physics.errors import UserError
from apf_physics.world.core import World


def separate(world: World, positions: np.ndarray, t: float, robots: np.ndarray) -> np.ndarray:
    """Robots at ``positions`` (k, 2) (of one crowd, in ``world`` at step ``t``), moved out of each
    other and off obstacles' edges without crossing anything.

    Args:
        robots: (k,) their global indices, for messages.

    Raises:
        UserError: A centre inside an obstacle or outside the map, or robots that cannot be
            separated in free space.
    """
    m = len(positions)
    p = np.array(positions, dtype=float, copy=True)
    r = world.robot_radius
    clearance = world.clearance(p, t)
    if np.any(clearance <= 0):
        k = int(np.argmin(clearance))
        raise UserError(f"{world.label}: robot {int(robots[k])} placed at {np.round(p[k], 4).tolist()} has its "
                        f"centre inside an obstacle or outside the map")
    need = 2 * r + 1e-6
    for _ in range(200):
        diff = p[:, None, :] - p[None, :, :]
        d = np.hypot(diff[..., 0], diff[..., 1]) + np.eye(m) * 1e9
        overlap = np.clip(need - d, 0.0, None)
        edge = np.clip(r + 1e-6 - clearance, 0.0, None)
        if not overlap.any() and not edge.any():
            return p
        # apart along the line of centres (robots on one point: a fixed fan of directions)
        fan = np.arange(m)[:, None] - np.arange(m)[None, :]
        angle = fan * 2.399963   # the golden angle: distinct for every pair
        unit = np.where(d[..., None] > 1e-9, diff / np.maximum(d, 1e-9)[..., None],
                        np.stack([np.cos(angle), np.sin(angle)], -1))
        # a little more than the overlap (1e-3), so that it ends rather than only halves
        push = 0.5 * np.sum(np.where(overlap > 0, overlap + 1e-3, 0.0)[..., None] * unit, axis=1)
        if edge.any():   # off an obstacle's edge: up the clearance (finite differences)
            h = 1e-4
            grad = np.stack([world.clearance(p + [h, 0], t) - world.clearance(p - [h, 0], t),
                             world.clearance(p + [0, h], t) - world.clearance(p - [0, h], t)], -1) / (2 * h)
            push += np.where(edge > 0, edge + 1e-3, 0.0)[:, None] * grad
        length = np.hypot(push[:, 0], push[:, 1])
        push *= np.minimum(1.0, 0.05 / np.maximum(length, 1e-12))[:, None]
        # never through anything: take the longest of these steps that keeps the radius all along
        bar = np.minimum(r, clearance)
        step = np.zeros_like(push)
        for scale in (0.25, 0.5, 1.0):
            ok = world.path_clearance(p, p + scale * push, 0.01, t=t, during=False) >= bar
            step[ok] = scale * push[ok]
        p = p + step
        clearance = world.clearance(p, t)   # once per move: clearance is most of the cost of placing robots
    raise UserError(f"{world.label}: robots {np.asarray(robots).tolist()} placed on top of each other "
                    f"could not be moved apart in free space")
