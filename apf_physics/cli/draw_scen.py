"""``apf-physics draw-scen MAP.map --count N --seed S --out FILE.scen``: scenarios drawn as the MAPF benchmark's."""

from __future__ import annotations

import argparse

from apf_physics.common.safefile import check_writable, write_text
from apf_physics.experiments.movingai import draw_scenarios
from apf_physics.world.io.mapfiles import scen_text


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "draw-scen", help="draw a MovingAI scenario file as the MAPF benchmark's random ones",
        description="Draw N start-goal pairs on a MovingAI map as the MAPF benchmark's random scenarios "
                    "(distinct free starts, distinct free goals, all in the map's largest connected region, "
                    "octile optimal lengths) and write them as a .scen file; `apf-physics eval MAP.map --scen "
                    "FILE.scen --agents N` runs its first N lines as N robots at once.")
    p.add_argument("map", metavar="MAP.map", help="the MovingAI map")
    p.add_argument("--count", type=int, required=True, help="scenarios (robots) to draw")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", required=True, metavar="FILE.scen", help="the scenario file to write")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    path = check_writable(args.out, create_parent=True)
    scenarios = draw_scenarios(args.map, args.count, args.seed)
    write_text(path, scen_text(scenarios))
    print(f"wrote {len(scenarios)} scenarios to {args.out}")
    return 0
