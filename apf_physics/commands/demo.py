"""``apf-physics demo``: the shipped models at work, no training needed.

Runs the fixed 20×20 world's three-robot formation with the shipped fixed-world DQN as
leader, and the thesis's general test worlds with the shipped general DQN, beside gradient
descent; writes videos and PNGs into a folder and prints the summary table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

WORLDS = Path(__file__).resolve().parent.parent.parent / "worlds"


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("demo", help="run the shipped models: fixed-world formation and general worlds, "
                                           "with videos, PNGs and a summary table",
                              description=__doc__.splitlines()[0])
    p.add_argument("--out", default="apf-demo", help="folder for the videos and PNGs (default: apf-demo)")
    p.add_argument("--worlds", default=str(WORLDS), help="the project's worlds folder (default: %(default)s)")
    p.add_argument("--no-video", action="store_true", help="only evaluate and print the table")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apf_physics.errors import UserError
    from apf_physics.evaluate import evaluate, format_table, write_json
    from apf_physics.formation import evaluate_formation
    from apf_physics.planners import make_planner
    from apf_physics.world import load_world

    began = time.perf_counter()
    worlds_dir = Path(args.worlds)
    fixed_path = worlds_dir / "fixed20.yaml"
    general_paths = [worlds_dir / "thesis" / f"test{i}.yaml" for i in range(1, 5)]
    for path in [fixed_path, *general_paths]:
        if not path.exists():
            raise UserError(f"{path}: demo world missing (run from the project folder or pass --worlds)")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{out}: cannot create the demo folder ({exc.strerror})") from None

    fixed = load_world(fixed_path)
    general = [load_world(p) for p in general_paths]
    evaluations = [
        evaluate(make_planner("gradient"), [fixed]),
        evaluate(make_planner("dqn"), [fixed]),
        evaluate_formation(make_planner("dqn"), [fixed]),
        evaluate(make_planner("gradient"), general),
        evaluate(make_planner("dqn"), general),
        # what a hand-made escape and the grid-search oracle do on the same worlds
        evaluate(make_planner("escape"), general),
        evaluate(make_planner("astar"), general),
    ]
    table = format_table(evaluations)
    print(table)
    (out / "summary.txt").write_text(table + "\n", encoding="utf-8")
    write_json(evaluations, out / "summary.json")

    if not args.no_video:
        from apf_physics.render.episodes import write_episode_video

        # The formation from four starts where gradient descent is trapped (the interesting ones).
        trapped = [e.start for e in evaluations[0].episodes if e.outcome == "trapped"][:4]
        formation_eps = [e for e in evaluations[2].episodes if any((e.start == s).all() for s in trapped)]
        write_episode_video(fixed, formation_eps, out / "fixed20_formation.mp4", png=out / "fixed20_formation.png",
                            overlay=("world fixed20", "leader dqn (shipped)"), formation=True, progress=False)
        write_episode_video(fixed, evaluations[1].episodes, out / "fixed20_dqn.mp4", png=out / "fixed20_dqn.png",
                            overlay=("world fixed20", "planner dqn (shipped)"), progress=False)
        for world in general:
            eps = [e for e in evaluations[4].episodes if e.world == world.name]
            write_episode_video(world, eps, out / f"{world.name}_dqn.mp4", png=out / f"{world.name}_dqn.png",
                                overlay=(f"world {world.name}", "planner dqn (shipped)"), progress=False)
    print(f"wrote {out}/ (summary.txt, summary.json{'' if args.no_video else ', videos and PNGs'}) "
          f"in {time.perf_counter() - began:.1f} s")
    return 0
