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

from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import Episode, Evaluation, evaluate, figures
from apf_physics.world.io.mapfiles import MAX_PROBLEMS, Scenario, read_movingai_map, read_scenarios, scenario_points
from apf_physics.planners.base import Planner
from apf_physics.world.core import World
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
