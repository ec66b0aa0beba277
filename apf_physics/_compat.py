"""The module paths of the flat layout (0.x), importable for one more release with a warning.

The package's modules moved into subpackages that say where each belongs (README, "Layout"):
``apf_physics.evaluate`` is now ``apf_physics.experiments.evaluate``, ``apf_physics.rl`` is
``apf_physics.learning``, and so on (:data:`MOVED`). Code that imports an old path gets the
module at its new home, the same object, and one :class:`DeprecationWarning` naming it.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType

MOVED = {
    "geometry": "common.geometry",
    "transforms": "common.transforms",
    "compiled": "common.compiled",
    "safefile": "common.safefile",
    "safeyaml": "common.safeyaml",
    "kinematics": "world.kinematics",
    "buckets": "world.buckets",
    "obstacles": "world.obstacles",
    "spatial": "world.spatial",
    "field": "world.field",
    "bundled": "world.bundled",
    "search": "world.search",
    "mapfiles": "world.io.mapfiles",
    "worldschema": "world.io.schema",
    "worldfile": "world.io.worldfile",
    "generate": "world.generate",
    "contacts": "sim.contacts",
    "tiles": "sim.tiles",
    "sweep": "sim.swept",
    "physics": "sim.physics",
    "engine": "sim.engine",
    "actions": "control.shield",
    "formation": "control.formation",
    "tracking": "control.tracking",
    "observation": "sensing.observation",
    "lidar": "sensing.lidar",
    "rollout": "experiments.rollout",
    "evaluate": "experiments.evaluate",
    "worldsets": "experiments.worldsets",
    "benchmark": "experiments.movingai",
    "campaign": "experiments.campaign",
    "curriculum": "learning.curriculum",
    "rl": "learning",
    "rl.evaluation": "learning.validation",
    "commands": "cli",
    "envs.formations": "envs.parallel",
}
"""Old module path → new, both under ``apf_physics``. A package's old path covers its modules too
(``apf_physics.rl.config`` → ``apf_physics.learning.config``)."""

ROOT = "apf_physics"


def new_name(old: str) -> str | None:
    """The module's path today for an old path (``apf_physics.…``), or None when it did not move."""
    if not old.startswith(ROOT + "."):
        return None
    tail = old[len(ROOT) + 1:]
    parts = tail.split(".")
    for cut in range(len(parts), 0, -1):      # the longest moved prefix wins (rl.evaluation before rl)
        head = ".".join(parts[:cut])
        if head in MOVED:
            return ".".join([ROOT, MOVED[head], *parts[cut:]])
    return None


class _Alias(importlib.abc.Loader):
    """Loads an old path as the module at its new home (one object under both names)."""

    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        warnings.warn(f"{spec.name} moved to {self.new}; the old path goes in the next release",
                      DeprecationWarning, stacklevel=2)
        module = importlib.import_module(self.new)
        self.spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        # Already executed at its new home; the import system has just given it the old path's
        # spec: give it back its own.
        module.__spec__ = self.spec


class _OldPaths(importlib.abc.MetaPathFinder):
    """Finds the flat layout's module paths (:data:`MOVED`) and aliases them to their new homes."""

    def find_spec(self, fullname, path=None, target=None):
        new = new_name(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _Alias(new))


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once): before the path finder, which would
    otherwise load an old package's modules a second time under their old names."""
    if not any(isinstance(f, _OldPaths) for f in sys.meta_path):
        sys.meta_path.insert(0, _OldPaths())
