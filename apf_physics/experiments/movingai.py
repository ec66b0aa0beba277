"""MovingAI benchmark scenarios: each line of a ``.scen`` file is one start–target pair on its map.

``apf-physics eval MAP.map --scen MAP.map.scen`` runs planners from each scenario's start to its
goal (cell centres, one cell = ``cell`` units, one step per unit by default) and reports, per
bucket, success, collisions and the path length against the scenario's optimal (octile) length.
Any-angle motion may beat the octile optimum: the ratio is reported as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from apf_physics.control.fleet import Lattice
from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import Episode, Evaluation, evaluate, figures
from apf_physics.world.io.mapfiles import Scenario, read_movingai_map, read_movingai_scen, scenario_points
from apf_physics.planners.base import Planner
from apf_physics.world.core import Fleet, World
from apf_physics.world.search import node_distances
from apf_physics.world.io.worldfile import world_from_dict


@dataclass(frozen=True)
class Trial:
    """One scenario as a world: the map with the scenario's goal as target and its start."""

    world: World
    scenario: Scenario

    @property
    def max_steps(self) -> int:
        """Three times the optimal length (a diagonal step covers √2 of it), and 50 more."""
        return int(math.ceil(3.0 * self.scenario.optimal)) + 50


def parse_buckets(text: str | None) -> tuple[int, int] | None:
    """``"A-B"`` (or ``"A"``) as an inclusive range of buckets; None for all."""
    if text is None:
        return None
    try:
        low, _, high = text.partition("-")
        bounds = (int(low), int(high or low))
    except ValueError:
        raise UserError(f"--buckets: expected A-B (e.g. 10-20) or one bucket, got {text!r}") from None
    if bounds[0] < 0 or bounds[1] < bounds[0]:
        raise UserError(f"--buckets: expected 0 <= A <= B, got {text!r}")
    return bounds


def scenario_trials(map_path: str | Path, scen_path: str | Path, buckets: tuple[int, int] | None = None,
                    limit: int | None = None, field: str = "thesis-general", cell: float = 1.0) -> list[Trial]:
    """The scenarios of ``scen_path`` on ``map_path`` as worlds sharing one map (its index and rasters).

    Args:
        map_path: The MovingAI ``.map``.
        scen_path: Its ``.scen`` file.
        buckets: Only scenarios of buckets in this inclusive range.
        limit: At most this many scenarios, taken evenly through the file (every bucket's range of
            lengths stays represented; a file lists its scenarios by bucket).
        field: The field's preset.
        cell: World units per cell (one step per unit).

    Raises:
        UserError: A file is unreadable, or a scenario does not fit the map.
    """
    grid = read_movingai_map(map_path, cell)
    scenarios = read_movingai_scen(scen_path)
    if buckets is not None:
        scenarios = [s for s in scenarios if buckets[0] <= s.bucket <= buckets[1]]
    if limit is not None and len(scenarios) > limit:
        scenarios = [scenarios[i] for i in np.linspace(0, len(scenarios) - 1, limit).round().astype(int)]
    if not scenarios:
        raise UserError(f"{scen_path}: no scenario" + (f" in buckets {buckets[0]}-{buckets[1]}" if buckets else ""))
    points = [scenario_points(s, grid) for s in scenarios]
    base = world_from_dict({"name": Path(map_path).stem, "grid": {"movingai": str(Path(map_path).resolve()), "cell": cell},
                            "field": field, "targets": [points[0][1].tolist()]}, str(map_path))
    clear = base.static_clearance(np.array([p for pair in points for p in pair]))
    for k, s in enumerate(scenarios):
        if min(clear[2 * k], clear[2 * k + 1]) < base.robot_radius:
            raise UserError(f"{scen_path}: line {s.line}: the start or goal is not on a free cell of {map_path}")
    return [Trial(base.with_task(goal, start, name=f"{base.name}@{s.line}"), s)
            for s, (start, goal) in zip(scenarios, points)]


def evaluate_trials(planner: Planner, trials: Sequence[Trial],
                    progress: Callable[[World, list[Episode]], None] | None = None) -> Evaluation:
    """Run ``planner`` on every trial, each with its own step limit (:attr:`Trial.max_steps`)."""
    episodes = []
    for trial in trials:
        episodes.extend(evaluate(planner, [trial.world], max_steps=trial.max_steps, progress=progress).episodes)
    return Evaluation(planner.name, episodes)


def bucket_summary(evaluation: Evaluation, trials: Sequence[Trial]) -> list[dict]:
    """Per bucket (and ``"all"``): episodes, successes, collisions, and the mean ratio of the path to the optimal length."""
    rows: dict[object, list[tuple]] = {}
    for episode, trial in zip(evaluation.episodes, trials):
        entry = (episode, trial.scenario.optimal)
        rows.setdefault(trial.scenario.bucket, []).append(entry)
        rows.setdefault("all", []).append(entry)
    out = []
    for bucket in sorted(rows, key=lambda b: (b == "all", b if b != "all" else 0)):
        entries = rows[bucket]
        scored = figures([e for e, _ in entries], optimal=[opt for _, opt in entries])
        ratio = scored.path_over_optimal
        out.append({"bucket": bucket, "episodes": scored.episodes, "successes": scored.successes,
                    "collisions": scored.collisions, "path_over_optimal": None if ratio is None else round(ratio, 4)})
    return out


def format_bucket_table(evaluations: Sequence[Evaluation], trials: Sequence[Trial]) -> str:
    """One row per planner and bucket, then a row for all buckets."""
    header = f"{'planner':<16} {'bucket':>6} {'eps':>5} {'success':>11} {'collide':>8} {'path/optimal':>13}"
    lines = [header, "-" * len(header)]
    for ev in evaluations:
        for row in bucket_summary(ev, trials):
            ratio = "-" if row["path_over_optimal"] is None else f"{row['path_over_optimal']:.3f}"
            n = row["episodes"]
            lines.append(f"{ev.planner:<16} {str(row['bucket']):>6} {n:>5} {row['successes']:>5}/{n:<5} "
                         f"{row['collisions'] / n:>8.1%} {ratio:>13}")
    return "\n".join(lines)


def trials_json(evaluations: Sequence[Evaluation], trials: Sequence[Trial]) -> list[dict]:
    """Per planner: each episode with its scenario (bucket, line, optimal length, ratio) and the per-bucket summary."""
    out = []
    for ev in evaluations:
        episodes = []
        for episode, trial in zip(ev.episodes, trials):
            s = trial.scenario
            data = episode.to_dict()
            data.update(bucket=s.bucket, scen_line=s.line, optimal=s.optimal,
                        path_over_optimal=round(episode.path_length / s.optimal, 4) if s.optimal > 0 else None)
            episodes.append(data)
        out.append({"planner": ev.planner, "episodes": episodes, "summary": ev.summary(),
                    "buckets": bucket_summary(ev, trials)})
    return out


def map_world(map_path: str | Path, field: str = "thesis-general", cell: float = 1.0) -> World:
    """A MovingAI map as a world (its first free cell's centre as the world's target, which no fleet uses)."""
    grid = read_movingai_map(map_path, cell)
    free = np.argwhere(~grid.occupied)
    if not len(free):
        raise UserError(f"{map_path}: the map has no free cell")
    r, c = free[0]
    target = [grid.origin[0] + (c + 0.5) * cell, grid.origin[1] + (r + 0.5) * cell]
    return world_from_dict({"name": Path(map_path).stem, "grid": {"movingai": str(Path(map_path).resolve()), "cell": cell},
                            "field": field, "targets": [target]}, str(map_path))


def scenario_fleet(map_path: str | Path, scen_path: str | Path, agents: int, field: str = "thesis-general",
                   cell: float = 1.0) -> tuple[World, Fleet]:
    """The first ``agents`` lines of a scenario file as one fleet on its map (the MAPF convention).

    Raises:
        UserError: The files are unreadable, a scenario does not fit the map, or the file has fewer
            than ``agents`` scenarios.
    """
    world = map_world(map_path, field, cell)
    scenarios = read_movingai_scen(scen_path)
    if agents > len(scenarios):
        raise UserError(f"{scen_path}: --agents {agents}: the file has only {len(scenarios)} scenarios")
    grid = read_movingai_map(map_path, cell)
    chosen = scenarios[:agents]
    points = np.array([scenario_points(s, grid) for s in chosen]).reshape(-1, 2, 2)
    labels = tuple(f"{scen_path}: line {s.line}" for s in chosen)
    optimal = np.array([s.optimal * cell for s in chosen])
    return world, Fleet(points[:, 0], points[:, 1], labels, optimal)


def draw_scenarios(map_path: str | Path, count: int, seed: int = 0) -> list[Scenario]:
    """``count`` scenarios drawn as the MAPF benchmark's random ones: distinct free starts, distinct free
    goals (none on its own start), all in the map's largest connected region (8-connected, no corner
    cut), each with its octile optimal length; buckets of 4 cells of length.

    Raises:
        UserError: The region has fewer than ``count`` free cells.
    """
    world = map_world(map_path)
    lattice = Lattice.of(world, (0.5, 0.5))
    regions = lattice.regions()
    largest = np.bincount(regions[regions >= 0]).argmax()
    region = np.flatnonzero(regions == largest)
    if count > len(region) or count < 1:
        raise UserError(f"{map_path}: --count {count}: the largest connected region has {len(region)} free cells")
    rng = np.random.default_rng(seed)
    starts = rng.choice(region, count, replace=False)
    goals = rng.choice(region, count, replace=False)
    for i in np.flatnonzero(starts == goals).tolist():   # none on its own start: trade goals with a neighbour
        j = (i + 1) % count
        goals[i], goals[j] = goals[j], goals[i]
    rows, cols = lattice.shape
    name = Path(map_path).name
    out = []
    for start, goal in zip(starts.tolist(), goals.tolist()):
        optimal = float(node_distances(lattice.ok, lattice.offsets, lattice.lengths, goal)[start])
        (sr, sc), (gr, gc) = divmod(start, cols), divmod(goal, cols)
        out.append(Scenario(int(optimal // 4), name, cols, rows, (sc, rows - 1 - sr), (gc, rows - 1 - gr), optimal))
    return out
