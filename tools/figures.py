"""The README's figures: each made by a command, kept in a results file, and written into the README from it.

    python tools/figures.py run [ROW ...] [--data DIR] [--movingai DIR] [--barn DIR]   # run the commands, write tools/results/
    python tools/figures.py show ROW                                      # print a row's commands
    python tools/figures.py readme                                        # rewrite the README's table from the results
    python tools/figures.py check                                         # exit 1 if the README's table differs

Every row of the README's "What works, in figures" table is one :class:`Row`: the shell commands
that measure it (they write ``tools/results/<row>.json``) and a function that turns that file
into the row's text. The table between the README's ``figures`` markers is written by
``readme`` and nothing else, and ``tests/test_readme.py`` checks that it matches the results
files, so a figure in the README cannot go stale: to change one, re-run its row and ``readme``.

Held-out worlds are generated into ``--data`` (default ``/tmp/apf-figures``) by the row's own
``apf-physics generate`` command, with the seed no training or validation used. The MovingAI
row needs the benchmark's maps, fetched by the user (``--movingai DIR``; sources in
BENCHMARKS.md, "Real maps"), and the BARN row the challenge's repository (``--barn DIR``:
``Daffan/nav-competition-icra2022``); nothing is downloaded.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "tools" / "results"
README = ROOT / "README.md"
BEGIN = "<!-- figures: written by `python tools/figures.py readme` from tools/results/; do not edit by hand -->"
END = "<!-- /figures -->"


@dataclass(frozen=True)
class Row:
    """One row of the table: what it is, how it is measured, and how its file reads."""

    key: str
    commands: tuple[str, ...]
    """Shell commands, run from the repository's root; ``{data}``, ``{movingai}``, ``{barn}`` and ``{out}``
    (where the last command writes its full results) are filled in. The row's results file,
    ``tools/results/<row>.json``, is that file without the per-episode records."""
    what: Callable[[dict], str]
    result: Callable[[dict], str]

    @property
    def path(self) -> Path:
        return RESULTS / f"{self.key}.json"


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _n(count: int, word: str) -> str:
    """``1 collision``, ``0 collisions``."""
    return f"{count} {word}" + ("" if count == 1 else "s")


def _range(values: list[Any]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo}" if lo == hi else f"{lo}–{hi}"


def _eval(data: dict, planner: str) -> dict:
    """The summary of one planner in an ``apf-physics eval --json`` file."""
    for entry in data["evaluations"]:
        if entry["planner"] == planner:
            return entry["summary"]
    raise KeyError(f"no planner {planner!r} in the results")


def _fixed20(data: dict) -> str:
    g, d = _eval(data, "gradient"), _eval(data, "dqn")
    trapped = round(g["trapped_rate"] * g["episodes"])
    return (f"gradient descent {g['successes']}/{g['episodes']} ({trapped} trapped); shipped DQN "
            f"**{d['successes']}/{d['episodes']}**, {_n(round(d['collision_rate'] * d['episodes']), 'collision')} "
            f"(thesis: 37/40)")


def _fixed20_random(data: dict) -> str:
    g, d, u = _eval(data, "gradient"), _eval(data, "dqn"), _eval(data, "dqn-unshielded")
    return (f"gradient {g['successes']}/{g['episodes']}; shipped DQN **{d['successes']}/{d['episodes']}** "
            f"({_pct(d['success_rate'])}), {_n(round(d['collision_rate'] * d['episodes']), 'collision')}; "
            f"unshielded {u['successes']}/{u['episodes']}")


def _train(data: dict) -> str:
    runs = data["runs"]
    random = [r for run in runs for r in run["random"]]
    n = random[0]["episodes"]
    collisions = sum(round(r["collision_rate"] * r["episodes"]) for r in random)
    own = [run["starts"]["successes"] for run in runs]
    seconds = [round(run["train_seconds"]) for run in runs]
    steps = [run["steps"] for run in runs]
    seeds = [run["seed"] for run in runs]
    loads = [v for run in runs for v in run["load_average"]]
    return (f"seeds {_range(seeds)}: **{_range([r['successes'] for r in random])} of {n}** random free starts "
            f"no run saw ({len(random) // len(runs)} draws each; median {_pct(data['median_random_success'])}), "
            f"{_n(collisions, 'collision')}, {_range(own)}/{runs[0]['starts']['episodes']} of the world starts; "
            f"stopped after {min(steps) / 1000:.0f}–{max(steps) / 1000:.0f}k steps (median "
            f"{data['median_steps'] / 1000:.0f}k), {_range(seconds)} s of training each (load "
            f"{min(loads):.1f}–{max(loads):.1f})")


def _formation(data: dict) -> str:
    s = _eval(data, "dqn+formation")
    links = " and ".join(_pct(v) for v in s.get("link_in_range", [s["links_in_range"]]))
    return (f"**{s['successes']}/{s['episodes']}**, {_n(round(s['collision_rate'] * s['episodes']), 'collision')}; links "
            f"in range {links} of steps ({s['episodes_all_links_99']} of {s['episodes']} episodes ≥ 99 % on every "
            f"link) (thesis: 8/8)")


def _general_what(data: dict) -> str:
    s = data["gradient"]
    return (f"general worlds (generated, held out, {s['starts']} starts, "
            f"{round(100 * s['trap_starts'] / s['starts'])} % traps)")


def _general(data: dict) -> str:
    g, e, a = data["gradient"], data["escape"], data["astar"]
    w, m, mu = data["dqn:general"], data["dqn:map"], data["dqn-unshielded:map"]
    return (f"gradient {_pct(g['success_rate'])}, escape (wall following) {_pct(e['success_rate'])}, A* "
            f"{_pct(a['success_rate'])}; the window network `general.pt` (memory of visited cells, shielded) "
            f"**{_pct(w['success_rate'])}**, {_n(w['collisions'], 'collision')}, paths {w['length_ratio_vs_astar']:.2f}× A*; "
            f"`map.pt` {_pct(m['success_rate'])} ({_pct(mu['success_rate'])} unshielded)")


def _thesis_test(data: dict) -> str:
    g, m, w = data["gradient"], data["dqn:map"], data["dqn:general"]
    return (f"the `dqn` default (`map.pt`) **{m['successes']} of {m['starts']} starts** (the window network: "
            f"{w['successes']} of {w['starts']}; thesis: 3 of 4 worlds), gradient descent {g['successes']} of {g['starts']}")


def _structures_what(data: dict) -> str:
    s = data["gradient"]
    return (f"worlds unlike the training (held out, {s['starts']} starts, "
            f"{round(100 * s['trap_starts'] / s['starts'])} % traps, a third 100×100): rooms, mazes, nested cups, "
            f"narrow gaps, dense clutter")


def _structures(data: dict) -> str:
    g, e, w, m, mu = (data[k] for k in ("gradient", "escape", "dqn:general", "dqn:map", "dqn-unshielded:map"))
    return (f"gradient {_pct(g['success_rate'])}, escape {_pct(e['success_rate'])}, the window network "
            f"{_pct(w['success_rate'])}; the map network (`map.pt`, the `dqn` default for Table 4's field) "
            f"**{_pct(m['success_rate'])}**, {_n(m['collisions'], 'collision')}, paths {m['length_ratio_vs_astar']:.2f}× A*; "
            f"{_pct(mu['success_rate'])} with no shield")


def _moving_what(data: dict) -> str:
    return f"moving obstacles (held out, {data['astar']['starts']} starts)"


def _moving(data: dict) -> str:
    a, s, m, g = data["astar"], data["sipp"], data["dqn:moving"], data["dqn:map"]
    return (f"replanning A* {_pct(a['success_rate'])} with {_n(a['collisions'], 'collision')}; `sipp` (plans on the "
            f"known motion) {_pct(s['success_rate'])}, {_n(s['collisions'], 'collision')}; the shield over time with "
            f"the motion predicted from what a robot senses: `moving.pt` (trained with them) "
            f"**{_pct(m['success_rate'])}**, {_n(m['collisions'], 'collision')}; the default, `map.pt`, "
            f"{_pct(g['success_rate'])}, {_n(g['collisions'], 'collision')}")


def _movingai_what(data: dict) -> str:
    return (f"real maps never seen (MovingAI: {len(data['maps'])} maps of Dragon Age, rooms, mazes, random, street, "
            f"warehouse; 32 to 512 cells a side, {data['totals']['dqn']['episodes']} scenarios)")


def _movingai(data: dict) -> str:
    d, u, a = (data["totals"][k] for k in ("dqn", "dqn-unshielded", "astar"))
    return (f"the `dqn` default (`map.pt`) **{d['successes']}/{d['episodes']}**, {_n(d['collisions'], 'collision')}, "
            f"paths **{d['path_over_optimal']:.3f}×** the optimal length; the network alone {u['successes']}/"
            f"{u['episodes']}; A* {a['successes']}/{a['episodes']}, {a['path_over_optimal']:.3f}×")


def _barn_what(data: dict) -> str:
    meta = data["barn"]
    return (f"BARN in 2-D (the ICRA challenge's worlds, a Jackal-sized disc of {meta['robot_radius_m']:g} m; "
            f"its {len(meta['indices'])} development worlds, the other 200 held out for judging)")


def _barn(data: dict) -> str:
    runs = [r for r in data["runs"] if r["planner"] == "dqn"]
    astar = [r for r in data["runs"] if r["planner"] == "astar"]
    steps = list(dict.fromkeys(r["step_m"] for r in runs))
    parts = []
    for step in steps:
        mine = [r for r in runs if r["step_m"] == step]
        cells = ", ".join(f"{r['summary']['successes']}/{r['summary']['worlds']} {r['kinematics']}" for r in mine)
        ratio = max(r["summary"]["path_over_astar"] or 0 for r in mine)
        parts.append(f"{step:g} m steps: {cells}, paths ≤ {ratio:.2f}× A*")
    collisions = sum(r["summary"]["collisions"] for r in runs)
    scores = [r["summary"]["mean_score"] for r in runs]
    reached = sum(r["summary"]["successes"] for r in astar)
    score = f"{min(scores):.4f}" if min(scores) == max(scores) else f"{min(scores):.4f}–{max(scores):.4f}"
    return (f"the `dqn` default (`map.pt`) **{'; '.join(parts)}**; {_n(collisions, 'collision')}; the challenge's "
            f"score {score} (0.25 at most); A* {reached}/{sum(r['summary']['worlds'] for r in astar)}")


def _crossing_what(data: dict) -> str:
    return f"several formations crossing (held out, {_eval(data, 'dqn+formation')['worlds']} worlds)"


def _crossing(data: dict) -> str:
    s = _eval(data, "dqn+formation")
    return (f"every formation arrived in **{s['worlds_all_arrived']}/{s['worlds']}** worlds (leaders: `map.pt`, "
            f"their default), {_n(s['robot_robot_collisions'], 'robot–robot collision')}, links in range "
            f"{_pct(s['links_in_range'])} of steps")


EVAL_GENERAL = "python tools/eval_general.py"
ROWS = [
    Row("fixed20", ("apf-physics eval worlds/fixed20.yaml --planner gradient,dqn --json {out} --no-progress",),
        lambda d: "fixed 20×20 world, 40 starts", _fixed20),
    Row("train_fixed20", ("python tools/train_seeds.py worlds/fixed20.yaml --seeds 0 1 2 --out {data}/train_fixed20 "
                          "--json {out}",),
        lambda d: "training on it from scratch (`apf-physics train --world worlds/fixed20.yaml`, its defaults)",
        _train),
    Row("fixed20_random", ("apf-physics eval worlds/fixed20.yaml --planner gradient,dqn,dqn-unshielded "
                           "--random-starts 200 --seed 1 --json {out} --no-progress",),
        lambda d: "same world, 200 random free starts", _fixed20_random),
    Row("formation", ("apf-physics eval worlds/fixed20.yaml --planner dqn --formation --json {out} --no-progress",),
        lambda d: "formation (leader + 2 followers) on the 40 starts", _formation),
    Row("general", ("apf-physics generate --family point,line,two_points,concave,bent_line,clutter --count 60 "
                    "--seed 100 --starts 5 --out {data}/heldout --force",
                    f"{EVAL_GENERAL} {{data}}/heldout --planners gradient,escape,astar,dqn,dqn-unshielded "
                    "--model general=general --model map=map --json {out}"),
        _general_what, _general),
    Row("thesis_test", (f"{EVAL_GENERAL} worlds/thesis/test1.yaml worlds/thesis/test2.yaml worlds/thesis/test3.yaml "
                        "worlds/thesis/test4.yaml --planners gradient,dqn --model general=general --model map=map "
                        "--json {out}",),
        lambda d: "the thesis's four general test worlds", _thesis_test),
    Row("structures", ("apf-physics generate --family rooms,maze,nested_cups,narrow_gap,dense_clutter --count 50 "
                       "--seed 2027 --starts 4 --out {data}/h12_50 --force",
                       "apf-physics generate --family rooms,maze,nested_cups,narrow_gap,dense_clutter,mixed --count 25 "
                       "--size 100 --seed 2028 --starts 4 --out {data}/h12_100 --force",
                       f"{EVAL_GENERAL} {{data}}/h12_50 {{data}}/h12_100 --planners gradient,escape,dqn,dqn-unshielded "
                       "--model general=general --model map=map --json {out}"),
        _structures_what, _structures),
    Row("moving", ("apf-physics generate --family moving --count 60 --seed 313 --starts 5 --out {data}/mv_heldout --force",
                   f"{EVAL_GENERAL} {{data}}/mv_heldout --planners astar,sipp,dqn --model moving=moving "
                   "--model map=map --json {out}"),
        _moving_what, _moving),
    Row("movingai", ("python tools/bench_movingai.py {movingai} --planners dqn,dqn-unshielded,astar --json {out}",),
        _movingai_what, _movingai),
    Row("barn", ("python tools/barn.py --barn {barn} --worlds dev --step 0.15,0.07,0.42 --kinematics holonomic,unicycle "
                 "--planner dqn,astar --json {out}",),
        _barn_what, _barn),
    Row("crossing", ("apf-physics generate --family crossing --count 60 --seed 314 --out {data}/crossing --no-label --force",
                     "apf-physics eval {data}/crossing --planner dqn --formation --json {out} --no-progress"),
        _crossing_what, _crossing),
]
BY_KEY = {row.key: row for row in ROWS}


def compact(data: Any) -> Any:
    """``data`` without its per-episode records (lists under an ``episodes`` key): the summaries stay."""
    if isinstance(data, dict):
        return {k: compact(v) for k, v in data.items() if not (k == "episodes" and isinstance(v, list))}
    if isinstance(data, list):
        return [compact(v) for v in data]
    return data


def load(row: Row) -> dict:
    """A row's results file; ``apf-physics eval --json``'s list becomes ``{"evaluations": [...]}``."""
    data = json.loads(row.path.read_text())
    return {"evaluations": data} if isinstance(data, list) else data


def table() -> str:
    """The README's table, from the results files."""
    lines = ["| | result | made by |", "|---|---|---|"]
    for row in ROWS:
        data = load(row)
        lines.append(f"| {row.what(data)} | {row.result(data)} | `python tools/figures.py run {row.key}` |")
    return "\n".join(lines)


def readme_block(text: str) -> str:
    """The table as the README holds it (between the markers)."""
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{README}: no figures block (the lines {BEGIN!r} and {END!r})")
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n")


def full_results(row: Row, data: str) -> Path:
    """Where the row's commands write their full results (per-episode records included)."""
    return Path(data) / "results" / f"{row.key}.json"


def commands(row: Row, data: str, movingai: str, barn: str = "barn") -> list[str]:
    out = shlex.quote(str(full_results(row, data)))
    return [c.format(data=shlex.quote(data), movingai=shlex.quote(movingai), barn=shlex.quote(barn), out=out)
            for c in row.commands]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=("run", "show", "readme", "check"))
    parser.add_argument("rows", nargs="*", metavar="ROW", help=f"rows (default: all): {', '.join(BY_KEY)}")
    parser.add_argument("--data", default="/tmp/apf-figures", help="where held-out worlds and runs are made")
    parser.add_argument("--movingai", default="maps/movingai", help="the MovingAI maps and scenarios, fetched by you")
    parser.add_argument("--barn", default="barn", help="BARN (nav-competition-icra2022's root), fetched by you")
    args = parser.parse_args(argv)
    unknown = [k for k in args.rows if k not in BY_KEY]
    if unknown:
        parser.error(f"unknown row {unknown[0]!r}; choose from {', '.join(BY_KEY)}")
    rows = [BY_KEY[k] for k in args.rows] or ROWS
    if args.action in ("run", "show"):
        for row in rows:
            if args.action == "run":
                full_results(row, args.data).parent.mkdir(parents=True, exist_ok=True)
            for command in commands(row, args.data, args.movingai, args.barn):
                print(f"$ {command}", flush=True)
                if args.action == "run":
                    subprocess.run(command, shell=True, check=True, cwd=ROOT)
            if args.action == "run":
                data = compact(json.loads(full_results(row, args.data).read_text()))
                RESULTS.mkdir(parents=True, exist_ok=True)
                row.path.write_text(json.dumps(data, indent=1) + "\n")
                print(f"wrote {row.path.relative_to(ROOT)} (from {full_results(row, args.data)})", flush=True)
        return 0
    text = README.read_text()
    if args.action == "check":
        same = readme_block(text) == table()
        print("the README's figures match tools/results/" if same else
              "the README's figures differ from tools/results/: run `python tools/figures.py readme`")
        return 0 if same else 1
    before, rest = text.split(BEGIN, 1)
    README.write_text(f"{before}{BEGIN}\n{table()}\n{END}{rest.split(END, 1)[1]}")
    print(f"wrote the figures into {README}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
