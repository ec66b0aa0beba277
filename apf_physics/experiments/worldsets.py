"""Generated world sets for training, validation and held-out tests: world files and a labelled manifest.

:func:`label_starts` labels each start of a world with what a benchmark needs to know of it:
whether gradient descent is trapped from it (rolled out through the physics) and the length
of the shortest path (:mod:`apf_physics.world.search`). :func:`generate_set` draws worlds with
:func:`~apf_physics.world.generate.generate_world` and writes them with a ``manifest.json`` of
those labels.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import numpy as np

from apf_physics.errors import UserError
from apf_physics.world.generate import generate_world
from apf_physics.planners.gradient import GradientPlanner
from apf_physics.common.safefile import check_writable, write_text
from apf_physics.render.video import progress_bar
from apf_physics.experiments.rollout import rollout
from apf_physics.world.search import shortest_path_length
from apf_physics.world.core import World
from apf_physics.world.io.worldfile import dump_world_yaml


def label_starts(world: World, max_steps: int | None = None) -> list[dict]:
    """Per start: gradient descent's outcome (through the physics) and the A* path length."""
    episodes = rollout(world, GradientPlanner(), world.starts, max_steps=max_steps)
    labels = []
    for start, episode in zip(world.starts, episodes):
        length = shortest_path_length(world, start)
        labels.append({
            "start": [float(v) for v in start],
            "gradient_outcome": episode.outcome,
            "gradient_trapped": episode.outcome != "reached",
            "astar_length": None if length is None else round(length, 3),
            "straight_distance": round(float(world.distance_to_target(start)[0]), 3),
        })
    return labels


GENERATED = "# Generated: family "
"""How every world file that :func:`generate_set` writes begins (how ``--force`` knows its own files)."""
MANIFEST = "manifest.json"
WORLD_SUFFIXES = (".yaml", ".yml")


def _written_by_generate(path: Path) -> bool:
    """Whether ``path`` is a regular file that begins as :func:`generate_set` begins its world files."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    try:
        return stat.S_ISREG(os.fstat(fd).st_mode) and os.read(fd, len(GENERATED)) == GENERATED.encode()
    except OSError:
        return False
    finally:
        os.close(fd)


def previous_worlds(out: Path, force: bool) -> list[Path]:
    """The world files of an earlier set in ``out``, which a new set replaces.

    Raises:
        UserError: ``out`` is not a folder; it is not empty and ``force`` is False; or it
            holds world files that :func:`generate_set` did not write (``--force`` never
            removes those: nothing a user wrote is lost).
    """
    if not out.exists() and not out.is_symlink():
        return []
    if not out.is_dir():
        raise UserError(f"--out: {out} is not a directory")
    entries = sorted(out.iterdir())
    if not entries:
        return []
    if not force:
        shown = ", ".join(e.name for e in entries[:3]) + (", ..." if len(entries) > 3 else "")
        raise UserError(f"--out: {out} is not empty ({shown}); choose an empty or new folder, or pass --force "
                        "to replace the worlds an earlier `generate` wrote there")
    worlds = [e for e in entries if e.suffix in WORLD_SUFFIXES]
    foreign = [e.name for e in worlds if not _written_by_generate(e)]
    if foreign:
        shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise UserError(f"--out: {out} holds world files that `generate` did not write ({shown}); --force replaces "
                        "only generated worlds: move those away or choose another folder")
    return worlds


def generate_set(family: str | list[str], count: int, seed: int, out: str | Path, size: float = 50,
                 field: str = "thesis-general", n_starts: int = 4, label: bool = True, force: bool = False,
                 progress: bool = False) -> dict:
    """Write ``count`` worlds (``<family>_<k>.yaml``) and ``manifest.json`` into ``out``.

    ``out`` must be empty or new; with ``force`` the worlds of an earlier set there are
    replaced (none is left behind to be evaluated with the new ones), but world files that
    this function did not write are never touched: their presence is an error. The whole set
    is drawn and labelled before anything is written, and every file is written atomically.

    Args:
        family: A family name, or several (worlds cycle through them).
        count: Number of worlds.
        seed: Seed of the one random generator all worlds are drawn from.
        out: Output directory (created).
        size: Map size.
        field: Field preset name.
        n_starts: Starts per world.
        label: Roll out gradient descent from every start and record the outcome (the
            manifest's ``gradient_trapped``); without it only the A* lengths are recorded.
        force: Replace an earlier set in ``out``.
        progress: Show a progress bar on stderr (when it is a terminal).

    Returns:
        The manifest: ``{"seed", "family", "size", "field", "n_starts", "worlds": [{"file",
        "family", "starts": [{"start", "gradient_outcome", "gradient_trapped",
        "astar_length", "straight_distance"}, ...]}, ...], "summary"}``.

    Raises:
        UserError: a bad count, an ``out`` that is not empty (see above), or a file that
            cannot be written.
    """
    families = [family] if isinstance(family, str) else list(family)
    if count < 1:
        raise UserError(f"--count: must be at least 1, got {count}")
    out = Path(out)
    stale = previous_worlds(out, force)
    check_writable(out / MANIFEST, create_parent=True)
    rng = np.random.default_rng(seed)
    width = len(str(count - 1))
    records, texts = [], {}
    bar = progress_bar(count, "generate", "world", progress)
    for k in range(count):
        fam = families[k % len(families)]
        name = f"{fam}_{k:0{width}d}" if size == 50 else f"{fam}{size:g}_{k:0{width}d}"   # sets of two sizes can mix
        world = generate_world(fam, rng, size=size, field=field, n_starts=n_starts, name=name)
        texts[f"{name}.yaml"] = f"{GENERATED}{fam}, seed {seed}, world {k} of {count}.\n" + dump_world_yaml(world)
        if label:
            starts = label_starts(world)
        else:
            starts = [{"start": [float(v) for v in s], "astar_length": round(shortest_path_length(world, s), 3)}
                      for s in world.starts]
        records.append({"file": f"{name}.yaml", "family": fam, "starts": starts})
        bar.update(1)
    bar.close()
    all_starts = [s for r in records for s in r["starts"]]
    summary = {"worlds": len(records), "starts": len(all_starts)}
    if label:
        trapped = sum(s["gradient_trapped"] for s in all_starts)
        summary.update(gradient_trapped=trapped, gradient_trapped_rate=round(trapped / len(all_starts), 4))
    manifest = {"seed": seed, "family": families[0] if len(families) == 1 else families, "size": size,
                "field": field, "n_starts": n_starts, "worlds": records, "summary": summary}
    for path in stale:
        if path.name not in texts:
            try:
                path.unlink()
            except OSError as exc:
                raise UserError(f"cannot remove {path}, a world of the earlier set ({exc.strerror or exc})") from None
    for name, text in texts.items():
        write_text(out / name, text)
    write_text(out / MANIFEST, json.dumps(manifest, indent=1))
    return manifest
