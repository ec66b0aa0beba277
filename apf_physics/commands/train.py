"""``apf-physics train (--world W | --curriculum FILE) --out DIR [--preset P] [--seed S] [--set KEY=VALUE ...] [--resume]``."""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train", help="train a DQN planner on a world; write best.pt, last.pt, train.csv, train.png",
        description="Train the thesis's Q-network with deep Q-learning on one world. Writes OUT/best.pt (the "
                    "network with the best greedy evaluation on the world's starts: the one to use), OUT/last.pt "
                    "(the full training state, for --resume), OUT/train.csv and OUT/train.png (the training curve).")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--world", help="world file (.yaml) to train in; its starts are the evaluation starts")
    where.add_argument("--curriculum", metavar="FILE",
                       help="general training: a curriculum file of stages (e.g. worlds/curricula/thesis.yaml); "
                            "stage i trains its worlds with every earlier stage's (rehearsal), then generated "
                            "worlds; presets general-revisit (default: the shipped general model), general-memory, "
                            "general or thesis-general")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--preset", default=None,
                   help="with --world: fast (default: learns fastest), thesis-fixed (Table 3 as written) or "
                        "thesis-general (Table 4); with --curriculum: general-revisit (default), general-memory, "
                        "general or thesis-general")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="change one training option, e.g. --set total_steps=500000 --set double_dqn=false "
                        "(values in YAML syntax; see apf_physics.rl.DQNConfig for the options)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its last.pt (same preset and options)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def parse_overrides(pairs: list[str]) -> dict:
    """``["key=value", ...]`` to a dict, each value read as YAML (``1e-3``, ``true``, ``[4, 4]``, ``null``)."""
    from apf_physics.errors import UserError

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


def run(args: argparse.Namespace) -> int:
    from apf_physics.errors import UserError
    from apf_physics.rl.dqn import load_checkpoint_config, preset, train
    from apf_physics.worldfile import load_world

    overrides = parse_overrides(args.set)
    if args.curriculum:
        from apf_physics.rl.general import run_curriculum_command

        return run_curriculum_command(args.curriculum, args.preset, args.out, seed=args.seed, resume=args.resume,
                                      overrides=overrides, progress=not args.no_progress)
    world = load_world(args.world)
    if args.seed is not None:
        overrides["seed"] = args.seed
    out = Path(args.out)
    if args.resume:
        last = out / "last.pt"
        if not last.is_file():
            raise UserError(f"{last}: nothing to resume (no checkpoint there)")
        saved = load_checkpoint_config(last)
        if args.preset is not None and args.preset != saved.preset:
            raise UserError(f"{last}: was trained with preset {saved.preset!r}, not {args.preset!r}")
        config = preset(saved.preset, **{**saved.to_dict(), **overrides})
    else:
        if (out / "last.pt").exists():
            raise UserError(f"{out} already holds a training run; use --resume to continue it or another --out")
        config = preset(args.preset or "fast", **overrides)
    result = train(config, world, out_dir=out, resume=args.resume, progress=not args.no_progress)
    best = "never evaluated" if result.best_eval_success is None else f"{result.best_eval_success:.1%} of the starts"
    print(f"trained {result.global_step} steps, {result.episodes} episodes, {result.updates} updates "
          f"in {result.wall_time:.1f} s; best greedy evaluation: {best}")
    if result.time_to_target is not None:
        print(f"reached the target success rate after {result.time_to_target:.1f} s")
    print(f"wrote {result.best_path} (use this), {result.last_path}, {out / 'train.csv'}, {out / 'train.png'}")
    return 0
