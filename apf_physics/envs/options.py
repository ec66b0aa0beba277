"""Options shared by the navigation environments, and how an episode's world and start are chosen."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence, Union

import numpy as np

from apf_physics.world import World, load_world

WorldSpec = Union[str, Path, World, Sequence[Union[str, Path, World]]]


def resolve_worlds(world: WorldSpec | None) -> list[World]:
    """A path, a :class:`World`, or a list of them, as a list of worlds."""
    if world is None:
        from apf_physics.errors import UserError
        raise UserError("the environment needs world=<path or World or list of them>")
    items = [world] if isinstance(world, (str, Path, World)) else list(world)
    if not items:
        raise ValueError("world= is an empty list")
    return [w if isinstance(w, World) else load_world(w) for w in items]


@dataclass(frozen=True)
class StartChooser:
    """Picks each episode's world and start.

    Attributes:
        starts: ``"world"``: the world's own starts in turn (random free positions if it has
            none); ``"random"``: a random free position farther than the goal tolerance from
            every target; or an ``(S, 2)`` array used in turn.
    """

    starts: str | np.ndarray = "world"

    def choose(self, worlds: Sequence[World], rng: np.random.Generator, episode: int) -> tuple[int, np.ndarray]:
        w = int(rng.integers(len(worlds))) if len(worlds) > 1 else 0
        world = worlds[w]
        if isinstance(self.starts, str) and self.starts == "world" and len(world.starts):
            return w, world.starts[episode % len(world.starts)].copy()
        if not isinstance(self.starts, str):
            return w, np.asarray(self.starts, dtype=float).reshape(-1, 2)[episode % len(self.starts)].copy()
        for _ in range(100):
            p = world.random_free_positions(rng, 1)[0]
            if np.min(np.hypot(*(world.targets - p).T)) > world.goal_tolerance:
                return w, p
        raise RuntimeError(f"{world.name}: no free start away from the targets")


def check_starts(starts) -> str | np.ndarray:
    if isinstance(starts, str):
        if starts not in ("world", "random"):
            raise ValueError(f"starts must be 'world', 'random' or an array of points, got {starts!r}")
        return starts
    arr = np.asarray(starts, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0:
        raise ValueError(f"starts must be an (S, 2) array of points, got shape {arr.shape}")
    return arr
