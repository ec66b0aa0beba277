"""The physics probe: do contacts hold at every speed a world file accepts?

    python tools/probe_contacts.py [--steps 3000] [--seeds 22 33] [--kinds ...] [--speeds 1 4]

Robots are driven at random among thin bars (0.001 to 0.1 thick, at random angles) in 20 × 20
worlds, straight through the physics (:class:`~apf_physics.sim.physics.Physics`), never reset:
a robot that hits a bar keeps being driven. Kinds:

- ``holonomic``: 128 robots alone in their slots, random velocities at up to √2 (the holonomic
  top speed), each held about ten steps; ``holonomic-crowd``: 8 slots of 4 in one world, all
  meeting (a crowd of 32);
- ``unicycle``: 128 unicycles alone in their slots, each step a random command at full speed
  forward or back and a random turn rate (within ``max_turn_rate`` π and the acceleration
  limits), at each ``--speeds`` top speed (the documented maximum is 4 steps per control step);
- ``unicycle-formation``: 32 slots of 4 unicycles that meet each other;
- ``unicycle-crowd``: 8 slots of 4 unicycles in one world, all meeting (a crowd of 32).

After every step each robot is measured exactly (the world's clearance): how far it is inside
an obstacle or past the map's edge (the contract: at most 0.01), how far into another robot it
meets (at most 0.02), and whether it **tunnelled**: its straight move crossed a bar's centre line
where going round either end of the bar is longer than the robot can move in a step, so that
it must have passed through the bar. Holonomic robots that meet are also checked for a centre
through another robot (their straight paths of the step within half a radius, as
``tests/contacts_check.py``); unicycles are not (two turning by up to π in a step may pass close
on their arcs without touching, so straight paths prove nothing). Prints, per kind and speed,
the robot-steps, the worst overlaps, and the counts of robot-steps that break each bound, with
the physics' CPU time.

The probe uses only what the physics offered before the speed cap (``Physics``,
``substep_velocities``, ``UnicycleLimits``), so ``PYTHONPATH=OTHER_CHECKOUT`` runs it on another
version for a before-and-after.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from apf_physics import world_from_dict
from apf_physics.sim.physics import Physics
from apf_physics.world.kinematics import UnicycleLimits, substep_velocities, wrap_angle

OBSTACLE_OVERLAP = 0.01
ROBOT_OVERLAP = 0.02


def bars(rng: np.random.Generator, count: int = 12):
    """A 20 × 20 world of ``count`` bars 0.001 to 0.1 thick, and each bar's centre line ``(a, b)``."""
    obstacles, lines = [], []
    for _ in range(count):
        c = rng.uniform(3, 17, 2)
        angle, length, width = rng.uniform(0, math.pi), rng.uniform(2, 6), rng.uniform(0.001, 0.1)
        u = np.array([math.cos(angle), math.sin(angle)])
        n = np.array([-u[1], u[0]])
        a, b = np.clip(c - u * length / 2, 0.5, 19.5), np.clip(c + u * length / 2, 0.5, 19.5)
        obstacles.append({"polygon": [(a - n * width / 2).tolist(), (b - n * width / 2).tolist(),
                                      (b + n * width / 2).tolist(), (a + n * width / 2).tolist()]})
        lines.append((a, b))
    world = world_from_dict({"size": [20, 20], "field": "thesis-fixed", "targets": [[19.5, 19.5]],
                             "obstacles": obstacles})
    return world, lines


def _crosses(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) whether the segments ``p → q`` cross the segment ``a → b`` (properly)."""
    def side(o, s, t):
        return (s[..., 0] - o[..., 0]) * (t[..., 1] - o[..., 1]) - (s[..., 1] - o[..., 1]) * (t[..., 0] - o[..., 0])
    return (side(a, b, p) * side(a, b, q) < 0) & (side(p, q, a) * side(p, q, b) < 0)


def tunnelled(lines, before: np.ndarray, after: np.ndarray, reach: float) -> np.ndarray:
    """(N,) robots whose move crossed a bar's centre line where the way round either end of the
    bar is longer than ``reach``: a centre that went round an end travelled at least that far
    (the shortest path that crosses the line beyond an end passes through the end)."""
    out = np.zeros(len(before), bool)
    for a, b in lines:
        around = np.minimum(np.hypot(*(before - a).T) + np.hypot(*(after - a).T),
                            np.hypot(*(before - b).T) + np.hypot(*(after - b).T))
        out |= _crosses(before, after, a[None], b[None]) & (around > reach)
    return out


def robot_overlaps(positions: np.ndarray, before: np.ndarray, groups, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """``(overlap (N,), through (N,))``: each robot's largest overlap with a robot of its group, and
    whether its straight path came within half a radius of another's (a centre through a robot)."""
    overlap, through = np.zeros(len(positions)), np.zeros(len(positions), bool)
    for robots in groups:
        a, b = positions[robots], before[robots]
        m = len(robots)
        d = np.hypot(*(a[:, None] - a[None]).transpose(2, 0, 1)) + np.eye(m) * 1e9
        overlap[robots] = (2 * radius - d).max(axis=1)
        r0, dr = b[:, None] - b[None], (a - b)[:, None] - (a - b)[None]
        aa = np.sum(dr * dr, -1)
        s = np.clip(np.where(aa > 0, -np.sum(r0 * dr, -1) / np.where(aa > 0, aa, 1), 0), 0, 1)
        closest = np.hypot(*(r0 + s[..., None] * dr).transpose(2, 0, 1)) + np.eye(m) * 1e9
        through[robots] = closest.min(axis=1) < 0.5 * radius
    return overlap, through


def probe(kind: str, speed: float, steps: int, seed: int) -> dict:
    """One run of ``kind`` at top speed ``speed``; the counts of the module docstring."""
    rng = np.random.default_rng(seed)
    made = [bars(rng) for _ in range(4)]
    worlds = [w for w, _ in made]
    unicycle = kind.startswith("unicycle")
    slots, m, crowd = {"holonomic": (128, 1, False), "holonomic-crowd": (8, 4, True), "unicycle": (128, 1, False),
                       "unicycle-formation": (32, 4, False), "unicycle-crowd": (8, 4, True)}[kind]
    world_of = np.zeros(slots, np.intp) if crowd else np.arange(slots) % len(worlds)
    top = max(math.sqrt(2.0), speed) if unicycle else math.sqrt(2.0)
    physics = Physics([worlds[i] for i in world_of], m, max_speed=top, crowds=[0] * slots if crowd else None)
    n = slots * m
    if crowd:
        physics.place(np.arange(n), worlds[0].random_free_positions(rng, n))
    else:
        for s in range(slots):
            physics.place(np.arange(s * m, (s + 1) * m), worlds[world_of[s]].random_free_positions(rng, m))
    robot_world = np.repeat(world_of, m)
    groups = ([np.arange(n)] if crowd else [np.arange(s * m, (s + 1) * m) for s in range(slots)]) if m > 1 else []
    limits = UnicycleLimits(max_speed=speed, max_reverse=speed, max_turn_rate=math.pi, max_accel=2 * speed,
                            max_turn_accel=2 * math.pi)
    state = np.zeros((n, 5))
    state[:, 2] = rng.uniform(-math.pi, math.pi, n)
    heading = rng.uniform(0, 2 * math.pi, n)
    pace = rng.choice([1.0, math.sqrt(2.0)], n)
    radius = worlds[0].robot_radius
    # how far a centre can move in a step: its speed, twice that when pushed by robots that meet
    reach = top * (2.0 if m > 1 else 1.0) + radius
    out = {"robot-steps": 0, "obstacle": 0, "robot": 0, "through": 0, "tunnel": 0,
           "worst obstacle": 0.0, "worst robot": 0.0, "substeps": physics.substeps}
    cpu = 0.0
    for _ in range(steps):
        before = physics.positions.copy()
        if unicycle:
            v, w = limits.clamp(rng.choice([-1.0, 1.0], n) * speed, rng.uniform(-math.pi, math.pi, n),
                                state[:, 3], state[:, 4])
            state[:, :2] = before
            command = substep_velocities(state, v, w, physics.substeps)
            state[:, 2] = wrap_angle(state[:, 2] + w)
            state[:, 3], state[:, 4] = v, w
        else:
            change = rng.random(n) < 0.1
            heading[change] = rng.uniform(0, 2 * math.pi, int(change.sum()))
            command = np.column_stack([np.cos(heading), np.sin(heading)]) * pace[:, None]
        t = time.process_time()
        physics.step(command)
        cpu += time.process_time() - t
        after = physics.positions
        inside = np.zeros(n)
        tunnel = np.zeros(n, bool)
        for i, (world, lines) in enumerate(made):
            mine = robot_world == i
            if mine.any():
                inside[mine] = world.robot_radius - world.clearance(after[mine])
                tunnel[mine] = tunnelled(lines, before[mine], after[mine], reach)
        overlap, through = robot_overlaps(after, before, groups, radius)
        if unicycle:
            through[:] = False   # (arcs: see the module docstring)
        out["robot-steps"] += n
        out["obstacle"] += int((inside > OBSTACLE_OVERLAP).sum())
        out["robot"] += int((overlap > ROBOT_OVERLAP).sum())
        out["through"] += int(through.sum())
        out["tunnel"] += int(tunnel.sum())
        out["worst obstacle"] = max(out["worst obstacle"], float(inside.max()))
        out["worst robot"] = max(out["worst robot"], float(overlap.max(initial=0.0)))
    out["physics us/robot-step"] = cpu / out["robot-steps"] * 1e6
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=3000, help="control steps per run (default 3000)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[22, 33], help="seeds, a run each (default 22 33)")
    parser.add_argument("--kinds", nargs="+", default=["holonomic", "holonomic-crowd", "unicycle", "unicycle-formation",
                                                       "unicycle-crowd"])
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.0, 3.0, 4.0],
                        help="unicycles' top speeds [steps per control step] (default 1 3 4; 4 is the most a world "
                             "file accepts)")
    args = parser.parse_args()
    print(f"{'kind':<20} {'speed':>5} {'seed':>5} {'substeps':>8} {'robot-steps':>12} {'worst in obst.':>14} "
          f"{'> 0.01':>7} {'worst in robot':>14} {'> 0.02':>7} {'through':>8} {'tunnels':>8} {'us/robot-step':>14}")
    for kind in args.kinds:
        for speed in (args.speeds if kind.startswith("unicycle") else [math.sqrt(2.0)]):
            for seed in args.seeds:
                r = probe(kind, speed, args.steps, seed)
                print(f"{kind:<20} {speed:>5.3g} {seed:>5} {r['substeps']:>8} {r['robot-steps']:>12,} "
                      f"{r['worst obstacle']:>14.4f} {r['obstacle']:>7} {r['worst robot']:>14.4f} {r['robot']:>7} "
                      f"{'-' if kind.startswith('unicycle') else r['through']:>8} {r['tunnel']:>8} "
                      f"{r['physics us/robot-step']:>14.1f}", flush=True)


if __name__ == "__main__":
    main()
