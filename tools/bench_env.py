"""Benchmark the environments: Navigate-v0 beside CartPole-v1, and the vector env beside VMAS.

    python tools/bench_env.py [--steps 20000] [--vmas] [--sizes 64 256 1024] [--robots-kinds] [--no-chipmunk]

Prints, from one process:

- µs per step of ``apf_physics/Navigate-v0`` and Gymnasium's ``CartPole-v1``, both through
  ``gymnasium.make`` (wrappers included) with random actions, timed in alternating blocks, and
  their ratio (aim ≤ 5);
- robot-steps per second of ``NavigateVectorEnv`` on fixed20 (random starts and actions) at
  each N, and with ``--vmas`` VMAS's ``navigation`` scenario (CPU, one agent per env,
  continuous random actions, one torch thread) at the same N, both without obstacles and in
  fixed20 (its three obstacles as colliding box landmarks, :func:`vmas_fixed20`: the same work
  as ours), stepped in alternating blocks, and the ratios by the wall clock and by this
  process's CPU time. Aim: ours at or above VMAS in fixed20 at every N.
- with ``--robots-kinds``, a second table from the same runs: robot-steps per second of the
  window env beside ``NavigateVectorEnv`` with a unicycle, continuous ``(v, ω)`` actions and a
  64-beam lidar observation (random actions in the box), their ratio (aim ≥ 0.5 at N = 1024),
  and with ``--vmas`` VMAS's ``navigation`` with its lidar at 12 rays (its default, the first
  table's) and at 64 (``n_lidar_rays=64``);
- how many robots per step needed pymunk (the others moved without it);
- with ``--no-chipmunk``, our vector env again with chipmunk's ``Space.step`` stubbed out
  (nothing moves in pymunk, nothing touches): an estimate of the rest of our step, and its ratio
  to VMAS with ``--vmas``;
- the cost of an observation in fixed20 with 8 moving discs beside the same discs frozen
  (aim ≤ 2×);
- with ``--contacts``, whether contacts hold: robots driven at random headings
  (each held about ten steps) among thin walls, alone in their slots and in crowds of 64 per
  world, counting the robot-steps that end more than 0.01 inside an obstacle or past the
  map's edge, more than 0.02 into another robot, or with a centre through another robot.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import gymnasium as gym
import numpy as np
import pymunk

import apf_physics  # noqa: F401  (registers the ids)
from apf_physics.envs import NavigateVectorEnv
from apf_physics.world.obstacles import CircleObstacle, Motion
from apf_physics.sensing.observation import Observer, ObserverConfig


def single_rates(steps: int, blocks: int = 10) -> tuple[float, float]:
    """Steps per second of ``CartPole-v1`` and of ``apf_physics/Navigate-v0`` (fixed20), each
    through ``gymnasium.make``, random actions, timed in alternating blocks (after a block of
    warm-up: the compiled kernels are compiled on their first use); the median block of each."""
    envs = [gym.make("CartPole-v1"), gym.make("apf_physics/Navigate-v0", world="fixed20")]
    rng = np.random.default_rng(0)
    per = max(1, steps // blocks)
    rates: list[list[float]] = [[], []]
    for env in envs:
        env.reset(seed=0)
    for block in range(blocks + 1):
        for env, out in zip(envs, rates):
            actions = rng.integers(0, env.action_space.n, per).tolist()
            t = time.perf_counter()
            for a in actions:
                _, _, terminated, truncated, _ = env.step(a)
                if terminated or truncated:
                    env.reset()
            if block:
                out.append(per / (time.perf_counter() - t))
    return float(np.median(rates[0])), float(np.median(rates[1]))


LIDAR_ROBOT = {"action": "continuous", "kinematics": "unicycle", "observation": "lidar", "lidar": {"beams": 64}}
"""The robot as real robots are driven (``--robots-kinds``): a unicycle given ``(v, ω)``, a 64-beam lidar."""


class OursVector:
    """``NavigateVectorEnv`` on fixed20, random starts and actions, stepped in blocks.

    ``robot``: the env's robot options (default: the thesis's robot, nine moves and the window;
    :data:`LIDAR_ROBOT`: a unicycle with continuous actions and the lidar, actions uniform in the box).
    """

    def __init__(self, num_envs: int, steps: int, robot: dict | None = None):
        self.env = NavigateVectorEnv(world="fixed20", num_envs=num_envs, starts="random", **(robot or {}))
        self.env.reset(seed=0)
        if robot and robot.get("action") == "continuous":
            self.actions = np.random.default_rng(0).uniform(-1, 1, (steps, num_envs, 2)).astype(np.float32)
        else:
            self.actions = np.random.default_rng(0).integers(0, 9, (steps, num_envs))
        for a in self.actions[:10]:   # warm up (proxies created, rows indexed)
            self.env.step(a)

    def run(self, block: slice) -> None:
        for a in self.actions[block]:
            self.env.step(a)

    def via_pymunk(self) -> float:
        """The share of robot-steps that go through pymunk (robots holding a proxy after a step)."""
        physics = self.env.task.stepper.physics
        simulated = 0
        for a in self.actions[:50]:
            self.env.step(a)
            simulated += int(physics.in_pymunk.sum())
        return simulated / (50 * self.env.num_envs)


class OursWithoutChipmunk(OursVector):
    """:class:`OursVector` with chipmunk's ``Space.step`` stubbed out while it runs (``--no-chipmunk``):
    robots sent to pymunk stay where they are and nothing touches, so its rate estimates
    everything of our step but chipmunk's own work (an estimate, not a physics)."""

    def run(self, block: slice) -> None:
        step = pymunk.Space.step
        pymunk.Space.step = lambda space, dt: None
        try:
            super().run(block)
        finally:
            pymunk.Space.step = step


class VmasVector:
    """VMAS's ``navigation`` scenario (CPU, one agent per env, continuous random actions, one torch thread).

    ``scenario``: the scenario's options (VMAS 1.5.2's ``navigation`` has a lidar whenever
    ``collisions`` is on, the default: ``n_lidar_rays=12``, ``lidar_range=0.35``, sensing other agents).
    """

    def __init__(self, num_envs: int, steps: int, **scenario):
        import torch
        import vmas

        torch.set_num_threads(1)
        self.env = vmas.make_env("navigation", num_envs=num_envs, device="cpu", continuous_actions=True, n_agents=1,
                                 seed=0, **scenario)
        self.env.reset()
        generator = torch.Generator().manual_seed(0)
        self.actions = [[torch.rand(num_envs, 2, generator=generator) * 2 - 1 for _ in self.env.agents]
                        for _ in range(steps)]
        for a in self.actions[:10]:
            self.env.step(a)

    def run(self, block: slice) -> None:
        for a in self.actions[block]:
            self.env.step(a)


FIXED20_BOXES = (
    # fixed20's three obstacles as VMAS boxes (centre x, y; length, width; rotation), in fixed20's units:
    # the funnel's two arms, the L's two legs, the quadrilateral
    (8.35, 10.85, 10.0, 1.2, 0.40), (10.85, 8.35, 10.0, 1.2, 1.17),
    (16.25, 2.75, 3.5, 1.5, 0.0), (17.25, 6.25, 1.5, 5.5, 0.0),
    (4.9, 16.4, 4.2, 3.4, -0.14),
)
"""fixed20's obstacles as box landmarks, for VMAS: the same world's work for both engines."""


def vmas_fixed20(num_envs: int, seed: int = 0):
    """VMAS's ``navigation`` scenario in fixed20: one agent (radius 0.25 of fixed20's 20 units) in a
    bounded square, among fixed20's obstacles as colliding box landmarks (:data:`FIXED20_BOXES`),
    scaled by 1/10 into VMAS's [-1, 1]."""
    import torch
    import vmas
    from vmas.scenarios.navigation import Scenario
    from vmas.simulator.core import Box, Landmark

    class Fixed20(Scenario):
        def make_world(self, batch_dim, device, **kwargs):
            world = super().make_world(batch_dim, device, n_agents=1, agent_radius=0.025, enforce_bounds=True,
                                       **kwargs)
            self.boxes = []
            for k, (x, y, length, width, angle) in enumerate(FIXED20_BOXES):
                box = Landmark(name=f"obstacle {k}", collide=True, shape=Box(length=length / 10, width=width / 10))
                box.placed = (x / 10 - 1.0, y / 10 - 1.0, angle)
                world.add_landmark(box)
                self.boxes.append(box)
            return world

        def reset_world_at(self, env_index=None):
            super().reset_world_at(env_index)
            for box in self.boxes:
                x, y, angle = box.placed
                box.set_pos(torch.tensor([x, y], device=self.world.device), batch_index=env_index)
                box.set_rot(torch.tensor([angle], device=self.world.device), batch_index=env_index)

    return vmas.make_env(Fixed20(), num_envs=num_envs, device="cpu", continuous_actions=True, seed=seed)


class VmasFixed20(VmasVector):
    """:func:`vmas_fixed20` stepped like :class:`VmasVector` (one torch thread, random actions)."""

    def __init__(self, num_envs: int, steps: int):
        import torch

        torch.set_num_threads(1)
        self.env = vmas_fixed20(num_envs)
        self.env.reset()
        generator = torch.Generator().manual_seed(0)
        self.actions = [[torch.rand(num_envs, 2, generator=generator) * 2 - 1 for _ in self.env.agents]
                        for _ in range(steps)]
        for a in self.actions[:10]:
            self.env.step(a)


def vector_rates(num_envs: int, steps: int, vmas: bool, block: int = 25, kinds: bool = False,
                 no_chipmunk: bool = False) -> dict:
    """Robot-steps per second of ours (and VMAS's), wall clock and CPU time of this process.

    The runners are stepped in alternating blocks of ``block`` steps, so that a machine whose load
    changes during the run slows all alike; the CPU-time rate is the steadier of the two on a
    shared machine (it does not count the time the process waits for a core). ``kinds`` adds
    our env with :data:`LIDAR_ROBOT` ("lidar") and, with ``vmas``, VMAS's navigation with a
    64-ray lidar ("vmas lidar64"). ``no_chipmunk`` adds :class:`OursWithoutChipmunk` ("no chipmunk").
    """
    runners = {"ours": OursVector(num_envs, steps)}
    if no_chipmunk:
        runners["no chipmunk"] = OursWithoutChipmunk(num_envs, steps)
    if kinds:
        runners["lidar"] = OursVector(num_envs, steps, LIDAR_ROBOT)
    if vmas:
        runners["vmas"] = VmasVector(num_envs, steps)
        runners["vmas fixed20"] = VmasFixed20(num_envs, steps)
        if kinds:
            runners["vmas lidar64"] = VmasVector(num_envs, steps, n_lidar_rays=64)
    wall = dict.fromkeys(runners, 0.0)
    cpu = dict.fromkeys(runners, 0.0)
    for first in range(0, steps, block):
        for name, runner in runners.items():
            w, c = time.perf_counter(), time.process_time()
            runner.run(slice(first, first + block))
            wall[name] += time.perf_counter() - w
            cpu[name] += time.process_time() - c
    out = {f"{name} wall": steps * num_envs / wall[name] for name in runners}
    out.update({f"{name} cpu": steps * num_envs / cpu[name] for name in runners})
    out["via pymunk"] = runners["ours"].via_pymunk()
    return out


def moving_world(frozen: bool):
    """fixed20 with 8 discs moving back and forth across it (or standing where they start)."""
    base = apf_physics.load_world("fixed20")
    rng = np.random.default_rng(0)
    discs = []
    for k in range(8):
        centre = np.array([2.0 + 2.0 * k, rng.uniform(3, 6)])
        motion = None if frozen else Motion(np.array([[0.0, 10.0]]), float(rng.uniform(0.15, 0.6)),
                                            phase=float(rng.uniform(0, 10)))
        discs.append(CircleObstacle(centre, 0.5, motion))
    return dataclasses.replace(base, obstacles=base.obstacles + tuple(discs))


def observation_cost(world, robots: int = 256, repeats: int = 200) -> float:
    """µs per robot of an observation (one Observer call for all robots, at varied steps)."""
    observer = Observer(ObserverConfig(), robots, [world])
    rng = np.random.default_rng(1)
    positions = world.random_free_positions(rng, robots)
    observer.reset(np.arange(robots), positions, [world] * robots)
    steps = rng.integers(0, 100, robots).astype(float)
    observer.observe(positions, t=steps)
    t = time.perf_counter()
    for k in range(repeats):
        observer.observe(positions, t=steps + k)
    return (time.perf_counter() - t) / (repeats * robots) * 1e6


def thin_walls(rng: np.random.Generator, count: int = 6):
    """A 20 × 20 world with ``count`` bars 0.005–0.1 thick at random angles."""
    obstacles = []
    for _ in range(count):
        c = rng.uniform(3, 17, 2)
        angle, length, width = rng.uniform(0, np.pi), rng.uniform(2, 6), rng.uniform(0.005, 0.1)
        u = np.array([np.cos(angle), np.sin(angle)])
        n = np.array([-u[1], u[0]])
        corners = [c - u * length / 2 - n * width / 2, c + u * length / 2 - n * width / 2,
                   c + u * length / 2 + n * width / 2, c - u * length / 2 + n * width / 2]
        obstacles.append({"polygon": np.clip(np.array(corners), 0.5, 19.5).tolist()})
    return apf_physics.world_from_dict({"size": [20, 20], "field": "thesis-fixed", "targets": [[19.5, 19.5]],
                                        "obstacles": obstacles})


def contacts_hold(robots_per_slot: int, slots: int, steps: int, seed: int = 0) -> dict:
    """Robot-steps that end too deep in an obstacle (> 0.01), in a robot (> 0.02), or through one.

    Every slot in a world of thin walls of its own; robots at random headings at speed 1 or √2,
    each heading held about ten steps. Overlaps are measured exactly (the world's clearance).
    """
    from apf_physics.sim.physics import Physics

    rng = np.random.default_rng(seed)
    worlds = [thin_walls(rng) for _ in range(slots)]
    physics = Physics(worlds, robots_per_slot=robots_per_slot)
    m = robots_per_slot
    for s, world in enumerate(worlds):
        physics.place(np.arange(s * m, (s + 1) * m), world.random_free_positions(rng, m))
    n = physics.num_robots
    heading = rng.uniform(0, 2 * np.pi, n)
    speed = rng.choice([1.0, np.sqrt(2)], n)
    counts = {"obstacle": 0, "robot": 0, "through": 0, "worst obstacle": 0.0, "worst robot": 0.0}
    elapsed = 0.0
    for _ in range(steps):
        change = rng.random(n) < 0.1
        heading[change] = rng.uniform(0, 2 * np.pi, int(change.sum()))
        before = physics.positions
        t = time.process_time()   # CPU time: steadier than the wall clock on a shared machine
        physics.step(np.column_stack([np.cos(heading), np.sin(heading)]) * speed[:, None])
        elapsed += time.process_time() - t
        after = physics.positions
        for s, world in enumerate(worlds):
            mine = slice(s * m, (s + 1) * m)
            inside = world.robot_radius - world.clearance(after[mine])
            counts["obstacle"] += int((inside > 0.01).sum())
            counts["worst obstacle"] = max(counts["worst obstacle"], float(inside.max()))
            if m > 1:
                a, b = after[mine], before[mine]
                d = np.hypot(*(a[:, None] - a[None]).transpose(2, 0, 1)) + np.eye(m) * 1e9
                overlap = 2 * world.robot_radius - d
                counts["robot"] += int((overlap.max(axis=1) > 0.02).sum())
                counts["worst robot"] = max(counts["worst robot"], float(overlap.max()))
                # a centre through another: the two straight paths of the step come within half a radius
                r0, dr = b[:, None] - b[None], (a - b)[:, None] - (a - b)[None]
                aa = np.sum(dr * dr, -1)
                u = np.clip(np.where(aa > 0, -np.sum(r0 * dr, -1) / np.where(aa > 0, aa, 1), 0), 0, 1)
                closest = np.hypot(*(r0 + u[..., None] * dr).transpose(2, 0, 1)) + np.eye(m) * 1e9
                counts["through"] += int((closest.min(axis=1) < 0.5 * world.robot_radius).sum())
    counts["robot-steps"] = n * steps
    counts["physics us/robot-step"] = elapsed / (n * steps) * 1e6
    return counts


def print_kinds(rows: list, vmas: bool) -> None:
    """The table of ``--robots-kinds``: robot-steps/s of each kind (wall clock), and ratios (wall, CPU)."""
    print("robots as real robots are driven (same runs, same blocks): NavigateVectorEnv on fixed20, the window "
          "env (nine moves, 11x11 window) beside a unicycle with continuous (v, w) and a 64-beam lidar "
          "(K + 5 = 69 values)" + (", and VMAS 'navigation' with its lidar of 12 rays (default) and of 64 rays "
                                   "(n_lidar_rays=64)" if vmas else ""))
    header = f"  {'N':>5} {'window env':>12} {'lidar env':>12} {'lidar/window':>13} {'(CPU time)':>11}"
    if vmas:
        header += f" {'VMAS 12 rays':>13} {'VMAS 64 rays':>13} {'lidar env/VMAS 64':>18} {'(CPU time)':>11}"
    print(header + "   (robot-steps/s; aim: lidar/window >= 0.5 at N = 1024)")
    for n, r in rows:
        line = (f"  {n:>5} {r['ours wall']:>12,.0f} {r['lidar wall']:>12,.0f} {r['lidar wall'] / r['ours wall']:>13.2f}"
                f" {r['lidar cpu'] / r['ours cpu']:>11.2f}")
        if vmas:
            line += (f" {r['vmas wall']:>13,.0f} {r['vmas lidar64 wall']:>13,.0f}"
                     f" {r['lidar wall'] / r['vmas lidar64 wall']:>18.2f}"
                     f" {r['lidar cpu'] / r['vmas lidar64 cpu']:>11.2f}")
        print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000, help="single-environment steps (default 20000)")
    parser.add_argument("--vmas", action="store_true", help="also run VMAS's navigation scenario (pip install vmas)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 256, 1024], help="numbers of environments")
    parser.add_argument("--vector-steps", type=int, default=300, help="vector steps per size (default 300)")
    parser.add_argument("--robots-kinds", action="store_true",
                        help="also step our vector env with a unicycle, continuous actions and a 64-beam lidar beside "
                             "the window env (and, with --vmas, VMAS's navigation with 64 lidar rays), and print "
                             "their rates and the ratio lidar env / window env")
    parser.add_argument("--no-chipmunk", action="store_true",
                        help="also step our vector env with chipmunk's Space.step stubbed out (nothing moves in "
                             "pymunk, nothing touches): an estimate of the rest of our step, beside VMAS with --vmas")
    parser.add_argument("--contacts", type=int, default=0, metavar="STEPS",
                        help="also count contacts that do not hold over STEPS steps of random crowds (e.g. 200)")
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    if args.contacts:
        print("contacts (thin walls, random headings held ~10 steps): robot-steps ending > 0.01 in an obstacle, "
              "> 0.02 in a robot, or through one")
        for m, slots in ((1, 256), (64, 4)):
            c = contacts_hold(m, slots, args.contacts)
            print(f"  {m:>2} robot(s) per slot x {slots:>3} slots, {c['robot-steps']:,} robot-steps: "
                  f"obstacle {c['obstacle']} (worst {c['worst obstacle']:.3f}), robot {c['robot']} "
                  f"(worst {c['worst robot']:.3f}), through {c['through']}; "
                  f"physics {c['physics us/robot-step']:.1f} us (CPU) per robot-step")
    cart, ours = single_rates(args.steps)
    print("single environment, random actions, through gymnasium.make (wrappers included; median of 10 "
          "alternating blocks, tools/bench_single.py for where the time goes)")
    print(f"  CartPole-v1                {cart:10.0f} steps/s   {1e6 / cart:7.1f} us/step")
    print(f"  apf_physics/Navigate-v0    {ours:10.0f} steps/s   {1e6 / ours:7.1f} us/step")
    print(f"  a Navigate step costs      {cart / ours:10.1f} x a CartPole step (aim <= 5)")
    header = f"  {'N':>5} {'ours robot-steps/s':>20} {'via pymunk':>11}"
    if args.vmas:
        header += (f" {'VMAS navigation':>17} {'ours / VMAS':>12} {'(CPU time)':>11}"
                   f" {'VMAS in fixed20':>16} {'ours / VMAS':>12} {'(CPU time)':>11}")
    print("vectorised: NavigateVectorEnv on fixed20 (random starts and actions)"
          + (" beside VMAS 'navigation' (CPU, 1 agent, 1 torch thread), in alternating blocks of 25 steps"
             if args.vmas else ""))
    print(header)
    kinds = []
    for n in args.sizes:
        r = vector_rates(n, args.vector_steps, args.vmas, kinds=args.robots_kinds, no_chipmunk=args.no_chipmunk)
        kinds.append((n, r))
        line = f"  {n:>5} {r['ours wall']:>20,.0f} {r['via pymunk']:>10.1%}"
        if args.vmas:
            line += (f" {r['vmas wall']:>17,.0f} {r['ours wall'] / r['vmas wall']:>12.2f}"
                     f" {r['ours cpu'] / r['vmas cpu']:>11.2f}"
                     f" {r['vmas fixed20 wall']:>16,.0f} {r['ours wall'] / r['vmas fixed20 wall']:>12.2f}"
                     f" {r['ours cpu'] / r['vmas fixed20 cpu']:>11.2f}")
        if args.no_chipmunk:
            line += f"   without chipmunk's stepping: {r['no chipmunk wall']:,.0f}"
            if args.vmas:
                line += f" ({r['no chipmunk wall'] / r['vmas wall']:.2f} x VMAS)"
        print(line)
    if args.robots_kinds:
        print_kinds(kinds, args.vmas)
    frozen, moving = observation_cost(moving_world(True)), observation_cost(moving_world(False))
    print("observations (256 robots, one call) in fixed20 with 8 discs")
    print(f"  discs frozen (in the static raster)     {frozen:7.2f} us/robot")
    print(f"  discs moving (added near where they are) {moving:7.2f} us/robot   {moving / frozen:5.2f} x (aim <= 2)")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
