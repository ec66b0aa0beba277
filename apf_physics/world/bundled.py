"""The world files that ship with the package, found by name wherever it is installed.

The project's top-level ``worlds/`` folder installs as the package ``apf_physics.worlds``
(a wheel carries it; an editable install maps it to the checkout), so ``fixed20``,
``thesis/test1`` or ``thesis`` (a folder) name the same files from any working directory.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from apf_physics.errors import WorldError, did_you_mean

WORLD_SUFFIXES = (".yaml", ".yml")


def bundled_dir() -> Path:
    """The folder of the bundled world files (``worlds/`` in a checkout), wherever installed."""
    return Path(str(importlib.resources.files("apf_physics.worlds")))


def list_bundled() -> list[str]:
    """Names of the bundled worlds, sorted: ``fixed20``, ``thesis/test1``, ...

    Curricula (``curricula/``) are stage lists and ``maps/`` holds the map files worlds refer
    to (a ROS map's YAML and image): neither is a world, and both are left out.
    """
    root = bundled_dir()
    names = []
    for path in root.rglob("*"):
        relative = path.relative_to(root)
        if path.suffix in WORLD_SUFFIXES and path.is_file() and relative.parts[0] not in ("curricula", "maps"):
            names.append(relative.with_suffix("").as_posix())
    return sorted(names)


def resolve_world(spec: str | Path) -> Path:
    """The world file or folder that ``spec`` names.

    An existing path (or a symbolic link, even one that leads nowhere) is returned as it is. Otherwise ``spec`` is read as the name of a bundled
    world or folder, relative to :func:`bundled_dir`: ``fixed20``, ``fixed20.yaml``,
    ``thesis/test1``, ``thesis`` (the folder), ``curricula/thesis``. A leading ``worlds/``
    is dropped, so the README's ``worlds/fixed20.yaml`` works outside a checkout too.

    Raises:
        WorldError: neither a path nor a bundled name; the message suggests the nearest bundled name
            and lists some.
    """
    path = Path(spec)
    if path.exists() or path.is_symlink():   # (a broken link or a loop: reading it says so)
        return path
    name = path.as_posix()
    if name.startswith("worlds/"):
        name = name[len("worlds/"):]
    root = bundled_dir()
    if name and not path.is_absolute() and ".." not in Path(name).parts:
        for candidate in (root / name, *(root / f"{name}{suffix}" for suffix in WORLD_SUFFIXES)):
            if candidate.is_file() or (candidate.is_dir() and any(candidate.glob("*.y*ml"))):
                return candidate
    names = list_bundled()
    shown = ", ".join(names[:8]) + (f", ... ({len(names)} in all; see `apf-physics worlds`)" if len(names) > 8 else "")
    stem = name[:-len(Path(name).suffix)] if Path(name).suffix in WORLD_SUFFIXES else name
    raise WorldError(f"{spec}: no such world file, and no bundled world of that name{did_you_mean(stem, names)} "
                     f"(bundled: {shown})")
