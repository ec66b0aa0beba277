"""Curriculum stages for training: which worlds, in which order, with rehearsal.

A curriculum file (YAML) lists stages; each stage names world files relative to the
curriculum file::

    stages:
    - name: basic
      worlds: [thesis/basic1.yaml, thesis/basic2.yaml]
    - name: line
      worlds: [thesis/curriculum1_line.yaml]

Rehearsal (thesis §6.3.2): stage ``i`` trains its own worlds together with the worlds of all
earlier stages, in random order, so that the network does not forget what it learned
before. :attr:`Stage.worlds` holds only the stage's own worlds; :func:`rehearsal_worlds`
(or :attr:`Stage.training_worlds`) gives the set a trainer uses at that stage.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence


from apf_physics.errors import UserError
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import load_world, read_yaml_file


@dataclass(frozen=True)
class Stage:
    """One curriculum stage.

    Attributes:
        name: The stage's name (unique within the curriculum).
        worlds: The worlds this stage introduces.
        training_worlds: The worlds trained at this stage: the earlier stages' worlds, then
            this stage's own (rehearsal).
    """

    name: str
    worlds: tuple[World, ...]
    training_worlds: tuple[World, ...] = ()


def rehearsal_worlds(stages: Sequence[Stage], index: int) -> list[World]:
    """The worlds trained at stage ``index``: its own and every earlier stage's, in stage order."""
    return [w for stage in stages[: index + 1] for w in stage.worlds]


def load_curriculum(path: str | Path) -> list[Stage]:
    """Read a curriculum file and load every world it names.

    Args:
        path: The curriculum YAML file.

    Returns:
        The stages in order, each with its own worlds and its rehearsal set.

    Raises:
        UserError: the file is missing or not YAML, or a key is missing, unknown or of the wrong
            type (the message names the file and the key).
        WorldError: a world file is missing or invalid (the message names that file).
    """
    path = Path(path)
    source = str(path)

    def fail(key: str, problem: str) -> UserError:
        return UserError(f"{source}: {key}: {problem}" if key else f"{source}: {problem}")

    data: Any = read_yaml_file(path, "curriculum")
    if not isinstance(data, dict):
        raise fail("", f"a curriculum file must be a mapping with a 'stages' list, got {type(data).__name__}")
    unknown = sorted(set(map(str, data)) - {"stages"})
    if unknown:
        raise fail(unknown[0], "unknown key (allowed: stages)")
    raw_stages = data.get("stages")
    if raw_stages is None:
        raise fail("stages", "missing")
    if not isinstance(raw_stages, list) or not raw_stages:
        raise fail("stages", "expected a non-empty list of stages")

    stages: list[Stage] = []
    seen: set[str] = set()
    cache: dict[Path, World] = {}
    for i, raw in enumerate(raw_stages):
        key = f"stages[{i}]"
        if not isinstance(raw, dict):
            raise fail(key, f"expected a mapping with 'name' and 'worlds', got {type(raw).__name__}")
        unknown = sorted(set(map(str, raw)) - {"name", "worlds"})
        if unknown:
            raise fail(f"{key}.{unknown[0]}", "unknown key (allowed: name, worlds)")
        name = raw.get("name")
        if not isinstance(name, str) or not name:
            raise fail(f"{key}.name", "missing" if name is None else f"expected a non-empty string, got {name!r}")
        if name in seen:
            raise fail(f"{key}.name", f"duplicate stage name {name!r}")
        seen.add(name)
        files = raw.get("worlds")
        if files is None:
            raise fail(f"{key}.worlds", "missing")
        if not isinstance(files, list) or not files:
            raise fail(f"{key}.worlds", "expected a non-empty list of world files")
        worlds = []
        for j, f in enumerate(files):
            if not isinstance(f, str) or not f:
                raise fail(f"{key}.worlds[{j}]", f"expected a world file path, got {f!r}")
            world_path = (path.parent / f).resolve()
            if world_path not in cache:
                if not world_path.is_file():
                    raise fail(f"{key}.worlds[{j}]", f"no such world file {f!r} (resolved to {world_path})")
                cache[world_path] = load_world(world_path)
            worlds.append(cache[world_path])
        stages.append(Stage(name, tuple(worlds)))
    return [Stage(s.name, s.worlds, tuple(rehearsal_worlds(stages, i))) for i, s in enumerate(stages)]
