"""Options shared by the environments: which worlds, which robot, how each episode's world and start are chosen."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Mapping, Sequence, Union

import numpy as np
from gymnasium import spaces

from apf_physics.control.shield import ACTIONS
from apf_physics.errors import UserError
from apf_physics.world.kinematics import KINEMATICS, LIMIT_KEYS, UNICYCLE_ACTIONS, UnicycleLimits, holonomic_from_unit
from apf_physics.sensing.lidar import LidarConfig
from apf_physics.sensing.kinds import OBSERVATIONS
from apf_physics.sensing.observation import ObserverConfig
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import load_world

WorldSpec = Union[str, Path, World, Sequence[Union[str, Path, World]]]


def resolve_worlds(world: WorldSpec | None) -> list[World]:
    """A path (or a bundled world's name), a :class:`World`, or a list of them, as a list of worlds."""
    if world is None:
        raise UserError("the environment needs world=<path or World or list of them>")
    items = [world] if isinstance(world, (str, Path, World)) else list(world)
    if not items:
        raise UserError("world= is an empty list")
    return [w if isinstance(w, World) else load_world(w) for w in items]


ACTION_KINDS = ("discrete", "continuous")
"""The environments' ``action`` option."""


@dataclass(frozen=True)
class RobotOptions:
    """Which robot an environment drives and what it sees (:func:`robot_options` builds it from the options).

    Attributes:
        action: ``"discrete"``: ``Discrete(9)``, the thesis's Table 1 for a holonomic robot,
            :data:`~apf_physics.world.kinematics.UNICYCLE_ACTIONS` for a unicycle; ``"continuous"``:
            ``Box(-1, 1, (2,))``, a holonomic robot's velocity (each axis times the top speed,
            one unit per step: the box's corners are Table 1's diagonal moves) or a unicycle's
            ``(v, ω)`` as shares of its limits (:meth:`UnicycleLimits.from_unit`).
        unicycle: The unicycle's limits, or None for a holonomic robot.
        observation: One of :data:`~apf_physics.sensing.kinds.OBSERVATIONS`.
        lidar: The range sensor (used with a ``"lidar"`` observation).
    """

    action: str = "discrete"
    unicycle: UnicycleLimits | None = None
    observation: str = "window"
    lidar: LidarConfig = LidarConfig()

    @property
    def kinematics(self) -> str:
        return "holonomic" if self.unicycle is None else "unicycle"

    @property
    def window(self) -> bool:
        return "window" in self.observation

    @property
    def ranges(self) -> bool:
        return "lidar" in self.observation

    @property
    def thesis(self) -> bool:
        """The thesis's robot: holonomic, nine moves, the potential window."""
        return self.action == "discrete" and self.unicycle is None and self.observation == "window"

    def action_space(self) -> spaces.Space:
        if self.action == "continuous":
            return spaces.Box(-1.0, 1.0, (2,), np.float32)
        return spaces.Discrete(len(ACTIONS))

    def commands(self, actions: Any, num: int) -> np.ndarray:
        """(num, 2) the stepper's commands of ``num`` actions: a holonomic robot's velocity
        [units/step] or a unicycle's ``(v, ω)`` (bounded by the stepper)."""
        if self.action == "continuous":
            a = np.asarray(actions, float).reshape(num, 2)
            if self.unicycle is None:
                return holonomic_from_unit(a)
            return np.column_stack(self.unicycle.from_unit(a))
        index = np.asarray(actions, dtype=np.intp).reshape(num)
        if self.unicycle is None:
            return ACTIONS[index]
        return np.column_stack(self.unicycle.from_unit(UNICYCLE_ACTIONS[index]))


def robot_options(worlds: Sequence[World], action: str = "discrete", kinematics: str | None = None,
                  observation: str = "window", lidar: LidarConfig | Mapping[str, Any] | None = None,
                  limits: UnicycleLimits | Mapping[str, Any] | None = None) -> RobotOptions:
    """The environments' robot options, checked.

    Args:
        worlds: The environment's worlds: ``kinematics=None`` takes their robot (``robot:
            {kinematics: unicycle, ...}`` in the world file; all must agree).
        action: ``"discrete"`` or ``"continuous"``.
        kinematics: ``"holonomic"``, ``"unicycle"`` or None (the worlds').
        observation: ``"window"``, ``"lidar"`` or ``"window+lidar"``.
        lidar: :class:`~apf_physics.sensing.lidar.LidarConfig` or its keys (``beams``, ``fov`` [degrees],
            ``max_range``, ``noise``).
        limits: A unicycle's :class:`~apf_physics.world.kinematics.UnicycleLimits` or some of its
            keys, over the world's (default: the world's, else the defaults).

    Raises:
        UserError: An unknown value, or worlds whose robots differ.
    """
    if action not in ACTION_KINDS:
        raise UserError(f"action must be one of {', '.join(ACTION_KINDS)}, got {action!r}")
    if observation not in OBSERVATIONS:
        raise UserError(f"observation must be one of {', '.join(OBSERVATIONS)}, got {observation!r}")
    own = {w.unicycle for w in worlds}
    if kinematics is None:
        if len(own) > 1:
            raise UserError("the worlds' robots differ (robot: kinematics or limits): give kinematics= "
                            "and limits= to drive them all alike")
        unicycle = own.pop() if own else None
    elif kinematics in KINEMATICS:
        worlds_own = next((u for u in own if u is not None), None)
        unicycle = (worlds_own or UnicycleLimits()) if kinematics == "unicycle" else None
    else:
        raise UserError(f"kinematics must be one of {', '.join(KINEMATICS)}, got {kinematics!r}")
    if limits is not None:
        if unicycle is None:
            raise UserError("limits= is for unicycle robots: add kinematics='unicycle'")
        if isinstance(limits, UnicycleLimits):
            unicycle = limits
        else:
            unknown = set(limits) - set(LIMIT_KEYS)
            if unknown:
                raise UserError(f"limits: unknown keys {sorted(unknown)}; known: {', '.join(LIMIT_KEYS)}")
            try:
                unicycle = replace(unicycle, **{k: float(v) for k, v in limits.items()})
            except (TypeError, ValueError) as e:
                raise UserError(f"limits: {e}") from None
    if lidar is None:
        config = LidarConfig()
    elif isinstance(lidar, LidarConfig):
        config = lidar
    else:
        known = {f.name for f in fields(LidarConfig)}
        unknown = set(lidar) - known
        if unknown:
            raise UserError(f"lidar: unknown keys {sorted(unknown)}; known: {', '.join(sorted(known))}")
        try:
            config = LidarConfig(**dict(lidar))
        except (TypeError, ValueError) as e:
            raise UserError(f"lidar: {e}") from None
    return RobotOptions(action, unicycle, observation, config)


def observer_config(obs_size: int, resolution: int, memory: bool, obs_scale: str,
                    observer: ObserverConfig | dict | None, previous: bool = False) -> ObserverConfig:
    """The environment's :class:`ObserverConfig`: ``observer`` if given, else built from the keyword options.

    ``previous`` adds the window of the field one step earlier (where moving obstacles were), so a
    policy can tell where they are going; ``memory`` the visit memory.
    """
    if observer is not None:
        return observer if isinstance(observer, ObserverConfig) else ObserverConfig.from_dict(observer)
    return ObserverConfig.of(obs_size, resolution, previous=previous, memory=memory, scale=obs_scale)


class StartChooser:
    """Picks each episode's world and start.

    Args:
        starts: ``"world"``: one of the world's own starts (random free positions if it has
            none); ``"random"``: a random free position farther than the goal tolerance from
            every target; or an ``(S, 2)`` array of starts.
        worlds: The worlds; with several, each episode draws one uniformly.

    Every choice is drawn from the generator it is given (the environment's ``np_random``),
    so ``reset(seed=k)`` makes it reproducible and different seeds give different starts.
    ``options={"start": i}`` picks row ``i`` of the starts, ``options={"start": [x, y]}`` a
    position, and ``options={"world": j}`` the world.
    """

    def __init__(self, starts: Any, worlds: Sequence[World]):
        self.worlds = list(worlds)
        if isinstance(starts, str):
            if starts not in ("world", "random"):
                raise UserError(f"starts must be 'world', 'random' or an array of points, got {starts!r}")
            self.kind, self.points = starts, None
        else:
            arr = np.asarray(starts, dtype=float)
            if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0:
                raise UserError(f"starts must be an (S, 2) array of points, got shape {arr.shape}")
            self.kind, self.points = "array", arr
        # per world: the list starts are drawn from, or None for the free cells away from the targets
        self._lists = [self.points if self.kind == "array" else
                       np.asarray(world.starts, float) if self.kind == "world" and len(world.starts) else None
                       for world in self.worlds]
        self._cells = [world.start_cells() if listed is None else None
                       for world, listed in zip(self.worlds, self._lists)]

    def draw(self, uniforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Worlds and starts of ``k`` new episodes from ``(k, 4)`` uniforms in [0, 1).

        Uniform 0 picks the world, 1 the start row (or the free cell), 2 and 3 the position
        within the cell. Returns ``(world indices (k,), starts (k, 2))``.
        """
        uniforms = np.asarray(uniforms, float).reshape(-1, 4)
        worlds = (uniforms[:, 0] * len(self.worlds)).astype(np.intp)
        if len(self.worlds) == 1:
            return worlds, self._starts_in(0, uniforms)
        starts = np.empty((len(uniforms), 2))
        for w in np.unique(worlds).tolist():
            mine = worlds == w
            starts[mine] = self._starts_in(w, uniforms[mine])
        return worlds, starts

    def _starts_in(self, w: int, uniforms: np.ndarray) -> np.ndarray:
        """(k, 2) starts in world ``w`` from ``(k, 4)`` uniforms (see :meth:`draw`), a new array."""
        listed = self._lists[w]
        if listed is not None:
            return listed[(uniforms[:, 1] * len(listed)).astype(np.intp)]
        cells = self._cells[w]
        if not len(cells):
            raise UserError(f"{self.worlds[w].label}: no free start away from the targets")
        return cells[(uniforms[:, 1] * len(cells)).astype(np.intp)] + (uniforms[:, 2:] - 0.5) * 0.25

    def choose(self, rng: np.random.Generator, options: dict | None = None) -> tuple[int, np.ndarray]:
        """``(world index, start)`` of a new episode, drawn from ``rng`` (four uniforms, one call)."""
        u = rng.random(4)
        if not options:
            worlds, starts = self.draw(u)
            return int(worlds[0]), starts[0]
        w = int(options.get("world", int(u[0] * len(self.worlds))))
        if not 0 <= w < len(self.worlds):
            raise UserError(f"options['world'] = {w} is not among the {len(self.worlds)} worlds")
        world = self.worlds[w]
        listed = self._lists[w]
        if "start" in options:
            start = np.asarray(options["start"], dtype=float)
            if start.shape == ():
                if listed is None or not 0 <= int(start) < len(listed):
                    raise UserError(f"options['start'] = {int(start)}: there are "
                                    f"{0 if listed is None else len(listed)} starts to choose from")
                return w, listed[int(start)].copy()
            start = start.reshape(2)
            if not world.is_free(start[None])[0]:
                raise UserError(f"options['start'] = {start.tolist()}: a robot of radius {world.robot_radius:g} "
                                f"does not fit there in {world.label}")
            return w, start.copy()
        _, starts = self.draw(np.concatenate([[(w + 0.5) / len(self.worlds)], u[1:]]))
        return w, starts[0]
