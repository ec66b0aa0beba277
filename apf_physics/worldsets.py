"""Generated world sets for training, validation and held-out tests: world files and a labelled manifest.

:func:`label_starts` labels each start of a world with what a benchmark needs to know of it:
whether gradient descent is trapped from it (rolled out through the physics) and the length
of the shortest path (:mod:`apf_physics.search`). :func:`generate_set` draws worlds with
:func:`~apf_physics.generate.generate_world` and writes them with a ``manifest.json`` of
those labels.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from apf_physics.errors import UserError
from apf_physics.generate import generate_world
from apf_physics.planners.gradient import GradientPlanner
from apf_physics.rollout import rollout
from apf_physics.search import shortest_path_length
from apf_physics.world import World
from apf_physics.worldfile import dump_world_yaml


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
            "straight_distance": round(float(np.min(np.hypot(*(world.targets - start).T))), 3),
        })
    return labels


def generate_set(family: str | list[str], count: int, seed: int, out: str | Path, size: float = 50,
                 field: str = "thesis-general", n_starts: int = 4, label: bool = True) -> dict:
    """Write ``count`` worlds (``<family>_<k>.yaml``) and ``manifest.json`` into ``out``.

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

    Returns:
        The manifest: ``{"seed", "family", "size", "field", "n_starts", "worlds": [{"file",
        "family", "starts": [{"start", "gradient_outcome", "gradient_trapped",
        "astar_length", "straight_distance"}, ...]}, ...], "summary"}``.
    """
    families = [family] if isinstance(family, str) else list(family)
    if count < 1:
        raise UserError(f"--count: must be at least 1, got {count}")
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out}: cannot create the output directory ({exc.strerror})") from None
    rng = np.random.default_rng(seed)
    width = len(str(count - 1))
    records = []
    for k in range(count):
        fam = families[k % len(families)]
        name = f"{fam}_{k:0{width}d}"
        world = generate_world(fam, rng, size=size, field=field, n_starts=n_starts, name=name)
        path = out / f"{name}.yaml"
        try:
            path.write_text(f"# Generated: family {fam}, seed {seed}, world {k} of {count}.\n"
                            + dump_world_yaml(world), encoding="utf-8")
        except OSError as exc:
            raise UserError(f"{path}: cannot write the world file ({exc.strerror})") from None
        if label:
            starts = label_starts(world)
        else:
            starts = [{"start": [float(v) for v in s], "astar_length": round(shortest_path_length(world, s), 3)}
                      for s in world.starts]
        records.append({"file": path.name, "family": fam, "starts": starts})
    all_starts = [s for r in records for s in r["starts"]]
    summary = {"worlds": len(records), "starts": len(all_starts)}
    if label:
        trapped = sum(s["gradient_trapped"] for s in all_starts)
        summary.update(gradient_trapped=trapped, gradient_trapped_rate=round(trapped / len(all_starts), 4))
    manifest = {"seed": seed, "family": families[0] if len(families) == 1 else families, "size": size,
                "field": field, "n_starts": n_starts, "worlds": records, "summary": summary}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    return manifest
