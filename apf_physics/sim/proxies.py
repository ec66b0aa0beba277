"""Proxies: the dynamic discs that pymunk moves for the robots that may touch something this step.

A robot whose move cannot touch anything moves without pymunk (:mod:`apf_physics.sim.freemove`);
every other robot borrows a *proxy* from this pool: a dynamic disc of its radius, put where the
robot is in its world's tile of the space, moved by pymunk and read back. A proxy stays with its
robot while the robot keeps needing physics and is parked when it does not (:data:`PARKING`), so
the pool grows to the most robots that needed physics at once, not to the fleet.

Proxies of robots alone in their slots are in one collision group (:data:`SOLO_FILTER`): they
share their world's tile and never touch each other.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from apf_physics.common.compiled import kernel
from apf_physics.sim.contacts import CollisionType

PARKING = (4.0, -1000.0)
"""Where idle bodies wait, far below every tile (which lie at positive coordinates): body ``k`` of
a pool's row ``row`` at ``(4k, -1000 (row + 1))``, 4 units from its neighbours, so that parked
bodies never touch anything (proxies are row 0, moving obstacles row 1)."""

SOLO_GROUP = 1
"""Collision group of the proxies of single-robot slots: they never touch each other."""
SOLO_FILTER = pymunk.ShapeFilter(group=SOLO_GROUP)
"""... and shape queries about one of them do not see the others."""


def parking(k: int, row: int = 0) -> tuple[float, float]:
    """Where body ``k`` of a pool's ``row`` waits (:data:`PARKING`)."""
    return (PARKING[0] * k, PARKING[1] * (row + 1))


class ProxyPool:
    """The proxies and which robot holds each.

    Attributes:
        bodies: Every proxy's pymunk body, in the order they were made.
        robot: (P,) the robot each proxy simulates, -1 when parked.
        of_robot: (N,) each robot's proxy, -1 when it holds none.
        dirty: (P,) parked since pymunk last stepped (it may still carry solver state: not lent).
        radius: (P,) each proxy's radius.
        solo: (P,) in the collision group of proxies that never meet (:data:`SOLO_FILTER`).
        ids: (P,) their body ids; ``order`` the argsort of ``ids``, ``sorted_ids`` the ids in that
            order (uint64), ``of_id`` the same as a dict.
        target: (P, 2) where each is to be put before pymunk next steps, in the space's
            coordinates; ``moved`` (P,) those that must be put there.
        held: Some robot held a proxy at the last step.
        lent: How many robots hold a proxy now.
        changed: The pool grew since the physics last mapped pymunk.batch's rows to bodies.
    """

    def __init__(self, space: pymunk.Space, num_robots: int):
        self.space = space
        self.bodies: list[pymunk.Body] = []
        self.robot = np.zeros(0, np.intp)
        self.of_robot = np.full(num_robots, -1, np.intp)
        self.dirty = np.zeros(0, bool)
        self.radius = np.zeros(0)
        self.solo = np.zeros(0, bool)
        self.ids = np.zeros(0, np.uintp)
        self.order = np.zeros(0, np.intp)
        self.sorted_ids = np.zeros(0, np.uint64)
        self.of_id: dict[int, int] = {}
        self.target = np.zeros((0, 2))
        self.parked = np.zeros((0, 2))
        self.moved = np.zeros(0, bool)
        self.held = False
        self.lent = 0
        self.changed = True

    def __len__(self) -> int:
        return len(self.bodies)

    def new(self, radius: float, solo: bool) -> int:
        """A new parked proxy of ``radius``; its index."""
        body = pymunk.Body(1.0, math.inf)
        shape = pymunk.Circle(body, radius)
        shape.collision_type = CollisionType.ROBOT
        shape.friction = 0.0
        shape.elasticity = 0.0
        if solo:
            shape.filter = SOLO_FILTER
        k = len(self.bodies)
        body.position = parking(k)
        self.space.add(body, shape)
        self.bodies.append(body)
        self.robot = np.append(self.robot, -1)
        self.dirty = np.append(self.dirty, False)
        self.radius = np.append(self.radius, radius)
        self.solo = np.append(self.solo, solo)
        self.ids = np.append(self.ids, np.uintp(body.id))
        self.order = np.argsort(self.ids)
        self.sorted_ids = self.ids[self.order].astype(np.uint64)
        self.of_id[body.id] = k
        self.target = np.vstack([self.target, parking(k)])
        self.parked = np.vstack([self.parked, parking(k)])
        self.moved = np.append(self.moved, False)
        self.changed = True
        return k

    def release(self, robots: np.ndarray) -> None:
        """Take the proxies of ``robots`` back to the parking (dirty until pymunk steps once more)."""
        proxies = self.of_robot[robots]
        proxies = proxies[proxies >= 0]
        if not len(proxies):
            return
        self.lent -= len(proxies)
        self.target[proxies] = self.parked[proxies]
        self.moved[proxies] = True
        self.of_robot[self.robot[proxies]] = -1
        self.robot[proxies] = -1
        self.dirty[proxies] = True

    def lend(self, robots: np.ndarray, radius: np.ndarray, solo: np.ndarray, where: np.ndarray) -> None:
        """Give each of ``robots`` (none holding one, sorted) a clean proxy of its ``radius`` and kind
        (``solo``), put at ``where`` (space coordinates): the free proxies of each kind in order
        (:func:`_lend_free`), then new ones for those left, kind by kind."""
        if not len(robots):
            return
        self.lent += len(robots)
        left = _lend_free(robots, radius, solo, self.robot, self.dirty, self.radius, self.solo, self.of_robot)
        if len(left):   # the pool is short: new proxies, kind by kind in order (as the pool grew before)
            kinds = sorted(set(zip(radius[left].tolist(), solo[left].tolist())))
            for r, alone in kinds:
                for robot in robots[left][(radius[left] == r) & (solo[left] == alone)].tolist():
                    k = self.new(r, alone)
                    self.robot[k] = robot
                    self.of_robot[robot] = k
        self.put(robots, where)

    def put(self, robots: np.ndarray, where: np.ndarray) -> None:
        """Have the proxies of ``robots`` put at ``where`` (space coordinates) before pymunk next steps."""
        proxies = self.of_robot[robots]
        self.target[proxies] = where
        self.moved[proxies] = True


@kernel
def _lend_free(robots, radius, solo, proxy_robot, proxy_dirty, proxy_radius, proxy_solo, robot_proxy):
    """Lend ``robots`` (sorted) the parked clean proxies of their kind (radius and ``solo``), each
    kind's in order of index, writing ``proxy_robot`` and ``robot_proxy``.

    Returns:
        The indices (into ``robots``) of those left without one, in order.
    """
    left = np.empty(len(robots), np.int64)
    count = 0
    cursor = np.zeros(len(robots), np.int64)   # per robot's kind (its first robot): the next proxy to try
    kind = np.empty(len(robots), np.int64)
    for i in range(len(robots)):
        kind[i] = i
        for j in range(i):
            if radius[j] == radius[i] and solo[j] == solo[i]:
                kind[i] = kind[j]
                break
        k = cursor[kind[i]]
        while k < len(proxy_robot) and not (proxy_robot[k] < 0 and not proxy_dirty[k] and proxy_radius[k] == radius[i]
                                            and proxy_solo[k] == solo[i]):
            k += 1
        if k < len(proxy_robot):
            proxy_robot[k] = robots[i]
            robot_proxy[robots[i]] = k
            cursor[kind[i]] = k + 1
        else:
            cursor[kind[i]] = k
            left[count] = i
            count += 1
    return left[:count].copy()
