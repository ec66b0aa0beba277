"""``apf-physics eval WORLD... --planner P [--model M] [--json OUT]``, ``eval MAP.map --scen MAP.map.scen``,
and fleets: ``eval MAP.map --scen FILE.scen --agents N`` (or a world file with ``robots:``), ``--lifelong STEPS``."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TextIO

from tqdm import tqdm

import numpy as np

from apf_physics.experiments.fleet import format_fleet_table, rollout_fleet
from apf_physics.experiments.movingai import (evaluate_trials, format_bucket_table, parse_buckets, scenario_fleet,
                                              scenario_trials, trials_json)
from apf_physics.experiments.campaign import evaluate_on_ray
from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import Episode, evaluate, format_table, write_json, write_text_atomic
from apf_physics.planners import make_planner
from apf_physics.common.safefile import check_writable
from apf_physics.render.fleet import write_fleet_video
from apf_physics.render.page import PAGE, VIDEO_FPS, Section, Video, file_stem, fleet_table, write_page, write_results
from apf_physics.world.kinematics import KINEMATICS
from apf_physics.experiments.rollout import kinematics_option
from apf_physics.world.io.units import show_length
from apf_physics.world.io.worldfile import MAX_STARTS, load_worlds


class EvalProgress:
    """What a long evaluation shows while it runs: a bar on a terminal, else plain lines.

    On a terminal, a tqdm bar over the episodes on stderr, with the success so far. Anywhere
    else (``nohup``, CI, a notebook cell, a pipe) there is no bar and no carriage return: one
    plain line after a tenth of the worlds or ``every`` seconds, whichever comes first, and one
    at the end, as the training's progress does; an evaluation done within ``quiet`` seconds
    prints none.
    """

    def __init__(self, planner: str, worlds: int, episodes: int, enabled: bool = True,
                 stream: TextIO | None = None, every: float = 30.0, quiet: float = 5.0):
        self.stream = sys.stderr if stream is None else stream
        self.planner, self.worlds, self.total, self.every = planner, worlds, episodes, every
        self.enabled, self.quiet = enabled, quiet
        self.done_worlds = self.done = self.successes = 0
        self.start = self.last = time.perf_counter()
        self.bar = (tqdm(total=episodes, desc=planner, unit="episode", file=self.stream, leave=False,
                         dynamic_ncols=True) if enabled and self.stream.isatty() else None)

    def __call__(self, world: object, episodes: list[Episode]) -> None:
        self.done_worlds += 1
        self.done += len(episodes)
        self.successes += sum(e.success for e in episodes)
        share = f"{self.successes / self.done:.1%}" if self.done else "-"
        if self.bar is not None:
            self.bar.set_postfix_str(f"success {share}", refresh=False)
            self.bar.update(len(episodes))
            return
        now = time.perf_counter()
        tenth = max(1, self.worlds // 10)
        if self.enabled and now - self.start >= self.quiet and (self.done_worlds % tenth == 0 or now - self.last >= self.every
                             or self.done_worlds == self.worlds):
            self.last = now
            print(f"eval: {self.planner}: world {self.done_worlds:,}/{self.worlds:,}, episodes {self.done:,}/"
                  f"{self.total:,}, success {share}, {now - self.start:.0f} s", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("eval", help="run planners from every start of every world; print a table, write JSON",
                              description="Run planners from every start of every world (or from random free starts), "
                                          "print a table and optionally write JSON.")
    p.add_argument("worlds", nargs="+", metavar="WORLD", help="world files (.yaml) or directories of them")
    p.add_argument("--planner", default="gradient",
                   help="planner, or several separated by commas: gradient, dqn (the default learned planner: the "
                        "best shipped network for the field), mapnet (the map network), window-dqn (the thesis's "
                        "window DQN), each also -unshielded, dqn-known, astar, sipp, escape (default: gradient)")
    p.add_argument("--model", help="DQN model file, or a shipped model by name (general, moving, map, fixed20; "
                                   "default: the shipped model for the world's field)")
    p.add_argument("--formation", action="store_true", help="run the world's formation (leader and followers)")
    p.add_argument("--kinematics", default=None, metavar="KIND",
                   help=f"robot kind: {' or '.join(KINEMATICS)} (default: each world file's robot.kinematics); "
                        "unicycles drive the planners' moves (turning on the spot where an arc is not as clear "
                        "as the straight move)")
    p.add_argument("--random-starts", type=int, metavar="N",
                   help="instead of the world's starts, N random free starts per world")
    p.add_argument("--seed", type=int, default=0, help="seed for --random-starts (default 0)")
    p.add_argument("--max-steps", type=int, help="step limit per episode (default: 4 x (width + height))")
    p.add_argument("--scen", metavar="FILE.scen",
                   help="MovingAI scenarios: WORLD is the .map, each line of FILE is a start and a goal; the table "
                        "gives success, collisions, trapped, timeouts and path length against the optimal length "
                        "(both in steps) per bucket")
    p.add_argument("--buckets", metavar="A-B", help="with --scen: only the buckets A to B")
    p.add_argument("--limit", type=int, metavar="N", help="with --scen: at most N scenarios, taken evenly through the "
                                                          "file (all lengths represented); needed beyond 100,000")
    p.add_argument("--agents", type=int, metavar="N",
                   help="with --scen: run the first N lines of FILE as N robots at once, a fleet on one map (the "
                        "MAPF convention); a world file with 'robots:' runs its robots so without this option")
    p.add_argument("--lifelong", type=int, metavar="STEPS",
                   help="fleets: run STEPS steps, a robot given its next goal (from a stream seeded by --seed) as "
                        "soon as it arrives; the table gives the throughput in goals per step")
    p.add_argument("--cell", type=float, default=1.0,
                   help="with --scen: world units (robot steps) per map cell (default 1)")
    p.add_argument("--json", metavar="OUT", help="write the episodes and summary as JSON")
    p.add_argument("--no-progress", action="store_true",
                   help="show no progress (default: a bar when stderr is a terminal, else a plain line per tenth "
                        "of the worlds or per 30 s)")
    p.add_argument("--html", metavar="DIR",
                   help="write a results page DIR/index.html: the table, a field figure and a video per planner "
                        "and world (viewable offline; DIR is created)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="run the worlds x planners as Ray tasks (needs the [ray] extra); same table and JSON. "
                        "Alone: RAY_ADDRESS if set, else a Ray started here on this machine's cores; "
                        "'auto': the Ray started here with `ray start --head`; HOST:PORT or ray://HOST:10001: "
                        "that cluster. Put it after the worlds, or write --ray=ADDRESS")
    p.add_argument("--ray-batch", type=int, metavar="N",
                   help="with --ray: worlds per Ray task (default: about 4 tasks per CPU of the cluster, "
                        "each of at least 50 episodes)")
    p.set_defaults(func=run)


def random_starts(world, count: int, seed: int) -> np.ndarray:
    """``count`` free starts, away from the targets, from a seeded generator."""
    rng = np.random.default_rng(seed)
    out = np.empty((0, 2))
    while len(out) < count:
        cand = world.random_free_positions(rng, count)
        out = np.vstack([out, cand[~world.reached(cand)]])
    return out[:count]


def _check_options(args: argparse.Namespace) -> None:
    """Every option that can be judged before any work: one message each, naming the option."""
    if args.json:
        check_writable(args.json, create_parent=True)
    if args.html:
        check_writable(Path(args.html) / PAGE, create_parent=True)
    if args.ray is not None and args.ray and Path(args.ray).exists():
        raise UserError(f"--ray: {args.ray!r} is a file, not a Ray address; put --ray after the worlds, "
                        "or write --ray=ADDRESS")
    if args.ray_batch is not None and args.ray is None:
        raise UserError("--ray-batch: only with --ray")
    if args.ray_batch is not None and args.ray_batch < 1:
        raise UserError(f"--ray-batch: must be at least 1, got {args.ray_batch}")
    if args.random_starts is not None and not 1 <= args.random_starts <= MAX_STARTS:
        raise UserError(f"--random-starts: must be from 1 to {MAX_STARTS:,} (as a world file's starts), "
                        f"got {args.random_starts}")
    kinematics_option(args.kinematics)   # a clear error for an unknown kind, before any work
    if args.kinematics is not None and args.scen is not None:
        raise UserError("--kinematics: not with --scen (MovingAI scenarios run holonomic robots)")
    if args.lifelong is not None and args.lifelong < 1:
        raise UserError(f"--lifelong: must be at least 1 step, got {args.lifelong}")


def _starts(args: argparse.Namespace, worlds: list) -> dict | None:
    """``--random-starts``' starts by world name, or None for the worlds' own (each must have some)."""
    if args.random_starts is None:
        empty = [w.label for w in worlds if not len(w.starts)]
        if empty:
            raise UserError(f"{', '.join(empty)}: no starts to run from (add 'starts: [[x, y], ...]' to the "
                            f"world file, or use --random-starts N)")
        return None
    for world in worlds:
        if not len(world.start_cells()):
            raise UserError(f"{world.label}: no free position for a robot farther than goal_tolerance "
                            f"{show_length(world.frame, world.goal_tolerance)} from every target, so no random start")
    return {w.name: random_starts(w, args.random_starts, args.seed) for w in worlds}


def _evaluate_here(args: argparse.Namespace, names: list[str], worlds: list, starts: dict | None) -> tuple[list, list]:
    """Each planner over the worlds in this process, with a progress bar: evaluations, and which network
    each learned planner ran."""
    evaluations, notes = [], []
    for name in names:
        planner = make_planner(name, model=args.model)
        count = sum(len(w.formations) if args.formation and w.formations
                    else len(w.starts if starts is None else starts[w.name]) for w in worlds)
        progress = EvalProgress(planner.name, len(worlds), count, enabled=not args.no_progress)
        try:
            evaluations.append(evaluate(planner, worlds, starts, max_steps=args.max_steps,
                                        formation=args.formation, progress=progress, kinematics=args.kinematics))
        finally:
            progress.close()
        if hasattr(planner, "describe"):   # a learned planner: say which network ran
            notes.append(planner.describe())
    return evaluations, notes


def _evaluate_on_ray(args: argparse.Namespace, names: list[str], worlds: list, starts: dict | None) -> tuple[list, list]:
    """:func:`_evaluate_here` as tasks on Ray."""
    evaluations = evaluate_on_ray(names, worlds, starts, model=args.model, max_steps=args.max_steps,
                                  formation=args.formation, address=args.ray or None,
                                  worlds_per_task=args.ray_batch, kinematics=args.kinematics)
    notes = []
    for name in names:   # which network each learned planner ran (on the last world, as a local run says)
        planner = make_planner(name, model=args.model)
        if hasattr(planner, "describe"):
            planner.reset(worlds[-1], np.zeros((1, 2)))
            notes.append(planner.describe())
    return evaluations, notes


def run(args: argparse.Namespace) -> int:
    _check_options(args)
    if args.scen is not None and args.agents is not None:
        return run_fleets(args, None)
    if args.scen is not None:
        if args.lifelong is not None:
            raise UserError("--lifelong: only for fleets (with --agents, or a world file with 'robots:')")
        return run_scenarios(args)
    for flag in ("buckets", "limit", "agents"):
        if getattr(args, flag) is not None:
            raise UserError(f"--{flag}: only with --scen")
    worlds = load_worlds(args.worlds)
    fleets = [w for w in worlds if w.robots is not None]
    if fleets:
        if len(fleets) < len(worlds):
            raise UserError(f"{fleets[0].label}: a world with 'robots:' (a fleet) is evaluated on its own, not with "
                            f"worlds of starts ({next(w.label for w in worlds if w.robots is None)})")
        return run_fleets(args, fleets)
    if args.lifelong is not None:
        raise UserError("--lifelong: only for fleets (with --scen and --agents, or a world file with 'robots:')")
    starts = _starts(args, worlds)
    names = [n.strip() for n in args.planner.split(",") if n.strip()]
    evaluations, notes = (_evaluate_on_ray if args.ray is not None else _evaluate_here)(args, names, worlds, starts)
    print(format_table(evaluations))
    for note in notes:
        print(note)
    if args.json:
        write_json(evaluations, args.json)
        print(f"wrote {args.json}")
    if args.html:
        page = write_results(args.html, evaluations, worlds, title=f"apf-physics eval: {', '.join(names)}",
                             progress=not args.no_progress)
        print(f"wrote {page} (open it in a browser)")
    return 0


def run_scenarios(args: argparse.Namespace) -> int:
    """``eval MAP.map --scen MAP.map.scen``: every scenario a start-goal pair; a table per bucket."""
    if len(args.worlds) != 1:
        raise UserError(f"--scen: give one MovingAI .map as WORLD, got {len(args.worlds)}")
    for flag in ("ray", "html", "random_starts"):
        if getattr(args, flag) not in (None, False):
            raise UserError(f"--{flag.replace('_', '-')}: not with --scen")
    if args.limit is not None and args.limit < 1:
        raise UserError(f"--limit: must be at least 1, got {args.limit}")
    if not args.cell > 0:
        raise UserError(f"--cell: must be positive, got {args.cell:g}")
    if args.json:
        check_writable(args.json, create_parent=True)
    trials = scenario_trials(args.worlds[0], args.scen, parse_buckets(args.buckets), args.limit, cell=args.cell,
                             warn=lambda message: print(f"apf-physics: warning: {message}", file=sys.stderr))
    names = [n.strip() for n in args.planner.split(",") if n.strip()]
    evaluations = []
    for name in names:
        planner = make_planner(name, model=args.model)
        progress = EvalProgress(planner.name, len(trials), len(trials), enabled=not args.no_progress)
        try:
            evaluations.append(evaluate_trials(planner, trials, progress=progress))
        finally:
            progress.close()
    print(f"{args.worlds[0]}: {len(trials)} scenarios")
    print(format_bucket_table(evaluations, trials))
    if args.json:
        write_text_atomic(args.json, json.dumps(trials_json(evaluations, trials), indent=1))
        print(f"wrote {args.json}")
    return 0


def run_fleets(args: argparse.Namespace, worlds: list | None) -> int:
    """Fleets: the first ``--agents`` lines of ``--scen`` on its map, or each world's ``robots:``, every
    robot at once; a table per planner and world, JSON per robot and a summary per run."""
    for flag in ("ray", "random_starts", "formation", "buckets", "limit", "kinematics"):
        if getattr(args, flag) not in (None, False):
            raise UserError(f"--{flag.replace('_', '-')}: not with fleets")
    if args.html:
        check_writable(Path(args.html) / PAGE, create_parent=True)
    if worlds is None:
        if len(args.worlds) != 1:
            raise UserError(f"--scen: give one MovingAI .map as WORLD, got {len(args.worlds)}")
        if args.agents < 1:
            raise UserError(f"--agents: must be at least 1, got {args.agents}")
        if not args.cell > 0:
            raise UserError(f"--cell: must be positive, got {args.cell:g}")
        world, fleet = scenario_fleet(args.worlds[0], args.scen, args.agents, cell=args.cell)
        tasks = [(world, fleet)]
    else:
        tasks = [(w, w.robots) for w in worlds]
    names = [n.strip() for n in args.planner.split(",") if n.strip()]
    runs = []
    for name in names:
        for world, fleet in tasks:
            planner = make_planner(name, model=args.model)
            progress = FleetProgress(planner.name, world.name, len(fleet), enabled=not args.no_progress)
            runs.append(rollout_fleet(world, planner, fleet, max_steps=args.max_steps, lifelong=args.lifelong,
                                      seed=args.seed, progress=progress))
            progress.close()
    print(format_fleet_table(runs))
    if args.json:
        write_text_atomic(args.json, json.dumps([run.to_dict() for run in runs], indent=1))
        print(f"wrote {args.json}")
    if args.html:
        print(f"wrote {fleet_page(args.html, runs, names)} (open it in a browser)")
    return 0


def fleet_page(folder: str, runs: list, names: list[str]) -> Path:
    """The results page of fleets: the table, and a video of each run (:mod:`apf_physics.render.fleet`)."""
    folder = Path(folder)
    sections = []
    for run in runs:
        stem = file_stem(run.world.name, run.planner, "fleet")
        video, poster = folder / f"{stem}.mp4", folder / f"{stem}_last.png"
        positions, goals = run.drawn()
        s = run.summary()
        tally = (f"{s['goals_reached']} goals in {run.steps} steps" if run.lifelong is not None
                 else f"{s['arrived']}/{s['robots']} on their goal after {run.steps} steps")
        frames = write_fleet_video(run.world, positions, goals, video, fps=VIDEO_FPS, size=1536, png=poster,
                                   caption=lambda step, run=run: [f"{run.world.name}  {run.planner}  step {step}/{run.steps}"])
        sections.append(Section(f"{run.world.name}: {run.planner}",
                                videos=[Video(video, f"{len(run.fleet)} robots, {tally}", frames / VIDEO_FPS, poster,
                                              wide=True)]))
    rows = [{"planner": run.planner, "world": run.world.name, **run.summary()} for run in runs]
    return write_page(folder, f"apf-physics eval: fleets, {', '.join(names)}", [], sections, tables=[fleet_table(rows)])


class FleetProgress:
    """A fleet's progress on stderr: on a terminal, a bar of robots on their goal; elsewhere a plain
    line every 30 s (none for a run done within 5 s)."""

    def __init__(self, planner: str, world: str, robots: int, enabled: bool = True, every: float = 30.0):
        self.stream = sys.stderr
        self.label, self.enabled, self.every = f"{planner} on {world}", enabled, every
        self.start = self.last = time.perf_counter()
        self.bar = (tqdm(total=robots, desc=self.label, unit="robot", file=self.stream, leave=False,
                         dynamic_ncols=True) if enabled and self.stream.isatty() else None)

    def __call__(self, step: int, home: int) -> None:
        if self.bar is not None:
            self.bar.n = home
            self.bar.set_postfix_str(f"step {step}", refresh=False)
            self.bar.refresh()
            return
        now = time.perf_counter()
        if self.enabled and now - self.last >= self.every:
            self.last = now
            print(f"eval: {self.label}: step {step:,}, {home} robots on their goal, {now - self.start:.0f} s",
                  file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
