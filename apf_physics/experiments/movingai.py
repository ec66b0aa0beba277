"""MovingAI benchmark scenarios: each line of a ``.scen`` file is one start–target pair on its map.

``apf-physics eval MAP.map --scen MAP.map.scen`` runs planners from each scenario's start to its
goal (cell centres, one cell = ``cell`` units, one step per unit by default) and reports, per
bucket, success, collisions, trapped and timeouts, and the path length against the scenario's
optimal (octile) length, both in steps (the optimal length in cells times ``cell``). Any-angle
motion may beat the octile optimum: the ratio is reported as it is.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from apf_physics.control.fleet import Lattice
from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import Episode, Evaluation, evaluate, figures
from apf_physics.world.io.mapfiles import MAX_PROBLEMS, Scenario, read_movingai_map, read_scenarios, scenario_points
from apf_physics.planners.base import Planner
from apf_physics.world.core import Fleet, World
from apf_physics.world.search import node_distances
from apf_physics.world.io.worldfile import world_from_dict


@dataclass(frozen=True)
class Trial:
    """One scenario as a world: the map with the scenario's goal as target and its start.

    Attributes:
        world: The map with the scenario's start and goal.
        scenario: The scenario file's line.
        cell: Steps per map cell (``eval --cell``): the scenario's lengths are in cells, paths in steps.
    """

    world: World
    scenario: Scenario
    cell: float = 1.0

    @property
    def optimal(self) -> float:
        """The scenario's optimal length in steps (its octile length in cells, times :attr:`cell`)."""
        return self.scenario.optimal * self.cell

    @property
    def max_steps(self) -> int:
        """Three times the optimal length in steps (a diagonal step covers √2 of it), and 50 more."""
        return int(math.ceil(3.0 * self.optimal)) + 50


def parse_buckets(text: str | None) -> tuple[int, int] | None:
    """``"A-B"`` (or ``"A"``) as an inclusive range of buckets; None for all."""
    if text is None:
        return None
    low, dash, high = text.strip().partition("-")
    if not re.fullmatch(r"[0-9]{1,9}", low) or (dash and not re.fullmatch(r"[0-9]{1,9}", high)):
        raise UserError(f"--buckets: expected A-B (e.g. 10-20) or one bucket A, whole numbers, got {text!r}")
    bounds = (int(low), int(high) if dash else int(low))
    if bounds[1] < bounds[0]:
        raise UserError(f"--buckets: expected A <= B, got {text!r}")
    return bounds


def scenario_trials(map_path: str | Path, scen_path: str | Path, buckets: tuple[int, int] | None = None,
                    limit: int | None = None, field: str = "thesis-general", cell: float = 1.0,
                    warn: Callable[[str], None] | None = None) -> list[Trial]:
    """The scenarios of ``scen_path`` on ``map_path`` as worlds sharing one map (its index and rasters).

    Args:
        map_path: The MovingAI ``.map``.
        scen_path: Its ``.scen`` file.
        buckets: Only scenarios of buckets in this inclusive range.
        limit: At most this many scenarios, taken evenly through the file (every bucket's range of
            lengths stays represented; a file lists its scenarios by bucket). Applied while reading.
        field: The field's preset.
        cell: World units per cell (one step per unit).
        warn: Told, in one line, when scenario lines name another map than ``map_path`` (by file
            name): they are run on ``map_path`` all the same (a map renamed, or copied).

    Raises:
        UserError: A file is unreadable, or scenarios do not fit the map (every such line, as
            :func:`~apf_physics.world.io.mapfiles.read_scenarios` reports bad lines).
    """
    grid = read_movingai_map(map_path, cell)
    rows, cols = grid.occupied.shape
    read = read_scenarios(scen_path, buckets, limit, map_name=Path(map_path).name, map_size=(cols, rows))
    scenarios = read.scenarios
    if not scenarios:
        raise UserError(f"{scen_path}: no scenario" + (f" in buckets {buckets[0]}-{buckets[1]}" if buckets else ""))
    if read.other_maps and warn is not None:
        warn(f"{scen_path}: {read.other_maps:,} of {read.lines:,} scenario lines name a map other than "
             f"{Path(map_path).name} (the first at line {read.first_other}); they are run on {map_path}")
    points = [scenario_points(s, grid) for s in scenarios]
    base = world_from_dict({"name": Path(map_path).stem, "grid": {"movingai": str(Path(map_path).resolve()), "cell": cell},
                            "field": field, "targets": [points[0][1].tolist()]}, str(map_path), confine=False)
    clear = base.static_clearance(np.array([p for pair in points for p in pair]))
    blocked = [s for k, s in enumerate(scenarios) if min(clear[2 * k], clear[2 * k + 1]) < base.robot_radius]
    if blocked:
        lines = [f"{scen_path}: line {s.line}: the start or goal is not on a free cell of {map_path}"
                 for s in blocked[:MAX_PROBLEMS]]
        if len(blocked) > MAX_PROBLEMS:
            lines.append(f"{scen_path}: and {len(blocked) - MAX_PROBLEMS:,} more such lines ({len(blocked):,} in all)")
        raise UserError("\n".join(lines))
    return [Trial(base.with_task(goal, start, name=f"{base.name}@{s.line}"), s, cell)
            for s, (start, goal) in zip(scenarios, points)]


def evaluate_trials(planner: Planner, trials: Sequence[Trial],
                    progress: Callable[[World, list[Episode]], None] | None = None) -> Evaluation:
    """Run ``planner`` on every trial, each with its own step limit (:attr:`Trial.max_steps`)."""
    episodes = []
    for trial in trials:
        episodes.extend(evaluate(planner, [trial.world], max_steps=trial.max_steps, progress=progress).episodes)
    return Evaluation(planner.name, episodes)


def bucket_summary(evaluation: Evaluation, trials: Sequence[Trial]) -> list[dict]:
    """Per bucket (and ``"all"``): episodes, successes, collisions, trapped, timeouts, and the
    mean ratio of the path to the optimal length (both in steps)."""
    rows: dict[object, list[tuple]] = {}
    for episode, trial in zip(evaluation.episodes, trials):
        entry = (episode, trial.optimal)
        rows.setdefault(trial.scenario.bucket, []).append(entry)
        rows.setdefault("all", []).append(entry)
    out = []
    for bucket in sorted(rows, key=lambda b: (b == "all", b if b != "all" else 0)):
        entries = rows[bucket]
        scored = figures([e for e, _ in entries], optimal=[opt for _, opt in entries])
        ratio = scored.path_over_optimal
        out.append({"bucket": bucket, "episodes": scored.episodes, "successes": scored.successes,
                    "collisions": scored.collisions, "trapped": scored.trapped,
                    "timeouts": sum(e.outcome == "timeout" for e, _ in entries),
                    "path_over_optimal": None if ratio is None else round(ratio, 4)})
    return out


def format_bucket_table(evaluations: Sequence[Evaluation], trials: Sequence[Trial]) -> str:
    """One row per planner and bucket, then a row for all buckets."""
    header = (f"{'planner':<16} {'bucket':>6} {'eps':>5} {'success':>11} {'collide':>8} {'trapped':>8} "
              f"{'timeout':>8} {'path/optimal':>13}")
    lines = [header, "-" * len(header)]
    for ev in evaluations:
        for row in bucket_summary(ev, trials):
            ratio = "-" if row["path_over_optimal"] is None else f"{row['path_over_optimal']:.3f}"
            n = row["episodes"]
            lines.append(f"{ev.planner:<16} {str(row['bucket']):>6} {n:>5} {row['successes']:>5}/{n:<5} "
                         f"{row['collisions'] / n:>8.1%} {row['trapped'] / n:>8.1%} {row['timeouts'] / n:>8.1%} "
                         f"{ratio:>13}")
    return "\n".join(lines)


def trials_json(evaluations: Sequence[Evaluation], trials: Sequence[Trial]) -> list[dict]:
    """Per planner: each episode with its scenario (bucket, line, optimal length, ratio) and the per-bucket summary."""
    out = []
    for ev in evaluations:
        episodes = []
        for episode, trial in zip(ev.episodes, trials):
            s = trial.scenario
            data = episode.to_dict()
            data.update(bucket=s.bucket, scen_line=s.line, optimal=s.optimal, optimal_steps=trial.optimal,
                        path_over_optimal=round(episode.path_length / trial.optimal, 4) if trial.optimal > 0 else None)
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
                            "field": field, "targets": [target]}, str(map_path), confine=False)


def scenario_fleet(map_path: str | Path, scen_path: str | Path, agents: int, field: str = "thesis-general",
                   cell: float = 1.0) -> tuple[World, Fleet]:
    """The first ``agents`` lines of a scenario file as one fleet on its map (the MAPF convention).

    Raises:
        UserError: The files are unreadable, a scenario does not fit the map, or the file has fewer
            than ``agents`` scenarios.
    """
    world = map_world(map_path, field, cell)
    grid = read_movingai_map(map_path, cell)
    rows, cols = grid.occupied.shape
    scenarios = read_scenarios(scen_path, map_name=Path(map_path).name, map_size=(cols, rows)).scenarios
    if agents > len(scenarios):
        raise UserError(f"{scen_path}: --agents {agents}: the file has only {len(scenarios)} scenarios")
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
