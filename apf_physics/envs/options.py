"""Options shared by the environments: which worlds, how each episode's world and start are chosen."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence, Union

import numpy as np

from apf_physics.errors import UserError
from apf_physics.observation import ObserverConfig
from apf_physics.world import World
from apf_physics.worldfile import load_world

WorldSpec = Union[str, Path, World, Sequence[Union[str, Path, World]]]


def resolve_worlds(world: WorldSpec | None) -> list[World]:
    """A path (or a bundled world's name), a :class:`World`, or a list of them, as a list of worlds."""
    if world is None:
        raise UserError("the environment needs world=<path or World or list of them>")
    items = [world] if isinstance(world, (str, Path, World)) else list(world)
    if not items:
        raise UserError("world= is an empty list")
    return [w if isinstance(w, World) else load_world(w) for w in items]


def observer_config(obs_size: int, resolution: int, memory: bool, obs_scale: str,
                    observer: ObserverConfig | dict | None, previous: bool = False) -> ObserverConfig:
    """The environment's :class:`ObserverConfig`: ``observer`` if given, else built from the keyword options.

    ``previous`` adds the window of the field one step earlier (where moving obstacles were), so a
    policy can tell where they are going; ``memory`` the visit memory.
    """
    if observer is not None:
        return observer if isinstance(observer, ObserverConfig) else ObserverConfig.from_dict(observer)
    channels = ("potential",) + (("previous",) if previous else ()) + (("memory",) if memory else ())
    return ObserverConfig(size=int(obs_size), resolution=int(resolution), channels=channels, scale=obs_scale)


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
                       world.starts if self.kind == "world" and len(world.starts) else None for world in self.worlds]
        self._cells = [world.start_cells() if listed is None else None
                       for world, listed in zip(self.worlds, self._lists)]

    def draw(self, uniforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Worlds and starts of ``k`` new episodes from ``(k, 4)`` uniforms in [0, 1).

        Uniform 0 picks the world, 1 the start row (or the free cell), 2 and 3 the position
        within the cell. Returns ``(world indices (k,), starts (k, 2))``.
        """
        uniforms = np.asarray(uniforms, float).reshape(-1, 4)
        worlds = (uniforms[:, 0] * len(self.worlds)).astype(np.intp)
        starts = np.empty((len(uniforms), 2))
        for w in np.unique(worlds).tolist():
            mine = worlds == w
            u = uniforms[mine]
            listed = self._lists[w]
            if listed is not None:
                starts[mine] = listed[(u[:, 1] * len(listed)).astype(np.intp)]
                continue
            cells = self._cells[w]
            if not len(cells):
                raise UserError(f"{self.worlds[w].label}: no free start away from the targets")
            starts[mine] = cells[(u[:, 1] * len(cells)).astype(np.intp)] + (u[:, 2:] - 0.5) * 0.25
        return worlds, starts

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
