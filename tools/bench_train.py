"""Benchmark: wall time of the ``fast`` DQN preset to 40/40 greedy successes, beside Stable-Baselines3.

For each seed, trains ``preset("fast")`` on the world until a greedy evaluation on the
world's starts succeeds from every start (or ``--budget`` seconds pass) and reports the
time. Then (``--sb3``) trains Stable-Baselines3's DQN on the same environment, with the
same network (a features extractor holding the thesis's convolutions and the same
observation transform), for the median of those times, and reports its env steps per
second and the best greedy success it reached. ``--profile`` prints a torch profile of a
short training run (where an update spends its time).

Usage::

    python tools/bench_train.py --world worlds/fixed20.yaml --seeds 0 1 2 --sb3
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import torch

from apf_physics import load_world
from apf_physics.rl.dqn import evaluate_greedy, navigate_env_factory, preset, train, training_starts


def bench_ours(world, seeds, budget: float, **overrides) -> tuple[list[float | None], list[float]]:
    times, rates = [], []
    for seed in seeds:
        config = preset("fast", seed=seed, total_steps=None, time_limit=budget, **overrides)
        with tempfile.TemporaryDirectory() as out:
            result = train(config, world, out_dir=out, progress=False)
        rate = result.global_step / result.wall_time
        print(f"ours seed {seed}: time to {result.best_eval_success:.0%}: "
              f"{result.time_to_target if result.time_to_target is None else round(result.time_to_target, 1)} s, "
              f"{result.global_step} env steps, {result.updates} updates, {rate:.0f} env steps/s", flush=True)
        times.append(result.time_to_target)
        rates.append(rate)
    return times, rates


def bench_sb3(world, seconds: float, seed: int, num_envs: int = 16, eval_every: int = 3_200) -> tuple[float, float]:
    import gymnasium as gym
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from apf_physics.envs import NavigateEnv

    config = preset("fast", seed=seed)
    torch.set_num_threads(config.threads)

    class ThesisExtractor(BaseFeaturesExtractor):
        """The thesis's convolutions and first 32-unit layer (SB3's CnnPolicy needs ≥ 36×36 images)."""

        def __init__(self, observation_space, features_dim: int = 32):
            super().__init__(observation_space, features_dim)
            net = config.network(obs_channels=observation_space.shape[0])
            self.net = net
            self.first = net.hidden[0]

        def forward(self, obs):
            from apf_physics.models.network import max_pool_2x2_stride1, relative_log
            import torch.nn.functional as F

            x = relative_log(obs)
            for i, conv in enumerate(self.net.convs):
                x = F.leaky_relu(conv(x), self.net.negative_slope)
                if i < self.net.pooled_convs:
                    x = max_pool_2x2_stride1(x)
            return F.leaky_relu(self.first(x.flatten(1)), self.net.negative_slope)

    starts = training_starts(world, config.train_starts, seed)  # the same training starts as ours

    def make():
        env = NavigateEnv(world=world, obs_size=config.obs_size, reward=config.reward, starts=starts)
        env = gym.wrappers.TimeLimit(env, config.max_episode_steps)
        return gym.wrappers.TransformReward(env, lambda r: r * config.reward_scale)

    vec = DummyVecEnv([make for _ in range(num_envs)])
    eval_envs = navigate_env_factory(world, num_envs=len(world.starts), seed=seed, starts=world.starts, config=config)
    model = DQN(
        "CnnPolicy", vec, learning_rate=config.learning_rate, buffer_size=config.buffer_size,
        learning_starts=config.learning_starts, batch_size=config.batch_size, tau=config.tau, gamma=config.gamma,
        # ε decays over the first 40,000 transitions, about where ours reaches ε_f
        train_freq=1, gradient_steps=1, target_update_interval=1, exploration_fraction=0.02,
        exploration_initial_eps=config.epsilon_initial, exploration_final_eps=config.epsilon_final,
        max_grad_norm=config.max_grad_norm, seed=seed, device="cpu",
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
                self.best = max(self.best, evaluate_greedy(self.model.q_net, eval_envs).success_rate)
            return time.perf_counter() - self.start < seconds and self.best < 1.0

    stop = Stop()
    model.learn(total_timesteps=2_000_000, callback=stop)
    elapsed = time.perf_counter() - stop.start
    print(f"SB3 DQN ({num_envs} envs, batch {config.batch_size}, same network and starts): {elapsed:.1f} s, "
          f"{model.num_timesteps} env steps ({model.num_timesteps / elapsed:.0f}/s), best greedy success {stop.best:.0%}")
    return model.num_timesteps / elapsed, stop.best


def profile(world, steps: int = 40_000) -> None:
    from torch.profiler import ProfilerActivity, profile as torch_profile

    config = preset("fast", total_steps=steps, eval_every=10**9, target_success=None)
    with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
        result = train(config, world, progress=False)
    print(f"{result.updates} updates in {result.wall_time:.1f} s "
          f"({result.wall_time / max(result.updates, 1) * 1e3:.1f} ms per vector step incl. acting and env)")
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=20))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--world", default="worlds/fixed20.yaml")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--budget", type=float, default=600, help="seconds per run before giving up (default 600)")
    parser.add_argument("--sb3", action="store_true", help="also train Stable-Baselines3 DQN for the median time")
    parser.add_argument("--profile", action="store_true", help="profile a short training run instead")
    args = parser.parse_args()
    world = load_world(args.world)
    if args.profile:
        profile(world)
        return
    import os

    print(f"load average at start: {os.getloadavg()[0]:.2f}; torch threads {preset('fast').threads}", flush=True)
    times, rates = bench_ours(world, args.seeds, args.budget)
    reached = [t for t in times if t is not None]
    if not reached:
        print("no run reached 100% within the budget")
        return
    median = statistics.median([t if t is not None else args.budget for t in times])
    print(f"ours: median time to 100% of the starts over {len(times)} seeds: {median:.1f} s "
          f"({len(reached)}/{len(times)} reached it; times {[None if t is None else round(t, 1) for t in times]})")
    if args.sb3:
        sb3_rate, sb3_best = bench_sb3(world, median, seed=args.seeds[0])
        ours_rate = statistics.median(rates)
        print(f"ratio: ours {ours_rate:.0f} env steps/s vs SB3 {sb3_rate:.0f} env steps/s = {ours_rate / sb3_rate:.1f}x; "
              f"in {median:.1f} s ours reached 100% (median seed), SB3 {sb3_best:.0%}")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
