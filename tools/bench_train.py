"""Benchmark: wall time of the ``fast`` DQN preset from scratch to 40/40 greedy successes, beside Stable-Baselines3.

For each seed, trains ``preset("fast")`` on the world until a greedy evaluation (the DQN
planner run through the physics, unshielded, as ``apf-physics eval --planner dqn-unshielded``
runs it) succeeds from every start of the world, or ``--budget`` seconds pass, and reports
the time, the env steps and env steps per second. The clock is the trainer's: it starts at
the first env step (the world and its evaluation labels are loaded before). Then
(``--sb3``) trains Stable-Baselines3's DQN on the same environment, with the same network
layers and observation transform and the same training starts, for the median of those
times, evaluated with the same evaluator, and reports its env steps per second and the best
greedy success it reached. ``--profile`` prints a torch profile of a short training run.

Usage::

    python tools/bench_train.py --world worlds/fixed20.yaml --seeds 0 1 2 [--sb3] [--set KEY=VALUE ...]
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

from apf_physics.commands.train import parse_overrides  # noqa: E402
from apf_physics.rl import evaluation  # noqa: E402
from apf_physics.rl.config import preset  # noqa: E402
from apf_physics.rl.dqn import q_network  # noqa: E402
from apf_physics.rl.phases import phases_for_world, training_starts  # noqa: E402
from apf_physics.rl.trainer import train  # noqa: E402
from apf_physics.worldfile import load_world  # noqa: E402


def bench_ours(world, seeds, budget: float, overrides: dict) -> tuple[list[float | None], list[float]]:
    times, rates = [], []
    for seed in seeds:
        config = preset("fast", **{"seed": seed, "total_steps": None, "time_limit": budget, **overrides})
        phases = phases_for_world(world, config)
        with tempfile.TemporaryDirectory() as out:
            result = train(config, phases, out_dir=out)
        c = result.counters
        rate = c.global_step / c.wall_time
        reached = None if c.time_to_target is None else round(c.time_to_target, 1)
        print(f"ours seed {seed}: time to {config.schedule.target_success:.0%}: {reached} s, {c.global_step} env steps, "
              f"{result.updates} updates, {rate:.0f} env steps/s; best evaluation {result.best['success']:.1%} "
              f"at step {c.best_step}", flush=True)
        times.append(c.time_to_target)
        rates.append(rate)
    return times, rates


class _SB3Network(torch.nn.Module):
    """SB3's Q-network with the ``arch`` a :class:`~apf_physics.models.DQNPolicy` reads."""

    def __init__(self, q_net: torch.nn.Module, obs_shape: tuple[int, ...]):
        super().__init__()
        self.q_net = q_net
        self.arch = {"obs_shape": list(obs_shape)}

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.q_net(obs)


def bench_sb3(world, seconds: float, seed: int, num_envs: int = 16, eval_every: int = 3_200) -> tuple[float, float]:
    import gymnasium as gym
    import torch.nn.functional as F
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from apf_physics.envs import NavigateEnv
    from apf_physics.models.network import max_pool_2x2_stride1, relative_log

    config = preset("fast", seed=seed)
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

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:
                self.next_eval += eval_every
                network = _SB3Network(self.model.q_net, config.observer.shape)
                episodes = evaluation.run(network, config.observer, phase.validation, config.evaluation.eval_shield)
                self.best = max(self.best, evaluation.summarise(episodes, phase.validation)["success"])
            return time.perf_counter() - self.start < seconds and self.best < 1.0

    stop = Stop()
    model.learn(total_timesteps=2_000_000, callback=stop)
    elapsed = time.perf_counter() - stop.start
    print(f"SB3 DQN ({num_envs} envs, batch {config.dqn.batch_size}, same network and starts): {elapsed:.1f} s, "
          f"{model.num_timesteps} env steps ({model.num_timesteps / elapsed:.0f}/s), best greedy success {stop.best:.0%}")
    return model.num_timesteps / elapsed, stop.best


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
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="change a field of the fast preset (as `apf-physics train --set`)")
    parser.add_argument("--sb3", action="store_true", help="also train Stable-Baselines3 DQN for the median time")
    parser.add_argument("--profile", action="store_true", help="profile a short training run instead")
    args = parser.parse_args()
    world = load_world(args.world)
    overrides = parse_overrides(args.set)
    if args.profile:
        profile(world, overrides)
        return
    print(f"load average at start: {os.getloadavg()[0]:.2f}; torch threads {preset('fast', **overrides).threads}; "
          f"changes to fast: {overrides or 'none'}", flush=True)
    times, rates = bench_ours(world, args.seeds, args.budget, overrides)
    reached = [t for t in times if t is not None]
    median = statistics.median([t if t is not None else args.budget for t in times])
    print(f"ours: median time to 100% of the starts over {len(times)} seeds: {median:.1f} s "
          f"({len(reached)}/{len(times)} reached it; times {[None if t is None else round(t, 1) for t in times]}); "
          f"median {statistics.median(rates):.0f} env steps/s")
    if args.sb3 and reached:
        sb3_rate, sb3_best = bench_sb3(world, median, seed=args.seeds[0])
        ours_rate = statistics.median(rates)
        print(f"ratio: ours {ours_rate:.0f} env steps/s vs SB3 {sb3_rate:.0f} env steps/s = {ours_rate / sb3_rate:.1f}x; "
              f"in {median:.1f} s ours reached 100% (median seed), SB3 {sb3_best:.0%}")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
