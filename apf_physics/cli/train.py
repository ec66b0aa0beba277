"""``apf-physics train (--world W | --curriculum FILE) --out DIR [--preset P | --config FILE] [--seed S] [--set KEY=VALUE ...] [--resume]``."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

import yaml

from apf_physics.learning.curriculum import load_curriculum
from apf_physics.errors import UserError
from apf_physics.learning.config import (CURRICULUM_DEFAULT, OPTIONS, PRESETS, WORLD_DEFAULT, explain, load_config, preset,
                                         replace)
from apf_physics.learning.phases import phases_for_curriculum, phases_for_world
from apf_physics.learning.rundir import RunDir
from apf_physics.learning.trainer import CSV_COLUMNS, check_phases, load_checkpoint_config, train, world_starts_apart
from apf_physics.world.io.worldfile import load_world


def add_parser(subparsers: argparse._SubParsersAction) -> None:

    p = subparsers.add_parser(
        "train", help="train a DQN planner on a world or a curriculum; write best.pt, last.pt, train.csv",
        description="Train a planner's network, on one world or through a curriculum: the thesis's Q-network "
                    "with deep Q-learning, or (preset map) the map network by imitation of A*. "
                    "Writes OUT/config.yaml (the configuration, for --config), OUT/best.pt (the network with the "
                    "best greedy evaluation, run through the physics as "
                    "`apf-physics eval` runs it: the one to use), OUT/last.pt (the full training state, for "
                    "--resume), OUT/train.csv and OUT/train.png (the training curve), and OUT/tensorboard/ when "
                    "the tensorboard package is installed. OUT is locked while a run trains into it.")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--world", help="world file (.yaml) to train in; its starts are the evaluation starts")
    where.add_argument("--curriculum", metavar="FILE",
                       help="a curriculum file of stages (e.g. worlds/curricula/thesis.yaml): stage i trains its "
                            "worlds with every earlier stage's (rehearsal), then generated worlds; evaluated on "
                            "generated validation worlds")
    p.add_argument("--out", metavar="DIR", help="output folder (created if missing)")
    recipe = p.add_mutually_exclusive_group()
    recipe.add_argument("--config", metavar="FILE", help="a configuration file (YAML), e.g. the config.yaml of an "
                                                         "earlier run, instead of a preset")
    recipe.add_argument("--preset", default=None, choices=list(PRESETS), metavar="PRESET",
                   help=f"one of {', '.join(PRESETS)}. Default: {WORLD_DEFAULT} with --world (learns a world "
                        f"fastest), {CURRICULUM_DEFAULT} with --curriculum (the shipped general model's recipe). "
                        "thesis-fixed is Table 3 on a world, thesis-general-world Table 4 on a world, "
                        "thesis-general Table 4 through the curriculum")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="change one training option, e.g. --set total_steps=500000 --set dqn.double_dqn=false "
                        "(values in YAML syntax; an option by its name or section.name, the fields of "
                        "apf_physics.learning.TrainConfig's sections)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its last.pt (its preset and options; --set may change "
                        "how long it runs and how often it reports)")
    p.add_argument("--no-progress", action="store_true", help="show no progress (default: a bar when stderr is a "
                                                                 "terminal, else a line per log row)")
    p.add_argument("--show-config", action="store_true",
                   help="print every training option of the recipe (preset or --config, with --set) and where its "
                        "value comes from, and train nothing (no --out needed)")
    p.set_defaults(func=run)


def parse_overrides(pairs: list[str]) -> dict:
    """``["key=value", ...]`` to a dict, each value read as YAML (``1e-3``, ``true``, ``[4, 4]``, ``null``)."""

    overrides = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--set expects KEY=VALUE, got {pair!r}")
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            raise UserError(f"--set {key.strip()}: cannot read the value {value!r}") from None
        if isinstance(parsed, str):  # YAML 1.1 reads "1e-4" as a string
            try:
                parsed = float(parsed)
            except ValueError:
                pass
        overrides[key.strip()] = parsed
    return overrides


def resume_command(args: argparse.Namespace) -> str:
    """The command that continues this run."""
    where = ["--world", args.world] if args.world else ["--curriculum", args.curriculum]
    return shlex.join(["apf-physics", "train", *where, "--out", args.out, "--resume"])


def show_config(args: argparse.Namespace, overrides: dict) -> int:
    """``--show-config``: every option, its value and its source, one line each."""
    if args.config is not None:
        given = {key.rpartition(".")[2] for key in overrides}
        config = replace(load_config(args.config), **overrides)
        rows = [(f"{OPTIONS[o]}.{o}" if OPTIONS[o] else o, v, "--set" if o in given else args.config)
                for o, v in config.options().items()]
    else:
        rows = explain(args.preset or (CURRICULUM_DEFAULT if args.curriculum else WORLD_DEFAULT), overrides)
    width = max(len(name) for name, _, _ in rows)
    for name, value, source in rows:
        shown = list(value) if isinstance(value, tuple) else value
        print(f"{name:<{width}}  {shown!s:<32}  {source}")
    return 0


def run(args: argparse.Namespace) -> int:

    overrides = parse_overrides(args.set)
    if args.seed is not None:
        overrides["seed"] = args.seed
    if args.show_config:
        return show_config(args, overrides)
    if not args.world and not args.curriculum:
        raise UserError("train: give --world FILE or --curriculum FILE (or --show-config to see a recipe)")
    if not args.out:
        raise UserError("train: give --out DIR, the folder to train into")
    world = load_world(args.world) if args.world else None
    stages = None if args.world else load_curriculum(args.curriculum)
    # Everything that can be refused is checked before the output folder is made: a refused command leaves nothing.
    if args.resume:
        if not Path(args.out).is_dir():
            raise UserError(f"{Path(args.out) / 'last.pt'}: nothing to resume (no checkpoint there)")
        run_dir = RunDir(args.out, CSV_COLUMNS)  # the folder is there: locked first, so a run in it is named
        try:
            config, phases = _resumed(run_dir, args, overrides, world, stages)
        except BaseException:
            run_dir.close()
            raise
    else:
        if (Path(args.out) / "last.pt").exists():
            raise UserError(f"{Path(args.out)} already holds a training run; continue it with --resume "
                            "or train into another --out")
        if args.config is not None:
            config = replace(load_config(args.config), **overrides)
        else:
            config = preset(args.preset or (WORLD_DEFAULT if args.world else CURRICULUM_DEFAULT), **overrides)
        phases = _phases(config, world, stages)
        run_dir = RunDir(args.out, CSV_COLUMNS)  # locked from here on: a second run into --out is refused
    with run_dir as out:
        config.to_yaml(out.path / "config.yaml")
        try:
            result = train(config, phases, out_dir=out, resume=args.resume, progress=not args.no_progress)
        except KeyboardInterrupt:
            if out.last.is_file():
                print(f"interrupted: the training state is in {out.last}; continue with\n  {resume_command(args)}",
                      file=sys.stderr)
            else:
                print("interrupted before anything was trained", file=sys.stderr)
            return 130
    c = result.counters
    if result.already_finished:
        print(f"{out.path}: this run has already finished ({result.stop_reason}, after {c.global_step} steps and "
              f"{c.episodes} episodes); nothing more to train. {_train_on_hint(result, args)}")
        return 0
    if result.diverged:
        print(f"training stopped: {result.stop_reason}", file=sys.stderr)
    print(f"trained {c.global_step:,} steps, {c.episodes:,} episodes, {result.updates:,} updates in "
          f"{c.wall_time:.1f} s ({result.stop_reason})")
    best = result.best
    if best is None:
        print("never evaluated")
    else:
        print(f"best.pt (step {c.best_step:,}): {_figures(best, phases[0])}")
    if c.time_to_target is not None:
        both = config.schedule.target_world_starts is not None and world_starts_apart(config, phases[0])
        print(f"met the target of the validation starts{' and of the world starts' if both else ''} after "
              f"{c.time_to_target:.1f} s")
    names = [Path(p).name for p in result.written]
    use = " (best.pt is the network to use)" if "best.pt" in names else ""
    print(f"wrote {', '.join(names)} in {out.path}{use}")
    return 1 if result.diverged else 0


def _phases(config, world, stages) -> list:
    phases = phases_for_world(world, config) if world is not None else phases_for_curriculum(stages, config)
    check_phases(phases)
    return phases


def _resumed(out: RunDir, args: argparse.Namespace, overrides: dict, world, stages) -> tuple:
    """The configuration and phases of the run in ``out`` to resume, with ``overrides``."""
    if not out.last.is_file():
        raise UserError(f"{out.last}: nothing to resume (no checkpoint there)")
    saved = load_checkpoint_config(out.last)
    if args.preset is not None and args.preset != saved.preset:
        raise UserError(f"{out.last}: was trained with preset {saved.preset!r}, not {args.preset!r}")
    config = replace(saved, **overrides)
    return config, _phases(config, world, stages)


def _figures(best: dict, phase) -> str:
    """What an evaluation measured, named as train.csv names it: the validation starts, then the world starts."""
    n = phase.validation.starts
    text = (f"{best['success']:.1%} of the {n:,} validation starts, {best['collisions']} "
            f"collision{'' if best['collisions'] == 1 else 's'}")
    if best.get("spl") is not None:
        text += f", SPL {best['spl']:.3f}"
    if best.get("world_starts_success") is not None and phase.world_starts is not phase.validation:
        k = phase.world_starts.starts
        text += f"; {round(best['world_starts_success'] * k)}/{k} world starts"
    return text


def _train_on_hint(result, args: argparse.Namespace) -> str:
    """How to continue a run that stopped by its rules: lift the rule that stopped it."""
    reason, c = result.stop_reason or "", result.counters
    if reason.startswith("diverged"):
        return "It diverged: train anew into another --out with other settings (see the reason)."
    if reason.startswith("every phase"):
        return "Every phase of its curriculum is done; train anew to train more."
    lift = {"total_steps": f"total_steps={2 * c.global_step}", "total_episodes": f"total_episodes={2 * c.episodes}",
            "time_limit": f"time_limit={2 * max(c.wall_time, 1):.0f}", "target_success": "target_success=null"}
    name = reason.split(" ")[0]
    if name not in lift:
        return ""
    return f"To train on, resume with the limit lifted:\n  {resume_command(args)} --set {lift[name]}"
