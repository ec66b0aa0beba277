"""Evaluate planners over worlds and starts: episodes, summaries, tables and JSON."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from apf_physics.planners.base import Planner
from apf_physics.common.safefile import check_writable, write_text
from apf_physics.experiments.rollout import Episode, kinematics_option, rollout, rollout_formations
from apf_physics.world.core import World
from apf_physics.world.io.units import same_units


@dataclass(frozen=True)
class Figures:
    """What a set of episodes scores: every report's figures come from here (:func:`figures`).

    Attributes:
        episodes: How many episodes.
        successes: Episodes that succeeded (:attr:`~apf_physics.experiments.rollout.Episode.success`).
        collisions: Episodes that ended in a collision.
        trapped: Episodes that ended trapped.
        success_rate: ``successes / episodes`` (0 without episodes); likewise
            ``collision_rate`` and ``trapped_rate``.
        mean_steps: Mean steps of the successes (None without any).
        mean_path_length: Mean path length of the successes (None without any).
        length_ratio: Summed path length over summed optimal length, both over the successes
            that have an optimal length (None without any, or without optimal lengths).
        path_over_optimal: The mean over the same successes of path length / optimal length.
        spl: Success weighted by path length (Anderson et al. 2018): the mean over all
            episodes of ``optimal / max(path, optimal)`` for a success, else 0 (a success
            without an optimal length counts 1). None without optimal lengths.
        trap_success: The success rate over the episodes whose starts are marked trapped
            (None without marks, or none marked).
    """

    episodes: int
    successes: int
    collisions: int
    trapped: int
    success_rate: float
    collision_rate: float
    trapped_rate: float
    mean_steps: Optional[float]
    mean_path_length: Optional[float]
    length_ratio: Optional[float] = None
    path_over_optimal: Optional[float] = None
    spl: Optional[float] = None
    trap_success: Optional[float] = None


def figures(episodes: Sequence[Episode], optimal: Sequence[Optional[float]] | np.ndarray | None = None,
            trapped: Sequence[bool] | np.ndarray | None = None) -> Figures:
    """The figures of ``episodes`` (see :class:`Figures`).

    Args:
        episodes: The episodes.
        optimal: Per episode, the optimal (A*, octile) path length from its start (None, nan,
            or 0: none); without it, no length ratios and no SPL.
        trapped: Per episode, whether its start traps gradient descent; without it, no ``trap_success``.
    """
    n = len(episodes)
    success = np.array([e.success for e in episodes], bool)
    length = np.array([e.path_length for e in episodes], float)
    ok = [e for e in episodes if e.success]
    collisions = sum(e.outcome == "collision" for e in episodes)
    stuck = sum(e.outcome == "trapped" for e in episodes)
    extra: dict = {}
    if optimal is not None:
        best = np.array([np.nan if v is None else v for v in optimal], float)
        efficient = success & np.isfinite(best) & (best > 0)
        spl = np.where(efficient, best / np.maximum(length, np.where(efficient, best, 1.0)), success.astype(float))
        extra.update(
            length_ratio=float(length[efficient].sum() / best[efficient].sum()) if efficient.any() else None,
            path_over_optimal=float(np.mean(length[efficient] / best[efficient])) if efficient.any() else None,
            spl=float(spl.mean()) if n else None)
    if trapped is not None:
        marked = np.asarray(trapped, bool)
        extra["trap_success"] = float(success[marked].mean()) if marked.any() else None
    return Figures(
        episodes=n, successes=len(ok), collisions=collisions, trapped=stuck,
        success_rate=len(ok) / n if n else 0.0,
        collision_rate=collisions / n if n else 0.0,
        trapped_rate=stuck / n if n else 0.0,
        mean_steps=float(np.mean([e.steps for e in ok])) if ok else None,
        mean_path_length=float(np.mean([e.path_length for e in ok])) if ok else None,
        **extra)


@dataclass
class Evaluation:
    """All episodes of one planner."""

    planner: str
    episodes: list[Episode]

    def summary(self, episodes: Sequence[Episode] | None = None) -> dict:
        """The figures of ``episodes`` (default: all). Lengths (``mean_path_length``,
        ``min_robot_distance``) are in the world files' units, named by ``units`` (None when the
        files name none); over worlds in different units they are None (``units``: ``"mixed"``).
        ``mean_steps`` counts control steps."""
        eps = self.episodes if episodes is None else list(episodes)
        n = len(eps)
        score = figures(eps)
        frame = same_units([e.frame for e in eps]) if eps else None
        scale = frame.unit if frame is not None else None

        def length(value: float | None, digits: int) -> float | None:
            return None if value is None or scale is None else round(value * scale, digits)
        extra = {}
        formations = [e.formation for e in eps if e.formation is not None]
        if formations and len(formations) == n:  # formations: link and robot–robot figures
            steps = np.array([max(e.steps, 1) for e in eps], float)
            links = [np.asarray(f.link_in_range, float) for f in formations]
            in_range = sum(float(np.sum(share) * s) for share, s in zip(links, steps))
            link_steps = sum(len(share) * s for share, s in zip(links, steps))
            closest = [f.min_robot_distance for f in formations if f.min_robot_distance is not None]
            extra = {
                "links_in_range": round(in_range / link_steps, 4) if link_steps else 1.0,
                "episodes_all_links_99": int(sum(share.min(initial=1.0) >= 0.99 for share in links)),
                "robot_robot_collisions": int(sum(f.robot_robot_collisions for f in formations)),
                "min_robot_distance": length(float(min(closest)), 4) if closest else None,   # None: robots alone
            }
            if len({len(share) for share in links}) == 1:   # the same formation everywhere: per link
                shares = np.array(links).reshape(n, -1)
                extra["link_in_range"] = [round(float(v), 4) for v in (shares * steps[:, None]).sum(0) / steps.sum()]
            crowds = {}
            for e in eps:
                if e.formation.crowd is not None:
                    crowds.setdefault(e.formation.crowd, []).append(e)
            if crowds:   # several formations per world: whole-world figures
                extra.update(
                    worlds=len(crowds),
                    worlds_all_arrived=sum(all(e.success for e in members) for members in crowds.values()),
                    between_collisions=int(sum(f.between_collisions for f in formations)),
                    within_collisions=int(sum(f.robot_robot_collisions - f.between_collisions for f in formations)),
                    deadlocks=int(sum(f.deadlocks for f in formations)),
                )
        return {
            "units": (frame.name or None) if frame is not None else ("mixed" if eps else None),
            "episodes": n,
            "successes": score.successes,
            "success_rate": round(score.success_rate, 4),
            "collision_rate": round(score.collision_rate, 4),
            "trapped_rate": round(score.trapped_rate, 4),
            "mean_steps": None if score.mean_steps is None else round(score.mean_steps, 2),
            "mean_path_length": length(score.mean_path_length, 3),
            **extra,
        }

    def to_dict(self) -> dict:
        return {"planner": self.planner, "episodes": [e.to_dict() for e in self.episodes], "summary": self.summary()}


def evaluate(planner: Planner, worlds: Sequence[World], starts: dict[str, np.ndarray] | None = None,
             max_steps: int | None = None, formation: bool = False,
             progress: Callable[[World, list[Episode]], None] | None = None,
             kinematics: str | None = None) -> Evaluation:
    """Run ``planner`` from every start of every world (or from ``starts[world.name]``).

    Args:
        planner: The planner (of the leaders, with ``formation``).
        worlds: The worlds.
        starts: Starts per world name, instead of the worlds' own.
        max_steps: Step limit per episode (default: :func:`~apf_physics.experiments.rollout.default_max_steps`).
        formation: Run each world's formation (its followers behind each leader).
        progress: Called with each world and its episodes once they are done.
        kinematics: ``"holonomic"`` or ``"unicycle"``: the robots of every world are of that kind
            (unicycles with the world file's limits, else the defaults); None: each world file's.

    Raises:
        UserError: An unknown ``kinematics``.
    """
    unicycle = kinematics_option(kinematics)
    episodes: list[Episode] = []
    for world in worlds:
        if formation and world.formations:   # several formations at once, each to its own target
            done = rollout_formations(world, planner, max_steps=max_steps, unicycle=unicycle)
        else:
            s = world.starts if starts is None else starts[world.name]
            done = rollout(world, planner, s, max_steps=max_steps, formation=formation, unicycle=unicycle)
        episodes.extend(done)
        if progress is not None:
            progress(world, done)
    return Evaluation(f"{planner.name}+formation" if formation else planner.name, episodes)


def format_table(evaluations: Sequence[Evaluation]) -> str:
    """One row per planner and world, then a total row per planner.

    ``steps``: the mean control steps of the successes; ``length``: their mean path length in the
    world file's units (named after it when the file names its unit; ``-`` over worlds in
    different units)."""
    header = (f"{'planner':<20} {'world':<28} {'eps':>5} {'success':>9} {'collide':>8} {'trapped':>8} {'steps':>7} "
              f"{'length':>10}")
    lines = [header, "-" * len(header)]

    def row(planner: str, world: str, summary: dict) -> str:
        steps = "-" if summary["mean_steps"] is None else f"{summary['mean_steps']:.1f}"
        units = summary["units"] if summary["units"] not in (None, "mixed") else ""
        length = ("-" if summary["mean_path_length"] is None
                  else f"{summary['mean_path_length']:.2f}" + (f" {units}" if units else ""))
        return (f"{planner:<20} {world:<28} {summary['episodes']:>5} "
                f"{summary['successes']:>4}/{summary['episodes']:<4} {summary['collision_rate']:>8.1%} "
                f"{summary['trapped_rate']:>8.1%} {steps:>7} {length:>10}")

    notes = []
    for ev in evaluations:
        names = list(dict.fromkeys(e.world for e in ev.episodes))
        for name in names:
            lines.append(row(ev.planner, name, ev.summary([e for e in ev.episodes if e.world == name])))
        if len(names) > 1:
            lines.append(row(ev.planner, "(all)", ev.summary()))
        summary = ev.summary()
        if "links_in_range" in summary:
            parts = []
            if summary.get("link_in_range") != []:   # (robots alone have no links)
                shares = (", ".join(f"{v:.1%}" for v in summary["link_in_range"]) if "link_in_range" in summary
                          else f"{summary['links_in_range']:.1%} (all links)")
                parts += [f"steps each link in range {shares}", f"episodes with every link >= 99%: "
                          f"{summary['episodes_all_links_99']}/{summary['episodes']}"]
            parts.append(f"robot-robot collisions {summary['robot_robot_collisions']}")
            if summary["min_robot_distance"] is not None:
                units = summary["units"] if summary["units"] not in (None, "mixed") else ""
                parts.append(f"closest robots {summary['min_robot_distance']:.2f}" + (f" {units}" if units else ""))
            notes.append(f"{ev.planner}: " + "; ".join(parts))
        if "worlds" in summary:
            notes.append(f"{ev.planner}: worlds where every formation arrived {summary['worlds_all_arrived']}/"
                         f"{summary['worlds']}; robot-robot collisions between formations {summary['between_collisions']}, "
                         f"within {summary['within_collisions']}; deadlocks resolved {summary['deadlocks']}")
    return "\n".join(lines + notes)


def write_json(evaluations: Sequence[Evaluation], path: str | Path) -> None:
    """A list with one ``{"planner", "episodes", "summary"}`` object per planner (one or several)."""
    write_text_atomic(path, json.dumps([ev.to_dict() for ev in evaluations], indent=1))


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename; a clear error if it cannot.

    A missing folder is created; anything at ``path`` that is not a regular file (a
    directory, a link, a device, a FIFO) is refused and left alone
    (:func:`~apf_physics.common.safefile.check_writable`).
    """
    write_text(check_writable(path, create_parent=True), text)
