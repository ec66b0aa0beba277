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

from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import Episode, Evaluation, evaluate, figures
from apf_physics.world.io.mapfiles import Scenario, read_movingai_map, read_movingai_scen, scenario_points
from apf_physics.planners.base import Planner
from apf_physics.world.core import World
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
