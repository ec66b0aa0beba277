"""Train a world from scratch with several seeds, as a user would, and judge each model on starts it never saw.

    python tools/train_seeds.py worlds/fixed20.yaml --seeds 0 1 2 --out runs/seeds \\
        [--set KEY=VALUE ...] [--random 200 --draws 1 2] [--json tools/results/train_fixed20.json]

For each seed this runs ``apf-physics train --world WORLD --seed S --out OUT/seedS`` (the default
preset unless ``--set`` changes it; its output kept in ``OUT/seedS/train.out``) and then
``apf-physics eval`` of its ``best.pt``: on the world's own starts (the world starts), and on
``--random`` random free starts drawn with each ``--seed`` of ``--draws`` (fresh draws: training
validates on its own generator's starts, never these). Prints one row per seed and the medians,
with the load average before and after each training; ``--json`` keeps them (the README's
figures are made from that file: ``tools/figures.py``).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apf_physics.common.safefile import write_text  # noqa: E402
from apf_physics.models.files import read_file  # noqa: E402


def run(command: list[str]) -> None:
    print("$ " + shlex.join(command), flush=True)
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)


def summary(path: Path) -> dict:
    return json.loads(path.read_text())[0]["summary"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("world")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=Path("runs/seeds"))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="passed to apf-physics train")
    parser.add_argument("--random", type=int, default=200, help="random free starts per draw (default 200)")
    parser.add_argument("--draws", type=int, nargs="+", default=[1, 2], help="--seed of each draw (default 1 2)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)

    rows = []
    for seed in args.seeds:
        out = args.out / f"seed{seed}"
        command = ["apf-physics", "train", "--world", args.world, "--seed", str(seed), "--out", str(out), "--no-progress"]
        command += [a for s in args.set for a in ("--set", s)]
        t, load = time.perf_counter(), os.getloadavg()[0]
        if not (out / "best.pt").exists():
            print("$ " + shlex.join(command), flush=True)
            out.mkdir(parents=True, exist_ok=True)
            done = subprocess.run(command, check=True, stdout=subprocess.PIPE, text=True)
            write_text(out / "train.out", done.stdout)
        seconds = time.perf_counter() - t
        loads = [round(load, 1), round(os.getloadavg()[0], 1)]
        with open(out / "train.csv", newline="") as f:
            log = list(csv.DictReader(f))
        first = next((r for r in log if r["world_starts_success"] not in ("", None)
                      and float(r["world_starts_success"]) >= 1.0), None)
        stopped = next((line for line in (out / "train.out").read_text().splitlines() if line.startswith("trained ")), "")
        training = read_file(out / "best.pt")[0]["training"]
        model = str(out / "best.pt")
        own = out / "eval_starts.json"
        run(["apf-physics", "eval", args.world, "--planner", "dqn", "--model", model, "--json", str(own), "--no-progress"])
        row = {"seed": seed, "seconds": round(seconds, 1), "train_seconds": round(float(log[-1]["wall_time"]), 1),
               "steps": int(log[-1]["global_step"]), "load_average": loads,
               "stopped": stopped[stopped.find("(") + 1:stopped.rfind(")")] if "(" in stopped else None,
               "best_step": training["evaluation_step"], "validation_success": training["evaluation"]["success"],
               "first_all_world_starts_seconds": None if first is None else round(float(first["wall_time"]), 1),
               "starts": summary(own), "random": []}
        for draw in args.draws:
            path = out / f"eval_random_{draw}.json"
            run(["apf-physics", "eval", args.world, "--planner", "dqn", "--model", model, "--random-starts",
                 str(args.random), "--seed", str(draw), "--json", str(path), "--no-progress"])
            row["random"].append({"seed": draw, **summary(path)})
        rows.append(row)
        randoms = ", ".join(f"{r['successes']}/{r['episodes']} ({r['collision_rate']:.0%} coll.)" for r in row["random"])
        print(f"seed {seed}: {row['starts']['successes']}/{row['starts']['episodes']} of the world starts, "
              f"random {randoms}; trained {row['train_seconds']:.0f} s ({row['steps']:,} steps, {row['stopped']}; "
              f"load {loads[0]} -> {loads[1]})", flush=True)
    shares = [r["successes"] / r["episodes"] for row in rows for r in row["random"]]
    result = {"world": args.world, "train": shlex.join(["apf-physics", "train", "--world", args.world]
                                                       + [a for s in args.set for a in ("--set", s)]),
              "runs": rows, "median_random_success": statistics.median(shares),
              "median_train_seconds": statistics.median(r["train_seconds"] for r in rows),
              "median_steps": statistics.median(r["steps"] for r in rows)}
    print(f"median: {result['median_random_success']:.1%} of random free starts; "
          f"{result['median_train_seconds']:.0f} s of training")
    if args.json:
        write_text(args.json, json.dumps(result, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
