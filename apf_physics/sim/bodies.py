"""The bodies pymunk moves, written and read in batches: the proxies' and the moving obstacles'.

Setting or reading one body's position or velocity from Python costs about as much as a
substep of a small space, so the bodies of a step are written and read through
``pymunk.batch`` (every body's position and velocity in one call), except when there are so
few that attribute access is cheaper (:data:`FEW`). ``pymunk.batch`` lists the space's bodies
in an order of its own (not insertion order): :meth:`SpaceBodies.index` maps its rows to the
pools' bodies whenever a pool or a tile has grown.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk
import pymunk.batch

from apf_physics.sim.movers import MoverPool
from apf_physics.sim.proxies import ProxyPool

FEW = 4
"""Up to this many proxies (and no moving obstacle), per-body attribute access beats pymunk.batch's fixed cost."""
_BODY_FIELDS = pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.VELOCITY   # (or-ing pymunk's flags costs µs)


class SpaceBodies:
    """Writes and reads the pools' bodies in ``space``.

    Attributes:
        tiles_grew: Static bodies were added to the space since :meth:`index` (set by the physics
            when it builds tiles); the pools say when they grow themselves.
    """

    def __init__(self, space: pymunk.Space, proxies: ProxyPool, movers: MoverPool):
        self.space = space
        self.proxies = proxies
        self.movers = movers
        self.tiles_grew = True
        self._buffer = pymunk.batch.Buffer()

    @property
    def stale(self) -> bool:
        """pymunk.batch's rows may no longer map to the bodies as :meth:`index` found them."""
        return self.tiles_grew or self.proxies.changed or self.movers.changed

    @property
    def few(self) -> bool:
        """Bodies are few enough to be set one by one (:data:`FEW`)."""
        return len(self.proxies) <= FEW and not len(self.movers)

    def index(self) -> None:
        """Map pymunk.batch rows to proxies and moving obstacles (rows are not in insertion order)."""
        buf = self._buffer
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.BODY_ID, buf)
        ids = np.frombuffer(buf.int_buf(), dtype=np.uintp).copy()
        index = {b.id: k for k, b in enumerate(self.proxies.bodies)}
        row_proxy = np.array([index.get(int(i), -1) for i in ids])
        self._proxy_rows = np.flatnonzero(row_proxy >= 0)
        self._proxy_of_row = row_proxy[self._proxy_rows]
        self._row_of_proxy = np.empty(len(self.proxies), np.intp)
        self._row_of_proxy[self._proxy_of_row] = self._proxy_rows
        movers = {b.id: k for k, b in enumerate(self.movers.bodies)}
        row_mover = np.array([movers.get(int(i), -1) for i in ids])
        self._row_of_mover = np.empty(len(self.movers), np.intp)
        self._row_of_mover[row_mover[row_mover >= 0]] = np.flatnonzero(row_mover >= 0)
        self.tiles_grew = self.proxies.changed = self.movers.changed = False

    def write(self, proxies: np.ndarray, velocity: np.ndarray) -> None:
        """Put the proxies that moved (``ProxyPool.moved``) at their targets, give ``proxies`` the
        ``velocity`` (k, 2) and every other proxy none, and the moving obstacles their targets."""
        if self.stale:
            self.index()
        pool = self.proxies
        if self.few:   # body by body, on Python floats: the moved put where they are to be, the rest at rest
            bodies = pool.bodies
            moved = pool.moved.tolist()
            target = pool.target.tolist()
            commanded = dict(zip(proxies.tolist(), velocity.tolist()))
            for k, body in enumerate(bodies):
                if moved[k]:
                    body.position = target[k]
                    body.velocity = commanded.get(k, (0.0, 0.0))
                elif k in commanded:
                    body.velocity = commanded[k]
                # (a body neither moved nor commanded is parked, at rest since it was: nothing touches it)
        else:
            moved = np.flatnonzero(pool.moved)
            every = np.zeros((len(pool), 2))
            every[proxies] = velocity
            # every body's position and velocity in one read and one write (static bodies are
            # rows too: they are written back as they were read)
            rows = self._read(_BODY_FIELDS, 4)
            rows[self._row_of_proxy[moved], :2] = pool.target[moved]
            rows[self._proxy_rows, 2:] = every[self._proxy_of_row]
            rows[self._row_of_mover] = self.movers.target
            self._write(rows)
        pool.moved[:] = False

    def add_velocities(self, proxies: np.ndarray, change: np.ndarray, cap: float) -> None:
        """Add ``change`` to the velocities of the bodies of ``proxies`` (between substeps), leaving
        everything else as it is. A free body then moves at its new command; one that a contact
        slowed keeps what the contact took (as a holonomic robot keeps it for the whole step).

        A contact that took the part of a command heading into a wall leaves the body's velocity
        off the command; adding the command's later changes on top can then give the body more
        than the top speed (a unicycle turning away from the wall it hit is pushed off it at up
        to twice its speed), which the substeps are not sized for. The sum is therefore capped
        at ``cap``, the top speed (:func:`cap_speed`); a free body, which moves at its command,
        is never above it.
        """
        if len(proxies) <= FEW:
            for k, (dx, dy) in zip(proxies.tolist(), change.tolist()):
                body = self.proxies.bodies[k]
                vx, vy = body.velocity
                body.velocity = cap_speed_one(vx + dx, vy + dy, cap)
            return
        rows = self._read(_BODY_FIELDS, 4)
        at = self._row_of_proxy[proxies]
        rows[at, 2:] = cap_speed(rows[at, 2:] + change, cap)
        self._write(rows)

    def positions(self, proxies: np.ndarray) -> np.ndarray:
        """(k, 2) where pymunk has the bodies of ``proxies``, in the space's coordinates."""
        if self.few:
            bodies = self.proxies.bodies
            return np.array([bodies[k].position for k in proxies.tolist()], float).reshape(-1, 2)
        return self._read(pymunk.batch.BodyFields.POSITION, 2)[self._row_of_proxy[proxies]]

    def _read(self, fields, width: int) -> np.ndarray:
        buf = self._buffer
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, fields, buf)
        return np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, width).copy()

    def _write(self, rows: np.ndarray) -> None:
        write = pymunk.batch.Buffer()
        write.set_float_buf(rows.reshape(-1))
        pymunk.batch.set_space_bodies(self.space, _BODY_FIELDS, write)


SPEED_CAP_SLACK = 1e-9
"""A body is slowed to the top speed only when it exceeds it by more than this share: a free
body's velocity, the command's chord added up substep by substep, may round a hair above it."""


def cap_speed(velocity: np.ndarray, cap: float) -> np.ndarray:
    """(K, 2) velocities, those faster than ``cap`` (by more than :data:`SPEED_CAP_SLACK`) scaled down to it."""
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    over = speed > cap * (1.0 + SPEED_CAP_SLACK)
    if over.any():
        velocity[over] *= (cap / speed[over])[:, None]
    return velocity


def cap_speed_one(vx: float, vy: float, cap: float) -> tuple[float, float]:
    """:func:`cap_speed` of one velocity, in Python floats."""
    speed = math.hypot(vx, vy)
    if speed > cap * (1.0 + SPEED_CAP_SLACK):
        return vx * (cap / speed), vy * (cap / speed)
    return vx, vy
