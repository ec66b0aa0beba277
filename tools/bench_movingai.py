"""The learned planner on MovingAI benchmark maps: success, collisions and path length against the optimal one.

    python tools/bench_movingai.py DIR [--limit 10] [--planners dqn,dqn-unshielded,astar] [--json OUT]

DIR holds the maps and their scenario files, fetched by the user (nothing is downloaded):
``NAME.map`` with ``NAME.map.scen`` (the single-agent benchmark) or ``NAME-random-1.scen`` (the
MAPF benchmark's, same line format). Each map runs ``--limit`` scenarios taken evenly through
its file (every length represented), exactly as ``apf-physics eval NAME.map --scen FILE --limit N``.
Prints one row per map and planner, then the totals; the maps and their sources are named in
BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from apf_physics.experiments.movingai import bucket_summary, evaluate_trials, scenario_trials, trials_json
from apf_physics.experiments.evaluate import figures
from apf_physics.planners import make_planner
from apf_physics.common.safefile import write_text

MAPS = [  # (family, name): the table's maps, 32 to 512 cells a side
    ("dao", "arena"), ("dao", "den312d"), ("dao", "lak303d"),
    ("rooms", "room-64-64-8"), ("rooms", "8room_000"),
    ("maze", "maze-32-32-2"), ("maze", "maze-128-128-1"), ("maze", "maze-128-128-10"),
    ("random", "random-32-32-20"), ("random", "random-64-64-20"), ("random", "random512-20-0"),
    ("street", "Berlin_0_256"), ("street", "Boston_0_256"),
    ("warehouse", "warehouse-10-20-10-2-1"),
]


def find(folder: Path, name: str) -> tuple[Path, Path] | None:
    """The map and its scenario file under ``folder`` (searched recursively), or None."""
    for scen_name in (f"{name}.map.scen", f"{name}-random-1.scen"):
        for scen in folder.rglob(scen_name):
            if (scen.parent / f"{name}.map").exists():
                return scen.parent / f"{name}.map", scen
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--limit", type=int, default=10, help="scenarios per map (default 10)")
    parser.add_argument("--planners", default="dqn,dqn-unshielded,astar")
    parser.add_argument("--maps", help="names, separated by commas (default: the table's 14)")
    parser.add_argument("--json", type=Path, help="write every episode and summary here, and the totals per planner")
    args = parser.parse_args()
    chosen = [(f, n) for f, n in MAPS if args.maps is None or n in args.maps.split(",")]
    names = [p.strip() for p in args.planners.split(",")]
    totals = {p: [] for p in names}
    out = []
    header = f"{'family':<10} {'map':<24} {'size':>9} {'planner':<15} {'success':>9} {'collide':>8} {'path/opt':>9} {'s':>6}"
    rows = [header, "-" * len(header)]
    for family, name in chosen:
        found = find(args.folder, name)
        if found is None:
            print(f"skipped {name}: not in {args.folder}", flush=True)
            continue
        trials = scenario_trials(found[0], found[1], limit=args.limit)
        size = f"{trials[0].world.size[0]:.0f}x{trials[0].world.size[1]:.0f}"
        evaluations = []
        for planner in names:
            t = time.perf_counter()
            ev = evaluate_trials(make_planner(planner), trials)
            seconds = time.perf_counter() - t
            evaluations.append(ev)
            every = bucket_summary(ev, trials)[-1]
            n = every["episodes"]
            ratio = "-" if every["path_over_optimal"] is None else f"{every['path_over_optimal']:.3f}"
            rows.append(f"{family:<10} {name:<24} {size:>9} {planner:<15} {every['successes']:>4}/{n:<4} "
                        f"{every['collisions']:>8} {ratio:>9} {seconds:>6.0f}")
            print(rows[-1], flush=True)
            totals[planner] += [(e, t.optimal) for e, t in zip(ev.episodes, trials)]
        out.append({"family": family, "map": name, "results": trials_json(evaluations, trials)})
    rows.append("-" * len(header))
    summary = {}
    for planner, entries in totals.items():
        if not entries:
            continue
        scored = figures([e for e, _ in entries], optimal=[opt for _, opt in entries])
        ratio = float("nan") if scored.path_over_optimal is None else scored.path_over_optimal
        rows.append(f"{'all':<10} {'':<24} {'':>9} {planner:<15} {scored.successes:>4}/{scored.episodes:<4} "
                    f"{scored.collisions:>8} {ratio:>9.3f}")
        summary[planner] = {"episodes": scored.episodes, "successes": scored.successes, "collisions": scored.collisions,
                            "path_over_optimal": None if scored.path_over_optimal is None
                            else round(scored.path_over_optimal, 4)}
    print("\n".join(rows))
    if args.json:
        write_text(args.json, json.dumps({"maps": out, "totals": summary}, indent=1))


if __name__ == "__main__":
    main()
