"""The anchors beside the fleet, on the same instances: a MAPF solver and navground's ORCA.

    python tools/fleet_anchors.py mapf MAP SCEN --agents N [--solvers lacam,pibt] [--time-limit 60]
    python tools/fleet_anchors.py orca MAP SCEN --agents N [--max-steps S]
    python tools/fleet_anchors.py lifelong MAP SCEN --agents N --horizon H [--seed S]
    python tools/fleet_anchors.py lacam MAP SCEN --agents N --binary PATH [--time-limit 30]

Neither is a dependency of the package: install them beside it for the benchmark
(``pip install pymapf navground``); a subcommand whose library is missing says so and stops.

``mapf``: the first N lines of a scenario file as one MAPF instance for ``pymapf`` (0.9: LaCAM and
PIBT in Python) on the map's grid, 4-connected with unit moves and waits (the MAPF benchmark's
convention: vertex and swap conflicts, no bodies). Prints whether it solved, its sum of costs and
makespan (in steps), the instance's lower bounds (the sums and the largest of the agents' own
shortest 4-connected lengths), the sum of the scenario's octile optima, and its time.

``orca``: the same robots as navground's ORCA agents (discs of radius 0.25, omnidirectional, at most
1 unit per second; one second is one of our control steps, simulated in steps of 0.1 s) among the
map's blocked cells as walls. ORCA avoids, it does not plan: each agent follows the corners of its own
shortest octile path (the usual pairing of ORCA with a global path). Prints the agents arrived
(within 0.75 of their goal at the end), the sum of their arrival times in seconds (= steps), the
largest, the agent pairs whose discs overlapped and the agents whose disc entered a wall (each summed
over the time steps of 0.1 s), and the time per agent-step.

``lacam``: LaCAM* as its authors ship it (``Kei18/lacam3``, a C++ program: give the path of the
``main`` binary you built by its README; nothing here builds it): the same instance (its ``-m MAP -i
SCEN -N N``, 4-connected), its sum of costs, makespan and their lower bounds as it reports them,
and its time.

``lifelong``: the MAPF baseline's throughput: pymapf's PIBT step (4-connected, no bodies) run one
step at a time, each agent given its next goal as soon as it arrives, from the same seeded streams
as ``apf-physics eval ... --lifelong`` (:class:`apf_physics.experiments.fleet.GoalStream`, here on
the 4-connected grid's cells).
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import tempfile
import time

import numpy as np

from apf_physics.control.fleet import Lattice
from apf_physics.control.fleet import GoalStream, place_fleet
from apf_physics.experiments.movingai import scenario_fleet
from apf_physics.common.geometry import occupancy_rectangles
from apf_physics.world.io.mapfiles import read_movingai_map, read_movingai_scen

FOUR = np.array([0, 1, 2, 3, 8])   # up, down, left, right, stay among ACTIONS


def cells(args):
    """(occupied (rows, cols) with row 0 the top line, [(start (r, c), goal (r, c))] for the first N lines)."""
    grid = read_movingai_map(args.map)
    occupied = grid.occupied[::-1]          # MovingAI's rows from the top
    scen = read_movingai_scen(args.scen)[:args.agents]
    pairs = [((s.start[1], s.start[0]), (s.goal[1], s.goal[0])) for s in scen]
    return occupied, pairs, scen


def four_connected_bounds(args):
    """(sum, largest) of the agents' own shortest 4-connected lengths (A* on the lattice without diagonals)."""
    world, fleet = scenario_fleet(args.map, args.scen, args.agents)
    placed = place_fleet(world, fleet)
    lattice = placed.lattice
    ok = lattice.ok.copy()
    ok[:, 4:8] = False
    from apf_physics.world.search import node_distances
    lengths = [node_distances(ok, lattice.offsets, lattice.lengths, int(g))[int(s)]
               for s, g in zip(placed.starts, placed.goals)]
    return float(np.sum(lengths)), float(np.max(lengths))


def pymapf_grid(args):
    """pymapf (a clear exit where it is missing), the map as its grid, and the scenario's cell pairs and lines."""
    try:
        import pymapf
    except ImportError:
        raise SystemExit("pymapf is not installed: pip install pymapf")
    occupied, pairs, scen = cells(args)
    return pymapf, pymapf.GridMap(occupied.astype(int).tolist()), pairs, scen


def mapf(args) -> None:
    pymapf, grid, pairs, scen = pymapf_grid(args)
    agents = [pymapf.Agent(f"a{i}", s, g) for i, (s, g) in enumerate(pairs)]
    problem = pymapf.MAPFProblem(grid, agents, allow_diagonals=False)
    lower, longest = four_connected_bounds(args)
    octile = sum(s.optimal for s in scen)
    print(f"{args.map} {args.scen} {args.agents} agents: lower bounds SoC {lower:.0f}, makespan {longest:.0f}; "
          f"octile optima {octile:.1f}; load average {os.getloadavg()[0]:.1f}")
    for name in args.solvers.split(","):
        kwargs = {"time_limit": args.time_limit}
        clock = time.perf_counter()
        solution = pymapf.solve(problem, name, **kwargs)
        seconds = time.perf_counter() - clock
        if solution is None:
            print(f"  {name}: not solved in {seconds:.1f} s")
            continue
        valid = solution.is_valid() if hasattr(solution, "is_valid") else None
        print(f"  {name}: solved, valid {valid}, SoC {solution.sum_of_costs} ({solution.sum_of_costs / lower:.3f} of the "
              f"bound, {solution.sum_of_costs / octile:.3f} of the octile optima), makespan {solution.makespan}, "
              f"{seconds:.1f} s", flush=True)


def shortest_path_corners(lattice: Lattice, start: int, goal: int) -> list[np.ndarray]:
    """The corners of one shortest octile path from ``start`` to ``goal`` on the lattice, the goal last."""
    d = lattice.distances(goal)
    path, node = [], start
    while node != goal:
        ends = lattice.ends(np.array([node]))[0, :8]
        ok = lattice.ok[node, :8]
        step = np.where(ok, d[ends] + lattice.lengths[:8], np.inf)
        node = int(ends[int(np.argmin(step))])
        path.append(node)
    points = lattice.points(np.array(path, np.intp)) if path else lattice.points(np.array([goal]))
    keep = [0] + [k for k in range(1, len(points) - 1)
                  if np.any(points[k] - points[k - 1] != points[k + 1] - points[k])] + [len(points) - 1]
    return [points[k] for k in sorted(set(keep))]


def orca(args) -> None:
    try:
        import navground.core as core
        import navground.sim as sim
    except ImportError:
        raise SystemExit("navground is not installed: pip install navground")
    world, fleet = scenario_fleet(args.map, args.scen, args.agents)
    placed = place_fleet(world, fleet)
    lattice = placed.lattice
    grid = read_movingai_map(args.map)
    w = sim.World()
    for c0, r0, c1, r1 in occupancy_rectangles(grid.occupied).tolist():
        corners = [(c0, r0), (c1, r0), (c1, r1), (c0, r1)]
        for a, b in zip(corners, corners[1:] + corners[:1]):
            w.add_wall(sim.Wall(np.array(a, float), np.array(b, float)))
    height, width = grid.occupied.shape
    for a, b in (((0, 0), (width, 0)), ((width, 0), (width, height)), ((width, height), (0, height)), ((0, height), (0, 0))):
        w.add_wall(sim.Wall(np.array(a, float), np.array(b, float)))
    agents = []
    for i in range(len(fleet)):
        agent = sim.Agent(radius=world.robot_radius)
        agent.kinematics = core.kinematics.OmnidirectionalKinematics(max_speed=1.0)
        agent.behavior = core.behaviors.ORCABehavior()
        agent.behavior.optimal_speed = 1.0
        agent.position = fleet.starts[i]
        corners = shortest_path_corners(lattice, int(placed.starts[i]), int(placed.goals[i]))
        agent.task = sim.tasks.WaypointsTask(waypoints=corners, loop=False, tolerance=0.25)
        agent.control_period = 0.1
        w.add_agent(agent)
        agents.append(agent)
    dt, steps = 0.1, args.max_steps or 4 * (width + height)
    arrived_at = np.full(len(agents), np.nan)
    overlap = walls = 0
    clock = time.perf_counter()
    for k in range(int(steps / dt)):
        w.update(dt)
        positions = np.array([a.position for a in agents])
        at = np.hypot(*(positions - fleet.targets).T) <= world.goal_tolerance
        arrived_at = np.where(at & np.isnan(arrived_at), (k + 1) * dt, np.where(at, arrived_at, np.nan))
        overlap += _overlapping_pairs(positions, 2 * world.robot_radius)
        walls += int(np.sum(world.static_clearance(positions) < world.robot_radius - 1e-6))
        if at.all():
            break
    seconds = time.perf_counter() - clock
    done = ~np.isnan(arrived_at)
    t = (k + 1) * dt
    print(f"orca {args.map} {args.agents} agents: {int(done.sum())}/{len(agents)} arrived, sum of arrival times "
          f"{np.nansum(np.where(done, arrived_at, t)):.0f} s (= steps), last {np.nanmax(arrived_at) if done.any() else 0:.1f} s, "
          f"agent pairs overlapping {overlap}, agents in a wall {walls} (each summed over 0.1 s steps), {1000 * seconds / (len(agents) * t):.3f} ms "
          f"per agent-step of 1 s; load average {os.getloadavg()[0]:.1f}", flush=True)


def _overlapping_pairs(positions: np.ndarray, contact: float) -> int:
    d = np.hypot(positions[:, None, 0] - positions[None, :, 0], positions[:, None, 1] - positions[None, :, 1])
    return int(np.sum(np.triu(d < contact - 1e-6, 1)))


def lifelong(args) -> None:
    pymapf, grid, pairs, _ = pymapf_grid(args)
    from pymapf.algorithms.pibt import _DistanceOracle, pibt_step
    world, fleet = scenario_fleet(args.map, args.scen, args.agents)
    placed = place_fleet(world, fleet)
    lattice = placed.lattice
    stream = GoalStream(lattice, placed.starts, args.seed)
    rows = lattice.shape[0]
    to_cell = lambda node: (rows - 1 - int(node) // lattice.shape[1], int(node) % lattice.shape[1])  # noqa: E731
    to_node = lambda cell: (rows - 1 - cell[0]) * lattice.shape[1] + cell[1]  # noqa: E731
    names = [f"a{i}" for i in range(len(pairs))]
    positions = {n: s for n, (s, _) in zip(names, pairs)}
    goals = {n: g for n, (_, g) in zip(names, pairs)}
    tables = {}
    rng = random.Random(args.seed)
    priorities = {n: i / (len(names) + 1) for i, n in enumerate(names)}
    reached, clock = 0, time.perf_counter()
    for step in range(args.horizon):
        for n in names:
            if goals[n] not in tables:
                tables[goals[n]] = _DistanceOracle(grid, {"g": goals[n]})
        distance = lambda name, cell: tables[goals[name]]("g", cell)  # noqa: E731
        nxt = pibt_step(grid, names, positions, goals, priorities, distance, rng=rng)
        if nxt is None:   # no valid configuration found: everyone waits a step
            nxt = dict(positions)
        positions = nxt
        for i, n in enumerate(names):
            if positions[n] == goals[n]:
                reached += 1
                goals[n] = to_cell(stream.next(i, to_node(positions[n])))
                priorities[n] = i / (len(names) + 1)
            else:
                priorities[n] += 1
    seconds = time.perf_counter() - clock
    print(f"pymapf PIBT lifelong, {args.agents} agents, {args.horizon} steps: {reached} goals, throughput "
          f"{reached / args.horizon:.3f} per step, {seconds:.0f} s; load average {os.getloadavg()[0]:.1f}", flush=True)


def lacam(args) -> None:
    if not os.path.isfile(args.binary):
        raise SystemExit(f"{args.binary}: no lacam3 binary there (build Kei18/lacam3 by its README)")
    _, _, scen = cells(args)
    octile = sum(s.optimal for s in scen)
    with tempfile.TemporaryDirectory() as folder:
        out = os.path.join(folder, "result.txt")
        clock = time.perf_counter()
        subprocess.run([args.binary, "-m", args.map, "-i", args.scen, "-N", str(args.agents), "-t", str(args.time_limit),
                        "-o", out], check=True, capture_output=True)
        seconds = time.perf_counter() - clock
        result = dict(line.split("=", 1) for line in open(out).read().splitlines() if "=" in line)
    soc = int(result["soc"])
    print(f"lacam3 {args.map} {args.agents} agents: solved {result['solved']}, SoC {soc} (bound {result['soc_lb']}; "
          f"{soc / octile:.3f} of the octile optima), makespan {result['makespan']} (bound {result['makespan_lb']}), "
          f"{int(result['comp_time']) / 1000:.1f} s of search ({seconds:.1f} s in all); load average "
          f"{os.getloadavg()[0]:.1f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, func in (("mapf", mapf), ("orca", orca), ("lifelong", lifelong), ("lacam", lacam)):
        p = sub.add_parser(name)
        p.add_argument("map")
        p.add_argument("scen")
        p.add_argument("--agents", type=int, required=True)
        p.set_defaults(func=func)
        if name == "mapf":
            p.add_argument("--solvers", default="lacam,pibt")
            p.add_argument("--time-limit", type=float, default=60.0)
        if name == "orca":
            p.add_argument("--max-steps", type=int)
        if name == "lacam":
            p.add_argument("--binary", required=True)
            p.add_argument("--time-limit", type=float, default=30.0)
        if name == "lifelong":
            p.add_argument("--horizon", type=int, default=500)
            p.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
