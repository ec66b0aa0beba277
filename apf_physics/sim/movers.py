"""Moving obstacles in pymunk: kinematic bodies lent, step by step, to the slots whose robots come near.

A moving obstacle's route is a pure function of the step (:class:`~apf_physics.world.obstacles.Motion`),
and each slot's episode is at a step of its own, so an obstacle may stand at a different place in
every slot. The pool keeps kinematic copies of each (world, obstacle), parked (row 1 of
:data:`~apf_physics.sim.proxies.PARKING`) until a robot that goes to pymunk comes near the box the
obstacle sweeps this step; then one copy per such slot is put where the route has it at the slot's
step, with the velocity that takes it to where it will be at the next.
"""

from __future__ import annotations

import numpy as np
import pymunk

from apf_physics.sim.contacts import MOVING, BodyLabels
from apf_physics.sim.proxies import parking
from apf_physics.sim.tiles import obstacle_shapes
from apf_physics.world.core import World

PARKING_ROW = 1
"""The row of :data:`~apf_physics.sim.proxies.PARKING` where idle copies wait."""


class MoverPool:
    """Kinematic copies of moving obstacles, each built for one (world, obstacle).

    Attributes:
        bodies: Every copy's body; ``key`` its ``(id(world), obstacle index)``.
        target: (K, 4) each copy's position and velocity before pymunk next steps, in the space's
            coordinates (parked and at rest unless lent this step); ``parked`` (K, 2) where each waits.
        changed: The pool grew since the physics last mapped pymunk.batch's rows to bodies.
    """

    def __init__(self, space: pymunk.Space, labels: BodyLabels):
        self.space = space
        self.labels = labels
        self.bodies: list[pymunk.Body] = []
        self.key: list[tuple[int, int]] = []
        self.target = np.zeros((0, 4))
        self.parked = np.zeros((0, 2))
        self.changed = False

    def __len__(self) -> int:
        return len(self.bodies)

    def new(self, world: World, index: int) -> int:
        """A kinematic body shaped like moving obstacle ``index`` of ``world``, parked; its index."""
        body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        shapes = obstacle_shapes(body, world.obstacles[index], (0.0, 0.0))
        for shape in shapes:
            shape.friction = 0.0
            shape.elasticity = 0.0
        k = len(self.bodies)
        body.position = parking(k, PARKING_ROW)
        self.space.add(body, *shapes)
        self.bodies.append(body)
        self.key.append((id(world), index))
        self.target = np.vstack([self.target, [*parking(k, PARKING_ROW), 0.0, 0.0]])
        self.parked = np.vstack([self.parked, parking(k, PARKING_ROW)])
        self.labels.add([(body, MOVING, index)])
        self.changed = True
        return k

    def lend(self, needed: list, slot_time: np.ndarray, slot_offset: np.ndarray, control_dt: float,
             active_slots: np.ndarray | None) -> None:
        """Park every copy, then put one copy of each obstacle in ``needed`` in each slot that needs it.

        Args:
            needed: ``(world, index, slots, near)`` for each moving obstacle that robots going to
                pymunk come near: the slots of ``world`` and whether any robot of each is near.
            slot_time: (S,) each slot's step (where its obstacles are).
            slot_offset: (S, 2) each slot's tile offset in the space.
            control_dt: The control step's duration (the copy's velocity covers the route's step in it).
            active_slots: (S,) bool: the slots that take part (None: all).
        """
        if not self.bodies and not needed:
            return
        self.target[:, :2] = self.parked
        self.target[:, 2:] = 0.0
        for world, index, slots, near in needed:
            if active_slots is not None:
                near = near & active_slots[slots]
            slots = slots[near]
            if not len(slots):
                continue
            pool = [k for k, key in enumerate(self.key) if key == (id(world), index)]
            while len(pool) < len(slots):
                pool.append(self.new(world, index))
            copies = np.array(pool[:len(slots)])
            motion = world.obstacles[index].motion
            t = slot_time[slots]
            start = motion.offset(t)
            self.target[copies, :2] = start + slot_offset[slots]
            self.target[copies, 2:] = (motion.offset(t + 1.0) - start) / control_dt

