"""The hostile inputs' worst cases, timed: every one a clean exit within seconds and the memory budget.

    python tools/bench_hostile.py [--timeout 60] [--memory 4000000] [--baseline OTHER_CHECKOUT]

Generates, in a temporary folder, the largest of the inputs a probe of the command line tried
(the world file of each is a grid world ``grid: {map: m.yaml}`` with ``robot: {radius: 0.2,
step: 0.25}``, a target and a start, run with ``apf-physics eval WORLD --planner gradient
--max-steps 30``):

- a plain PGM 1000 × 1000 with one value of 10,000 characters; a plain PGM 4000 × 4000 of
  13-character values (224 MB; a robot step of 1 m keeps its rasters within the budget);
- a 4000 × 4000 map at 2.5 mm, half its pixels occupied at random, as a ROS map and as a MovingAI
  map at ``--cell 0.1``; the same at 1 % density with five scenarios clear of the noise;
- a resolution and a ``--cell`` of 1e300; a ``.scen`` of 2.6 million lines (62 MB), without
  ``--limit`` and with ``--limit 1``; a unicycle with ``max_speed: 1e9``.

Each runs in a process of its own under ``ulimit -v`` (``--memory`` KiB, as the probe's
4,000,000) and a timeout, and prints its exit status, wall-clock and CPU seconds, peak resident
memory and the first line it wrote to stderr. With ``--baseline DIR`` every case runs again on
the package in ``DIR`` (``PYTHONPATH``), side by side.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

WORLD = ("grid: {{map: {map}}}\nrobot: {{radius: 0.2, step: {step}{extra}}}\nfield: thesis-general\n"
         "targets: [[{target}]]\nstarts: [[{start}]]\n")
RUN = ("import resource, sys\nfrom apf_physics.cli import main\ntry:\n    status = main(sys.argv[1:])\n"
       "finally:\n    print(f'@@ {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}', file=sys.stderr)\n"
       "sys.exit(status)\n")


def world(folder: Path, name: str, map_file: str, step: float = 0.25, extra: str = "", target: str = "1.5, 1.5",
          start: str = "0.6, 0.6") -> Path:
    path = folder / f"{name}.yaml"
    path.write_text(WORLD.format(map=map_file, step=step, extra=extra, target=target, start=start))
    return path


def ros_map(folder: Path, name: str, image: str, resolution: str) -> str:
    (folder / f"{name}.yaml").write_text(f"image: {image}\nresolution: {resolution}\norigin: [0, 0, 0]\n")
    return f"{name}.yaml"


def make_cases(folder: Path) -> list[tuple[str, list[str]]]:
    """(label, apf-physics arguments) of each case, its files written into ``folder``."""
    eval_ = ["eval", "--planner", "gradient", "--no-progress"]
    cases = []
    with open(folder / "wide.pgm", "wb") as f:                      # one value of 10,000 characters
        f.write(b"P2 1000 1000 255\n" + b"0" * 9999 + b"1\n" + b"254 " * 999_999)
    cases.append(("P2, a 10,000-character value", eval_ + [str(world(folder, "wide", ros_map(folder, "wide_m", "wide.pgm",
                                                                                               "0.05"))), "--max-steps", "30"]))
    with open(folder / "big.pgm", "wb") as f:                       # 4000 x 4000 of 13 characters each
        f.write(b"P2 4000 4000 255\n")
        row = b"0000000000254 " * 4000 + b"\n"
        for _ in range(4000):
            f.write(row)
    cases.append(("P2 4000x4000, 13-char values", eval_ + [str(world(folder, "big", ros_map(folder, "big_m", "big.pgm", "0.05"),
                                                                       step=1.0, target="150, 150", start="10, 10")),
                                                              "--max-steps", "30"]))
    rng = np.random.default_rng(0)
    for label, density in (("dense", 0.5), ("sparse", 0.01)):
        occupied = rng.random((4000, 4000)) < density
        with open(folder / f"{label}.pgm", "wb") as f:
            f.write(b"P5\n4000 4000\n255\n")
            f.write(np.where(occupied, 0, 254).astype(np.uint8).tobytes())
        with open(folder / f"{label}.map", "wb") as f:
            f.write(b"type octile\nheight 4000\nwidth 4000\nmap\n")
            f.write(np.column_stack([np.where(occupied, ord("@"), ord(".")).astype(np.uint8),
                                     np.full(4000, 10, np.uint8)]).tobytes())
        if label == "dense":
            (folder / "dense.map.scen").write_text("version 1\n0\tdense.map\t4000\t4000\t10\t10\t20\t20\t14.1\n")
            cases.append(("4000x4000 at 2.5 mm, 50 % noise", eval_ + [str(world(
                folder, "dense", ros_map(folder, "dense_m", "dense.pgm", "0.0025"), target="5.0, 5.0",
                start="2.0, 2.0")), "--max-steps", "30"]))
            cases.append(("the same, MovingAI --cell 0.1", eval_ + [str(folder / "dense.map"), "--scen",
                                                                   str(folder / "dense.map.scen"), "--cell", "0.1"]))
        else:
            padded = np.pad(occupied, 3, constant_values=True)
            clear = ~np.lib.stride_tricks.sliding_window_view(padded, (7, 7)).any(axis=(2, 3))
            free = np.argwhere(clear)
            lines = ["version 1"]
            for _ in range(5):
                r1, c1 = free[rng.integers(len(free))]
                r2, c2 = free[np.argmin(np.abs(np.hypot(*(free - [r1, c1]).T) - 300))]
                lines.append(f"0\tsparse.map\t4000\t4000\t{c1}\t{r1}\t{c2}\t{r2}\t{np.hypot(r1 - r2, c1 - c2) * 1.1:.3f}")
            (folder / "sparse.map.scen").write_text("\n".join(lines) + "\n")
            cases.append(("MovingAI 1 % noise, --cell 0.1, 5 scen", eval_ + [str(folder / "sparse.map"), "--scen",
                                                                          str(folder / "sparse.map.scen"), "--cell", "0.1"]))
    from apf_physics.world.io.mapfiles import write_pgm
    write_pgm(folder / "free.pgm", np.zeros((40, 40), bool))
    cases.append(("resolution: 1.0e+300", eval_ + [str(world(folder, "huge", ros_map(folder, "huge_m", "free.pgm",
                                                                                    "1.0e+300"))), "--max-steps", "30"]))
    (folder / "g.map").write_text("type octile\nheight 8\nwidth 8\nmap\n" + "........\n" * 8)
    (folder / "g.scen").write_text("version 1\n0\tg.map\t8\t8\t1\t1\t6\t6\t7.07\n")
    cases.append(("--cell 1e300", eval_ + [str(folder / "g.map"), "--scen", str(folder / "g.scen"), "--cell", "1e300"]))
    with open(folder / "many.scen", "w") as f:
        f.write("version 1\n")
        block = "".join(f"{b}\tg.map\t8\t8\t1\t1\t6\t6\t7\n" for b in range(10))
        for _ in range(260_000):
            f.write(block)
    cases.append((".scen of 2.6M lines", eval_ + [str(folder / "g.map"), "--scen", str(folder / "many.scen")]))
    cases.append((".scen of 2.6M lines, --limit 1", eval_ + [str(folder / "g.map"), "--scen", str(folder / "many.scen"),
                                                              "--limit", "1"]))
    ros_map(folder, "free_m", "free.pgm", "0.05")
    cases.append(("max_speed: 1.0e+9", eval_ + [str(world(folder, "fast", "free_m.yaml",
                                                          extra=", kinematics: unicycle, max_speed: 1.0e+9")),
                                                "--max-steps", "30"]))
    return cases


def run(args: list[str], path: str | None, timeout: float, memory_kib: int) -> dict:
    env = dict(os.environ)
    if path is not None:
        env["PYTHONPATH"] = path
    env.setdefault("OMP_NUM_THREADS", "1")

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (memory_kib * 1024, memory_kib * 1024))

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    try:
        done = subprocess.run([sys.executable, "-c", RUN, *args], capture_output=True, text=True, timeout=timeout,
                              env=env, preexec_fn=limit, cwd=tempfile.gettempdir())
        status, err = done.returncode, done.stderr
    except subprocess.TimeoutExpired as exc:
        status, err = "timeout", (exc.stderr or b"").decode(errors="replace") if isinstance(exc.stderr, bytes) else ""
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    lines = [line for line in err.splitlines() if not line.startswith("@@ ")]
    peak = [int(line[3:]) for line in err.splitlines() if line.startswith("@@ ")]
    said = next((line for line in lines if line.strip()), "")
    if "Traceback" in err:
        said = "Traceback: " + next((line for line in reversed(lines) if line.strip()), "")
    return {"status": status, "wall": wall, "cpu": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
            "peak": f"{peak[0] / 2**20:.2f} GiB" if peak else "-", "said": said}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--timeout", type=float, default=60.0)
    parser.add_argument("--memory", type=int, default=4_000_000, help="address space per case [KiB] (ulimit -v)")
    parser.add_argument("--baseline", help="another checkout: every case again on its package, side by side")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        cases = make_cases(Path(folder))
        versions = [("this", None)] + ([("baseline", args.baseline)] if args.baseline else [])
        for label, command in cases:
            for version, path in versions:
                r = run(command, path, args.timeout, args.memory)
                wall = f"{r['wall']:.1f} s" if r["status"] != "timeout" else f">{args.timeout:.0f} s"
                print(f"{label:<40} {version:<9} exit {str(r['status']):<8} {wall:>8} {r['cpu']:>7.1f} s CPU "
                      f"{r['peak']:>10}  {r['said'][:150]}", flush=True)


if __name__ == "__main__":
    main()
