"""Cost against the number of obstacles: one 100 x 100 world of K small boxes on a jittered lattice.

    python tools/bench_obstacles.py [--counts 25 100 400 1600 3600] [--steps 200] [--envs 256] [--spacing S]

Prints, from one process, for each K (same 8 starts and target, boxes of 0.6 x 0.6; with
``--spacing S`` the map grows instead, K boxes S apart, so that the density stays the same and
only the count grows; the starts and target scale with the map):

- start-up: loading the world and building its index (seconds);
- ``eval --planner dqn`` (the shipped map network, shielded) in seconds per robot-step, the
  8 starts run together, start-up excluded, and its ratio to the smallest K;
- the vector env (``NavigateVectorEnv``, random actions and random starts) in robot-steps per
  second at N = ``--envs``, and its ratio to the smallest K.
Aim: both ratios at K = 3,600 within 1.5 of K = 25.

    python tools/bench_obstacles.py --chipmunk [--counts 25 3600] [--env-steps 200] [--rounds 3]

instead splits the vector env's step by this thread's CPU time (``time.thread_time``, what a
loaded machine's scheduler takes away is not in it), in rounds over the counts: the whole step,
chipmunk's ``Space.step`` timed apart, and the rest; how many robots end an episode, are in
pymunk, and wait parked in its pool per step; and chipmunk's floor: a bare pymunk space of the
same boxes (the physics' spatial hash) with as many discs moving among them as were in pymunk,
no parked bodies, stepped as often.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from apf_physics.envs import NavigateVectorEnv
from apf_physics.experiments.evaluate import evaluate
from apf_physics.planners import make_planner
from apf_physics.world.io.worldfile import world_from_dict

STARTS = [[2, 2], [2, 50], [2, 98], [50, 2], [98, 2], [50, 98], [30, 70], [70, 30]]
TARGET = [96.0, 96.0]


def lattice_world(count: int, seed: int = 0, spacing: float | None = None):
    """K boxes of 0.6 on a jittered sqrt(K) x sqrt(K) lattice over 100 x 100 (or ``spacing`` apart on
    a map of ``sqrt(K) * spacing``), kept off the starts and target."""
    rng = np.random.default_rng(seed)
    n = int(round(np.sqrt(count)))
    side = 100.0 if spacing is None else n * spacing
    spacing = side / n
    scale = side / 100.0
    keep = np.clip(np.array(STARTS + [TARGET], float) * scale, 1.0, side - 1.0)
    boxes = []
    for i in range(n):
        for j in range(n):
            c = (np.array([i, j]) + 0.5 + rng.uniform(-0.25, 0.25, 2)) * spacing - 0.3
            if np.min(np.hypot(*(keep - (c + 0.3)).T)) < 1.5:
                continue   # kept off the starts and the target
            c = np.clip(c, 0.2, side - 0.8)
            boxes.append({"polygon": [[c[0], c[1]], [c[0] + 0.6, c[1]], [c[0] + 0.6, c[1] + 0.6], [c[0], c[1] + 0.6]]})
    return world_from_dict({"name": f"lattice{len(boxes)}", "size": [side, side], "field": "thesis-general",
                            "obstacles": boxes, "targets": [keep[-1].tolist()], "starts": keep[:-1].tolist()},
                           f"<lattice {count}>")


def eval_cost(world, steps: int) -> tuple[float, float]:
    """(start-up seconds, seconds per robot-step) of the shielded map network from the 8 starts."""
    planner = make_planner("dqn")
    t = time.perf_counter()
    evaluate(planner, [world], max_steps=1)          # start-up: index, rasters, the map network's values
    startup = time.perf_counter() - t
    t = time.perf_counter()
    ev = evaluate(planner, [world], max_steps=steps)
    robot_steps = sum(e.steps for e in ev.episodes)
    return startup, (time.perf_counter() - t) / max(robot_steps, 1)


def vector_rate(world, envs: int, steps: int) -> float:
    env = NavigateVectorEnv(world=world, num_envs=envs, starts="random")
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 9, (steps, envs))
    for a in actions[:10]:
        env.step(a)
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    return steps * envs / (time.perf_counter() - t)


def chipmunk_split(world, envs: int, steps: int) -> dict:
    """CPU ms per step of the vector env among ``world``'s boxes, chipmunk's ``Space.step`` timed apart."""
    import pymunk

    spent = [0.0]
    step = pymunk.Space.step

    def timed(space, dt):
        t = time.thread_time()
        step(space, dt)
        spent[0] += time.thread_time() - t

    env = NavigateVectorEnv(world=world, num_envs=envs, starts="random")
    env.reset(seed=0)
    physics = env.task.stepper.physics
    actions = np.random.default_rng(0).integers(0, 9, (steps + 20, envs))
    for a in actions[:20]:
        env.step(a)
    ended = in_pymunk = parked = 0
    pymunk.Space.step = timed
    try:
        t = time.thread_time()
        for a in actions[20:]:
            _, _, terminated, truncated, _ = env.step(a)
            ended += int(np.count_nonzero(terminated | truncated))
            in_pymunk += int(np.count_nonzero(physics.in_pymunk))
            parked += len(physics.proxies) - physics.proxies.lent
        whole = (time.thread_time() - t) / steps
    finally:
        pymunk.Space.step = step
    return {"whole": whole * 1e3, "chipmunk": spent[0] / steps * 1e3, "ended": ended / steps,
            "in_pymunk": in_pymunk / steps, "parked": parked / steps, "physics": physics}


def chipmunk_floor(world, physics, discs: int, steps: int) -> float:
    """CPU ms per control step of a bare pymunk space set up as ``physics``'s (solver, spatial hash,
    substeps): ``world``'s boxes, ``discs`` of the robot's radius moving among them at random
    velocities of one unit per step, no parked bodies."""
    import pymunk

    space = pymunk.Space()
    space.iterations = physics.space.iterations
    space.collision_slop = physics.space.collision_slop
    space.collision_persistence = physics.space.collision_persistence
    space.use_spatial_hash(physics.hash_dim, physics.hash_cells)
    substeps = physics.substeps
    space.add(*[pymunk.Poly(space.static_body, [tuple(v) for v in np.asarray(o.vertices)]) for o in world.obstacles])
    rng = np.random.default_rng(0)
    for _ in range(discs):
        body = pymunk.Body(1.0, float("inf"))
        body.position = tuple(rng.uniform(1.0, world.size[0] - 1.0, 2))
        body.velocity = tuple(rng.uniform(-1.0, 1.0, 2))
        space.add(body, pymunk.Circle(body, world.robot_radius))
    for _ in range(substeps):
        space.step(1.0 / substeps)
    t = time.thread_time()
    for _ in range(steps * substeps):
        space.step(1.0 / substeps)
    return (time.thread_time() - t) / steps * 1e3


def chipmunk_main(args) -> None:
    worlds = [lattice_world(count, spacing=args.spacing) for count in args.counts]
    runs: list[list[dict]] = [[] for _ in worlds]
    for _ in range(args.rounds):   # rounds over the counts: a change of the machine's load hits all alike
        for i, world in enumerate(worlds):
            runs[i].append(chipmunk_split(world, args.envs, args.env_steps))
    print(f"the vector env at N = {args.envs}, random actions, CPU ms per step; {args.rounds} rounds (median, range)")
    print(f"{'K':>6} {'whole step':>20} {'Space.step':>20} {'the rest':>20} {'ended':>6} {'in pymunk':>10} "
          f"{'parked':>7} {'bare space':>11} {'rate / smallest K':>18}")
    base = None
    for world, rounds in zip(worlds, runs):
        whole = [r["whole"] for r in rounds]
        chip = [r["chipmunk"] for r in rounds]
        rest = [w - c for w, c in zip(whole, chip)]
        r0 = rounds[0]
        floor = chipmunk_floor(world, r0["physics"], int(round(np.median([r["in_pymunk"] for r in rounds]))),
                               args.env_steps)
        base = base or whole
        span = lambda xs: f"{np.median(xs):.3f} ({min(xs):.2f}-{max(xs):.2f})"   # noqa: E731
        print(f"{len(world.obstacles):>6} {span(whole):>20} {span(chip):>20} {span(rest):>20} "
              f"{np.median([r['ended'] for r in rounds]):>6.1f} {np.median([r['in_pymunk'] for r in rounds]):>10.1f} "
              f"{np.median([r['parked'] for r in rounds]):>7.1f} {floor:>11.3f} "
              f"{'1/' + format(np.median(whole) / np.median(base), '.2f'):>18}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[25, 100, 400, 1600, 3600])
    parser.add_argument("--steps", type=int, default=200, help="episode limit of the eval runs")
    parser.add_argument("--env-steps", type=int, default=200, help="vector env steps per K")
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--spacing", type=float, help="boxes this far apart on a map that grows with K (fixed density)")
    parser.add_argument("--chipmunk", action="store_true",
                        help="split the vector env's step by CPU time: chipmunk, the rest, and chipmunk's floor")
    parser.add_argument("--rounds", type=int, default=3, help="with --chipmunk: rounds over the counts")
    args = parser.parse_args()
    if args.chipmunk:
        chipmunk_main(args)
        return
    rows = []
    for count in args.counts:
        t = time.perf_counter()
        world = lattice_world(count, spacing=args.spacing)
        world.shapes, world.near_shapes   # the indexes, built once
        load = time.perf_counter() - t
        startup, per_step = eval_cost(world, args.steps)
        rate = vector_rate(world, args.envs, args.env_steps)
        rows.append((len(world.obstacles), world.size[0], load, startup, per_step, rate))
        print(f"K={len(world.obstacles)} done", flush=True)
    base = rows[0]
    print(f"{'K':>6} {'map':>9} {'load s':>8} {'eval start-up s':>16} {'eval ms/robot-step':>19} {'ratio':>6} "
          f"{'env robot-steps/s':>18} {'ratio':>6}")
    for k, side, load, startup, per_step, rate in rows:
        print(f"{k:>6} {side:>9.0f} {load:>8.2f} {startup:>16.2f} {per_step * 1e3:>19.3f} {per_step / base[4]:>6.2f} "
              f"{rate:>18,.0f} {base[5] / rate:>6.2f}")


if __name__ == "__main__":
    main()
