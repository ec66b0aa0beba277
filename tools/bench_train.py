"""Benchmark: wall time of DQN from scratch to 40/40 greedy successes on a world, beside Stable-Baselines3.

For each seed, trains the ``40of40`` recipe (the ``fast`` preset with its earlier stop rule:
lattice training starts, validated on the world's own starts, stop at 100 % of them; the
measure of issue 25) or, with ``--recipe fast``, the ``fast`` preset as it is, until a greedy
evaluation (the DQN planner run through the physics, as ``apf-physics eval --planner
dqn-unshielded`` runs it) reaches the target or ``--budget`` seconds pass. It reports the
time, the env steps, the env steps per second (of the whole run, and of training alone:
evaluations left out), and where the time went: stepping the environments, choosing the
actions, storing transitions, the updates, the evaluations. The clock is the trainer's: it
starts at the first env step (the world and its evaluation labels are loaded before).

Then (``--sb3``) trains Stable-Baselines3's DQN on ``Navigate-v0`` (16 copies in a
``DummyVecEnv``) with the same network layers and observation transform, the same training
starts and hyper-parameters, for the env steps of the median of our runs, evaluated by the
same evaluator every 3,200 env steps (its evaluation time left out of its env steps/s), and
reports its env steps per second and the best greedy success it reached. ``--profile``
prints a torch profile of a short training run.

Usage::

    python tools/bench_train.py --world worlds/fixed20.yaml --seeds 0 1 2 [--sb3] [--recipe fast] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apf_physics.cli.train import parse_overrides  # noqa: E402
from apf_physics.learning import validation  # noqa: E402
from apf_physics.learning.config import preset  # noqa: E402
from apf_physics.learning.dqn import q_network  # noqa: E402
from apf_physics.learning.phases import phases_for_world, training_starts  # noqa: E402
from apf_physics.learning.trainer import train  # noqa: E402
from apf_physics.world.io.worldfile import load_world  # noqa: E402


RECIPES = {
    "40of40": dict(train_starts="lattice", eval_random_starts=0, select=("success",), target_success=1.0),
    "fast": {},
}
"""Changes to the ``fast`` preset per recipe: ``40of40`` is its stop rule before 2026-11-25."""


class Clock:
    """Seconds spent in a few functions of the training loop, by wrapping them for a run."""

    PARTS = (("environments", "apf_physics.learning.dqn", "TrainingEnvs", "step"),
             ("acting (network forward)", "apf_physics.learning.dqn", None, "epsilon_greedy"),
             ("storing transitions", "apf_physics.learning.buffer", "ReplayBuffer", "add"),
             ("updates", "apf_physics.learning.dqn", "QLearning", "update"),
             ("evaluations", "apf_physics.learning.trainer", None, "evaluate"))

    def __init__(self):
        self.seconds = {name: 0.0 for name, *_ in self.PARTS}
        self._undo = []

    def __enter__(self):
        import importlib
        for name, module, cls, attr in self.PARTS:
            owner = getattr(importlib.import_module(module), cls) if cls else importlib.import_module(module)
            original = getattr(owner, attr)
            setattr(owner, attr, self._timed(name, original))
            self._undo.append((owner, attr, original))
        return self

    def __exit__(self, *exc):
        for owner, attr, original in reversed(self._undo):
            setattr(owner, attr, original)

    def _timed(self, name, function):
        seconds = self.seconds

        def timed(*args, **kwargs):
            t = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                seconds[name] += time.perf_counter() - t
        return timed


def bench_ours(world, seeds, budget: float, overrides: dict) -> tuple[list[float | None], list[float], list[int]]:
    times, rates, steps = [], [], []
    for seed in seeds:
        config = preset("fast", **{"seed": seed, "total_steps": None, "time_limit": budget, **overrides})
        phases = phases_for_world(world, config)
        with tempfile.TemporaryDirectory() as out, Clock() as clock:
            result = train(config, phases, out_dir=out)
        c = result.counters
        rate = c.global_step / c.wall_time
        training = c.wall_time - clock.seconds["evaluations"]
        reached = None if c.time_to_target is None else round(c.time_to_target, 1)
        print(f"ours seed {seed}: time to {config.schedule.target_success:.0%}: {reached} s, "
              f"{c.global_step} env steps, "
              f"{result.updates} updates, {rate:.0f} env steps/s ({c.global_step / training:.0f}/s without the "
              f"evaluations); best evaluation {result.best['success']:.1%} at step {c.best_step}", flush=True)
        parts = clock.seconds
        rest = c.wall_time - sum(parts.values())
        print("  where the time went: " + ", ".join(f"{name} {sec:.1f} s ({sec / c.wall_time:.0%})"
                                                   for name, sec in [*parts.items(), ("the rest", rest)]), flush=True)
        times.append(c.time_to_target)
        rates.append(c.global_step / training)
        steps.append(c.global_step)
    return times, rates, steps


class _SB3Network(torch.nn.Module):
    """SB3's Q-network with the ``arch`` a :class:`~apf_physics.models.DQNPolicy` reads."""

    def __init__(self, q_net: torch.nn.Module, obs_shape: tuple[int, ...]):
        super().__init__()
        self.q_net = q_net
        self.arch = {"obs_shape": list(obs_shape)}

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.q_net(obs)


def bench_sb3(world, steps: int, seed: int, overrides: dict, num_envs: int = 16,
              eval_every: int = 3_200) -> tuple[float, float]:
    """SB3's DQN for ``steps`` env steps (or until 100 %); returns its env steps/s without the
    evaluations, and the best greedy success."""
    import gymnasium as gym
    import torch.nn.functional as F
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from apf_physics.envs import NavigateEnv
    from apf_physics.models.network import max_pool_2x2_stride1, relative_log

    config = preset("fast", **{"seed": seed, **overrides})
    torch.set_num_threads(config.run.threads)
    phase = phases_for_world(world, config)[0]

    class ThesisExtractor(BaseFeaturesExtractor):
        """The thesis's convolutions and first 32-unit layer (SB3's CnnPolicy needs ≥ 36×36 images)."""

        def __init__(self, observation_space, features_dim: int = 32):
            super().__init__(observation_space, features_dim)
            self.net = q_network(config)
            self.first = self.net.hidden[0]

        def forward(self, obs):
            x = relative_log(obs)
            for i, conv in enumerate(self.net.convs):
                x = F.leaky_relu(conv(x), self.net.negative_slope)
                if i < self.net.pooled_convs:
                    x = max_pool_2x2_stride1(x)
            return F.leaky_relu(self.first(x.flatten(1)), self.net.negative_slope)

    starts = training_starts(world, config.env.train_starts, seed)  # the same training starts as ours

    def make():
        env = NavigateEnv(world=world, observer=config.observer, reward=config.env.reward_weights, starts=starts)
        env = gym.wrappers.TimeLimit(env, config.env.max_episode_steps)
        return gym.wrappers.TransformReward(env, lambda r: r * config.dqn.reward_scale)

    vec = DummyVecEnv([make for _ in range(num_envs)])
    model = DQN(
        "CnnPolicy", vec, learning_rate=config.network.learning_rate, buffer_size=config.dqn.buffer_size,
        learning_starts=config.dqn.learning_starts, batch_size=config.dqn.batch_size, tau=config.dqn.tau, gamma=config.dqn.gamma,
        # ε decays over the first 40,000 transitions, about where ours reaches ε_f
        train_freq=1, gradient_steps=1, target_update_interval=1, exploration_fraction=0.02,
        exploration_initial_eps=config.dqn.epsilon_initial, exploration_final_eps=config.dqn.epsilon_final,
        max_grad_norm=config.network.max_grad_norm, seed=seed, device="cpu",
        policy_kwargs=dict(features_extractor_class=ThesisExtractor, net_arch=[32], normalize_images=False),
    )

    class Stop(BaseCallback):
        def __init__(self):
            super().__init__()
            self.start = time.perf_counter()
            self.best = 0.0
            self.next_eval = eval_every
            self.evaluating = 0.0   # seconds in our evaluator, left out of the rate

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:
                self.next_eval += eval_every
                t = time.perf_counter()
                network = _SB3Network(self.model.q_net, config.observer.shape)
                episodes = validation.run(network, config.observer, phase.validation, config.evaluation.eval_shield)
                self.best = max(self.best, validation.summarise(episodes, phase.validation)["success"])
                self.evaluating += time.perf_counter() - t
            return self.num_timesteps < steps and self.best < 1.0

    stop = Stop()
    model.learn(total_timesteps=2_000_000, callback=stop)
    elapsed = time.perf_counter() - stop.start
    rate = model.num_timesteps / (elapsed - stop.evaluating)
    print(f"SB3 DQN ({num_envs} envs, batch {config.dqn.batch_size}, same network, starts and recipe): "
          f"{elapsed:.1f} s, "
          f"{model.num_timesteps} env steps ({rate:.0f}/s without the evaluations, {stop.evaluating:.1f} s), "
          f"best greedy success {stop.best:.0%}", flush=True)
    return rate, stop.best


def profile(world, overrides: dict, steps: int = 40_000) -> None:
    from torch.profiler import ProfilerActivity, profile as torch_profile

    config = preset("fast", **{"total_steps": steps, "eval_every": 10**9, "target_success": None, **overrides})
    phases = phases_for_world(world, config)
    with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
        result = train(config, phases)
    print(f"{result.counters.vector_steps} vector steps, {result.updates} updates in {result.wall_time:.1f} s "
          f"({result.wall_time / max(result.counters.vector_steps, 1) * 1e3:.1f} ms per vector step incl. acting, "
          f"env and update)")
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=20))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--world", default="worlds/fixed20.yaml")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--budget", type=float, default=600, help="seconds per run before giving up (default 600)")
    parser.add_argument("--recipe", choices=sorted(RECIPES), default="40of40",
                        help="40of40 (default): stop at 100%% of the world's starts; fast: the preset as it is")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="change a field of the recipe (as `apf-physics train --set`)")
    parser.add_argument("--sb3", action="store_true", help="also train Stable-Baselines3 DQN for the median env steps")
    parser.add_argument("--profile", action="store_true", help="profile a short training run instead")
    args = parser.parse_args()
    world = load_world(args.world)
    overrides = {**RECIPES[args.recipe], **parse_overrides(args.set)}
    if args.profile:
        profile(world, overrides)
        return
    print(f"load average at start: {os.getloadavg()[0]:.2f}; torch threads {preset('fast', **overrides).run.threads}; "
          f"recipe {args.recipe}: changes to fast: {overrides or 'none'}", flush=True)
    times, rates, steps = bench_ours(world, args.seeds, args.budget, overrides)
    reached = [t for t in times if t is not None]
    median = statistics.median([t if t is not None else args.budget for t in times])
    ours_rate = statistics.median(rates)
    print(f"ours: median time to the target over {len(times)} seeds: {median:.1f} s "
          f"({len(reached)}/{len(times)} reached it; times {[None if t is None else round(t, 1) for t in times]}); "
          f"median {ours_rate:.0f} env steps/s without the evaluations", flush=True)
    if args.sb3:
        budget = int(statistics.median(steps))
        sb3_rate, sb3_best = bench_sb3(world, budget, seed=args.seeds[0], overrides=overrides)
        print(f"env steps/s (training, evaluations left out): ours {ours_rate:.0f} vs SB3 {sb3_rate:.0f} = "
              f"{ours_rate / sb3_rate:.1f}x; in {budget} env steps (our median run) SB3 reached {sb3_best:.0%}")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
