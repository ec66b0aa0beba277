"""``apf-physics sweep SWEEP.yaml --out DIR [--ray ADDRESS] [--resume]``: a training sweep on Ray Tune."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from apf_physics.learning.sweep import format_results, load_sweep, run_sweep


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "sweep", help="compare training recipes on Ray Tune: grids, seeds, early stopping; the best model copied out",
        description="Train every combination of a sweep file's values and seeds as Ray Tune trials (the trainer of "
                    "`apf-physics train`, checkpointed in its own last.pt/best.pt), stop the weaker ones early "
                    "(ASHA), and write OUT/results.csv (a row per trial), OUT/best.pt (the best trial's model) and "
                    "OUT/best.json. Needs the [ray] extra. See sweeps/*.yaml for examples.")
    p.add_argument("sweep", metavar="SWEEP", help="the sweep file (.yaml), e.g. sweeps/tiny.yaml")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (Tune's experiment in DIR/tune; on a cluster, a folder every node sees)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="where Ray is. Default and alone: RAY_ADDRESS if set, else a Ray started here on this "
                        "machine's cores; 'auto': the Ray started here with `ray start --head`; HOST:PORT or "
                        "ray://HOST:10001: that cluster")
    p.add_argument("--resume", action="store_true",
                   help="continue the interrupted sweep in --out (Tune's Tuner.restore): unfinished trials go on "
                        "from their latest checkpoints")
    p.add_argument("--quiet", action="store_true", help="no Tune status tables while it runs")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    sweep = load_sweep(args.sweep)
    result = run_sweep(sweep, args.out, resume=args.resume, address=args.ray or None, verbose=0 if args.quiet else 1)
    print(format_results(result, sweep))
    if result.interrupted:
        again = ["apf-physics", "sweep", args.sweep, "--out", args.out, "--resume"]
        if args.ray:
            again += [f"--ray={args.ray}"]
        print(f"interrupted: the trials' checkpoints are in {Path(args.out) / 'tune'}; continue with\n"
              f"  {shlex.join(again)}")
        return 130
    names = ", ".join(p.name for p in result.written)
    if result.best is None:
        print(f"no trial reported a result; wrote {names} in {result.out}")
        return 1
    values = ", ".join(f"{k}={v}" for k, v in result.best.values.items())
    print(f"best trial {result.best.trial} ({values}): {sweep.metric} {result.best.metrics[sweep.metric]:.4f}; "
          f"wrote {names} in {result.out}" + (" (best.pt is the model to use)" if "best.pt" in names else ""))
    return 0
