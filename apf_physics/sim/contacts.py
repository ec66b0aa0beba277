"""Contacts: what touched what during a control step, read from pymunk's arbiters.

Every static body the physics builds (an obstacle, a wall slab, a moving obstacle) is
labelled with what it is (:class:`BodyLabels`), and every robot's proxy is known by its body
id. After a substep in which shapes may touch (:class:`Touching`), the arbiters' body-id pairs are
read (:func:`touching_pairs`), and at the end of the step they become the rows
``(robot, kind, other)`` of a :class:`ContactLog` (:func:`contact_log`, one compiled loop).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from typing import Callable

import numpy as np
import pymunk
import pymunk.batch

from apf_physics.common.compiled import kernel

KINDS = ("obstacle", "wall", "robot", "moving_obstacle")
"""What a robot can touch; :attr:`ContactLog.pairs` holds indices into this."""
OBSTACLE, WALL, ROBOT, MOVING = range(4)
"""Indices into :data:`KINDS`."""
_KIND_COUNT = len(KINDS)


class CollisionType(IntEnum):
    ROBOT = 1
    OBSTACLE = 2
    WALL = 3


@dataclass(frozen=True)
class Contact:
    """One touch seen during a control step.

    Attributes:
        robot: Global index of the robot.
        kind: ``"obstacle"``, ``"wall"`` or ``"robot"``.
        other: Obstacle index in the robot's world, wall index (0 bottom, 1 right, 2 top, 3 left),
            or the other robot's global index.
    """

    robot: int
    kind: str
    other: int


@dataclass(frozen=True)
class ContactLog:
    """What touched what during the last control step.

    Attributes:
        obstacle: (N,) bool: the robot touched a static obstacle.
        wall: (N,) bool: the robot touched the map's edge.
        robot: (N,) bool: the robot touched another robot.
        moving: (N,) bool: the robot touched a moving obstacle (or one touched it).
        rows: (K, 3) int: one row ``(robot, kind, other)`` per touching pair, as read, where a
            static obstacle may still be unnamed (``other`` -1, a tile's obstacles' shared body).
        namer: Names the static obstacles of ``rows`` (only when :attr:`pairs` is first read).
    """

    obstacle: np.ndarray
    wall: np.ndarray
    robot: np.ndarray
    moving: np.ndarray
    rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.intp))
    namer: Callable[[np.ndarray], np.ndarray] | None = field(default=None, repr=False, compare=False)

    @property
    def pairs(self) -> np.ndarray:
        """(K, 3) int: one row ``(robot, kind, other)`` per touching pair (:data:`KINDS`; a robot–robot
        touch appears once per robot; a static obstacle by its index in the robot's world), sorted."""
        if self.namer is not None:   # named once, when asked: stepping needs the kinds alone
            object.__setattr__(self, "rows", self.namer(self.rows))
            object.__setattr__(self, "namer", None)
        return self.rows

    @classmethod
    def nothing(cls, num_robots: int) -> ContactLog:
        """The (read-only) log of a step in which nothing touched."""
        none = np.zeros(num_robots, bool)
        none.flags.writeable = False
        return cls(none, none, none, none)

    @property
    def any(self) -> np.ndarray:
        """(N,) bool: touched anything."""
        return self.obstacle | self.wall | self.robot | self.moving

    @property
    def obstacle_or_edge(self) -> np.ndarray:
        """(N,) bool: touched an obstacle, static or moving, or the map's edge (anything but a robot)."""
        return self.obstacle | self.wall | self.moving

    @property
    def touched(self) -> bool:
        """Whether anything touched anything."""
        return len(self.rows) > 0

    @property
    def contacts(self) -> list[Contact]:
        """The pairs as :class:`Contact` records."""
        return [Contact(int(r), KINDS[k], int(o)) for r, k, o in self.pairs.tolist()]


class BodyLabels:
    """What each static body is: ``(kind, index)`` by body id (:data:`KINDS`; the obstacle's index
    in its world, or the wall's: 0 bottom, 1 right, 2 top, 3 left).

    Attributes:
        ids: Sorted body ids.
        label: (B, 2) ``(kind, index)`` of each, in that order.
        of_id: The same as a dict (a few contacts are read by it).
    """

    def __init__(self):
        self.ids = np.zeros(0, np.uintp)
        self.label = np.zeros((0, 2), np.intp)
        self.of_id: dict[int, tuple[int, int]] = {}

    def add(self, bodies: list[tuple[pymunk.Body, int, int]]) -> None:
        """Record ``(body, kind, index)`` of each of ``bodies``."""
        ids = np.concatenate([self.ids, np.array([b.id for b, _, _ in bodies], np.uintp)])
        labels = np.concatenate([self.label, np.array([(k, i) for _, k, i in bodies], np.intp).reshape(-1, 2)])
        order = np.argsort(ids)
        self.ids, self.label = ids[order], labels[order]
        self.of_id.update((b.id, (k, i)) for b, k, i in bodies)


class Touching:
    """Whether any shapes of ``space`` may touch now: a substep after which none do has no
    arbiters to read.

    Two ways to know, each cheaper in its case: pymunk's begin/separate callbacks keep a count of
    the pairs touching (a Python call each time a contact begins or ends: cheap for a few robots,
    which touch rarely), or nothing is counted and the arbiters are read after every substep
    (one call per substep, whatever touches: cheaper when many robots are in contact).
    :meth:`count` switches between them; a count that starts is set to the arbiters present.

    While counting, :attr:`begun` counts the contacts that began: every pair that touches during
    a step is among the arbiters after the substep in which it began, or after the first substep
    if it touched before; a reader needs no other substep (:meth:`new_pairs`).
    """

    def __init__(self, space: pymunk.Space, buffer: pymunk.batch.Buffer):
        self.space, self._buffer = space, buffer
        self.pairs = 0          # pairs touching now, while counting
        self.begun = 0          # contacts begun, while counting
        self.counting = False
        self.count(True)

    def count(self, counting: bool) -> None:
        """Count (True) or read after every substep (False)."""
        if counting == self.counting:
            return
        if counting:
            self.pairs = len(touching_pairs(self.space, self._buffer))
            self.space.on_collision(begin=self._begin, separate=self._separate)
        else:
            self.space.on_collision(begin=pymunk.empty_callback, separate=pymunk.empty_callback)
        self.counting = counting

    @property
    def maybe(self) -> bool:
        """Some shapes may touch now (always, when not counting)."""
        return not self.counting or self.pairs > 0

    def new_pairs(self, first: bool, begun_before: int) -> bool:
        """After a substep (``first``: the step's first; ``begun_before``: :attr:`begun` before it):
        may the arbiters now hold a pair not read after an earlier substep of this step?"""
        if not self.counting:
            return True
        return self.begun != begun_before or (first and self.pairs > 0)

    def _begin(self, arbiter, space, data) -> None:
        self.pairs += 1
        self.begun += 1

    def _separate(self, arbiter, space, data) -> None:
        self.pairs -= 1


_PAIR_FIELDS = pymunk.batch.ArbiterFields.BODY_A_ID | pymunk.batch.ArbiterFields.BODY_B_ID
_DEPTH_FIELDS = _PAIR_FIELDS | pymunk.batch.ArbiterFields.NORMAL | pymunk.batch.ArbiterFields.DISTANCE_1
# (the fields as constants: or-ing pymunk's flags costs as much as reading a few arbiters)


def touching_pairs(space: pymunk.Space, buffer: pymunk.batch.Buffer) -> np.ndarray:
    """(K, 2) body ids of the pairs of bodies whose shapes touch now (read through ``buffer``)."""
    return np.frombuffer(touching_pair_bytes(space, buffer), dtype=np.uintp).reshape(-1, 2)


def touching_pair_bytes(space: pymunk.Space, buffer: pymunk.batch.Buffer) -> bytes:
    """:func:`touching_pairs` as the bytes of its array: a reader after every substep joins them
    once at the end of the step (``np.frombuffer(b"".join(...), np.uintp)``), rather than paying
    numpy's fixed costs at every substep."""
    buffer.clear()
    pymunk.batch.get_space_arbiters(space, _PAIR_FIELDS, buffer)
    return bytes(buffer.int_buf())


def touching_depths(space: pymunk.Space, buffer: pymunk.batch.Buffer) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs touching now, as :func:`touching_pairs`, with how they touch.

    Returns:
        ``(ids (K, 2), normal (K, 2), distance (K,))``: body ids ``(a, b)``, the contact normal
        from ``a`` to ``b``, and the signed distance of their contact point (negative: ``a``
        and ``b`` overlap by that much). A robot's disc meets a shape at one point.
    """
    buffer.clear()
    pymunk.batch.get_space_arbiters(space, _DEPTH_FIELDS, buffer)
    ids = np.frombuffer(buffer.int_buf(), dtype=np.uintp).reshape(-1, 2).copy()
    values = np.frombuffer(buffer.float_buf(), dtype=np.float64).reshape(-1, 3)
    return ids, values[:, :2].copy(), values[:, 2].copy()


def contact_log(pairs: np.ndarray, labels: BodyLabels, proxy_ids: np.ndarray, proxy_order: np.ndarray,
                proxy_robot: np.ndarray, num_robots: int,
                namer: Callable[[], Callable[[np.ndarray], np.ndarray]] | None = None) -> ContactLog:
    """The contact log of the touching body-id pairs: its sorted distinct rows ``(robot, kind,
    other)`` and each robot's flags, from one compiled loop.

    Args:
        pairs: (K, 2) touching body ids (a pair may come several times).
        labels: What the static bodies are.
        proxy_ids: The proxies' body ids, sorted (uint64; :attr:`~apf_physics.sim.proxies.ProxyPool.sorted_ids`).
        proxy_order: The proxy of each of them (the argsort of the ids in the pool's order).
        proxy_robot: The robot each proxy simulates (-1: parked).
        num_robots: Robots in the log.
        namer: Makes the namer of the rows' unnamed static obstacles (a tile's obstacles' shared
            body, ``other`` -1), called only when there are some (:attr:`ContactLog.pairs`).
    """
    rows, flags, unnamed = _contact_rows(np.ascontiguousarray(pairs, np.uint64), proxy_ids, proxy_order, proxy_robot,
                                         labels.ids.astype(np.uint64, copy=False), labels.label, num_robots)
    return ContactLog(flags[OBSTACLE], flags[WALL], flags[ROBOT], flags[MOVING], rows,
                      namer() if unnamed and namer is not None else None)


def body_robots(pairs: np.ndarray, proxy_ids: np.ndarray, proxy_order: np.ndarray,
                proxy_robot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each body of the (K, 2) body-id ``pairs``: ``(robot, proxy)``, both (K, 2), the robot it
    simulates (-1: not a lent proxy) and which proxy it is (-1: not a proxy); arguments as
    :func:`contact_log`."""
    return _body_robots(np.ascontiguousarray(pairs, np.uint64), proxy_ids, proxy_order, proxy_robot)


def deep_planes(ids: np.ndarray, normal: np.ndarray, distance: np.ndarray, tolerance: float, proxy_ids: np.ndarray,
                proxy_order: np.ndarray, proxy_robot: np.ndarray,
                proxy_solo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The last substep's pairs (:func:`touching_depths`) that overlap by more than ``tolerance``,
    split by who must settle them.

    Returns:
        ``(robots (R,), first (R + 1,), planes (K, 3), rest (L,))``: the robots alone in their
        slots (``proxy_solo``) that overlap static shapes, sorted, robot ``robots[i]``'s planes
        being ``planes[first[i]:first[i + 1]]``, each ``(way out x, y, depth)`` in the arbiters'
        order; and the indices of the other deep pairs (two robots, or a robot of a formation
        or near moving obstacles) in ``ids``. Other arguments as :func:`contact_log`.
    """
    return _deep_planes(np.ascontiguousarray(ids, np.uint64), normal, distance, float(tolerance),
                        proxy_ids, proxy_order, proxy_robot, proxy_solo)


@kernel
def _deep_planes(ids, normal, distance, tolerance, proxy_ids, proxy_order, proxy_robot, proxy_solo):
    """:func:`deep_planes` over ``proxy_ids`` sorted (``proxy_order``: their proxies)."""
    n = len(distance)
    robot, proxy = _body_robots(ids, proxy_ids, proxy_order, proxy_robot)
    solo_robot = np.empty(n, np.int64)
    solo_plane = np.empty((n, 3))
    rest = np.empty(n, np.int64)
    count = 0
    others = 0
    for i in range(n):
        if not distance[i] < -tolerance or (robot[i, 0] < 0 and robot[i, 1] < 0):
            continue
        side = 0 if robot[i, 0] >= 0 else 1
        if robot[i, 1 - side] >= 0 or not proxy_solo[proxy[i, side]]:
            rest[others] = i
            others += 1
            continue
        sign = -1.0 if side == 0 else 1.0   # the way out: against the normal from a robot that is a, along it if b
        solo_robot[count] = robot[i, side]
        solo_plane[count, 0], solo_plane[count, 1] = sign * normal[i, 0], sign * normal[i, 1]
        solo_plane[count, 2] = -distance[i]
        count += 1
    order = np.argsort(solo_robot[:count], kind="mergesort")   # stable: each robot's planes in the arbiters' order
    sorted_robot = solo_robot[:count][order]
    first = np.empty(count + 1, np.int64)
    robots = 0
    for j in range(count):
        if j == 0 or sorted_robot[j] != sorted_robot[j - 1]:
            first[robots] = j
            robots += 1
    first[robots] = count
    unique = np.empty(robots, np.int64)
    for j in range(robots):
        unique[j] = sorted_robot[first[j]]
    return unique, first[:robots + 1].copy(), solo_plane[:count][order], rest[:others].copy()


@kernel
def _body_robots(pairs, proxy_ids, proxy_order, proxy_robot):
    """:func:`body_robots` over ``proxy_ids`` sorted (``proxy_order``: their proxies)."""
    n = pairs.shape[0]
    robot = np.full((n, 2), -1, np.int64)
    proxy = np.full((n, 2), -1, np.int64)
    for i in range(n):
        for side in range(2):
            k = np.searchsorted(proxy_ids, pairs[i, side])
            if k < len(proxy_ids) and proxy_ids[k] == pairs[i, side]:
                proxy[i, side] = proxy_order[k]
                robot[i, side] = proxy_robot[proxy_order[k]]
    return robot, proxy


@kernel
def _contact_rows(pairs, proxy_ids, proxy_order, proxy_robot, label_ids, label, num_robots):
    """:func:`contact_log`'s loop over ``proxy_ids`` sorted (``proxy_order``: their proxies) and
    ``label_ids`` sorted with their ``label`` rows: each body of a pair that is a lent proxy gives
    one row, ``(its robot, kind, index)`` for a static body or ``(its robot, ROBOT, the other's
    robot)`` for another lent proxy; rows sorted, each once.

    Returns:
        ``(rows (K, 3), flags (kinds, num_robots), unnamed)``: the rows, whether each robot
        touched each kind, and whether a row's static obstacle is unnamed (``other`` -1).
    """
    n = pairs.shape[0]
    robot, proxy = _body_robots(pairs, proxy_ids, proxy_order, proxy_robot)
    rows = np.empty((2 * n, 3), np.int64)
    count = 0
    for i in range(n):
        for a in range(2):
            b = 1 - a
            if robot[i, a] < 0:
                continue
            if proxy[i, b] < 0:
                s = min(np.searchsorted(label_ids, pairs[i, b]), max(len(label_ids) - 1, 0))
                rows[count, 0], rows[count, 1], rows[count, 2] = robot[i, a], label[s, 0], label[s, 1]
                count += 1
            elif robot[i, b] >= 0:
                rows[count, 0], rows[count, 1], rows[count, 2] = robot[i, a], ROBOT, robot[i, b]
                count += 1
    rows = rows[:count]
    # rows as one sortable key: one 1-D unique (the index shifted by one: a tile's obstacles' body is -1)
    span = 1
    for i in range(count):
        span = max(span, rows[i, 2] + 2)
    key = np.unique((rows[:, 0] * _KIND_COUNT + rows[:, 1]) * span + rows[:, 2] + 1)
    out = np.empty((len(key), 3), np.intp)
    flags = np.zeros((_KIND_COUNT, num_robots), np.bool_)
    unnamed = False
    for i in range(len(key)):
        out[i, 0], out[i, 1] = key[i] // (_KIND_COUNT * span), key[i] // span % _KIND_COUNT
        out[i, 2] = key[i] % span - 1
        flags[out[i, 1], out[i, 0]] = True
        unnamed = unnamed or out[i, 2] == -1   # a tile's obstacles' shared body (tiles.ANY_OBSTACLE)
    return out, flags, unnamed
