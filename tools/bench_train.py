"""Benchmark: DQN from scratch on a world as ``apf-physics train`` runs it, where its time goes, and SB3's DQN beside it.

For each seed, trains the ``fast`` preset as it is (``--recipe fast``, the default: validated on
random free starts, stopped at its target or its step budget) or the ``40of40`` recipe (lattice
training starts, validated on the world's own starts, stopped at 100 % of them), with
``--set`` changes. It reports the steps and the time to the target, the env steps per second
(of the whole run, and of training alone: evaluations left out), where the time went
(stepping the environments, choosing the actions, storing transitions, the updates, the
evaluations) and ``best.pt`` on two fresh draws of 200 random free starts, shielded, as
``apf-physics eval --planner dqn --random-starts 200 --seed 1`` (and ``--seed 2``) measures
it. The clock is the trainer's: it starts at the first env step (the world and its
evaluation starts are loaded before).

Then (``--sb3``) trains Stable-Baselines3's DQN on the same vector env (``SB3VecEnv``), with
the same network (``WindowCNN``), training starts and the hyper-parameters SB3 has, for the
median training time of our runs (its evaluations on our validation starts, every 6,400
env steps, left out of that time), and measures its best model on the same fresh draws.
``--profile`` prints a torch profile of a short training run; ``--updates`` times one update of the
network computed four ways (its 2×2 convolutions as they are, in channels-last memory, by torch's
native convolution, and as four shifted slices and one matmul), side by side.

Usage::

    python tools/bench_train.py --world worlds/fixed20.yaml --seeds 0 1 2 [--sb3] [--recipe 40of40] [--set KEY=VALUE ...]
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
from apf_physics.models.files import load_model  # noqa: E402
from apf_physics.world.io.worldfile import load_world  # noqa: E402


RECIPES = {
    "fast": {},
    "40of40": dict(train_starts="lattice", eval_random_starts=0, select=("success",), target_success=1.0),
}
"""Changes to the ``fast`` preset per recipe: ``40of40`` is the time to all the world's starts."""


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


def bench_ours(world, seeds, overrides: dict) -> tuple[list[float], list[float]]:
    """Train each seed; returns their training seconds and env steps per second (evaluations left out)."""
    seconds, rates = [], []
    for seed in seeds:
        config = preset("fast", **{"seed": seed, **overrides})
        phases = phases_for_world(world, config)
        with tempfile.TemporaryDirectory() as out, Clock() as clock:
            result = train(config, phases, out_dir=out)
            best = load_model(Path(out) / "best.pt")
        c = result.counters
        training = c.wall_time - clock.seconds["evaluations"]
        reached = None if c.time_to_target is None else round(c.time_to_target, 1)
        draws = fresh_draws(world, best.network, best.observer)
        print(f"ours seed {seed}: {result.stop_reason} after {c.global_step} env steps and {c.wall_time:.1f} s "
              f"(the target at {reached} s), {result.updates} updates, {c.global_step / c.wall_time:.0f} env "
              f"steps/s ({c.global_step / training:.0f}/s without the evaluations); best.pt at step {c.best_step}: "
              f"validation {result.best['success']:.1%}, fresh draws 1 and 2: "
              + ", ".join(f"{s}/{n} ({k} collisions)" for s, k, n in draws), flush=True)
        parts = clock.seconds
        rest = c.wall_time - sum(parts.values())
        print("  where the time went: " + ", ".join(f"{name} {sec:.1f} s ({sec / c.wall_time:.0%})"
                                                   for name, sec in [*parts.items(), ("the rest", rest)]), flush=True)
        seconds.append(c.wall_time)
        rates.append(c.global_step / training)
    return seconds, rates


class _SB3Network(torch.nn.Module):
    """SB3's Q-network with the ``arch`` a :class:`~apf_physics.models.DQNPolicy` reads."""

    def __init__(self, q_net: torch.nn.Module, obs_shape: tuple[int, ...]):
        super().__init__()
        self.q_net = q_net
        self.arch = {"obs_shape": list(obs_shape)}

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.q_net(obs)


def fresh_draws(world, network, observer, draws=(1, 2), count: int = 200) -> list[tuple[int, int, int]]:
    """``(successes, collisions, episodes)`` of the shielded planner (``apf-physics eval --planner dqn``) on
    ``count`` random free starts drawn as ``apf-physics eval --random-starts COUNT --seed D`` draws them."""
    from apf_physics.cli.eval import random_starts
    from apf_physics.experiments.evaluate import evaluate
    from apf_physics.models.policy import DQNPolicy
    from apf_physics.planners.dqn import DQNPlanner

    out = []
    for draw in draws:
        planner = DQNPlanner(policy=DQNPolicy(network, observer), shield=True)
        episodes = evaluate(planner, [world], starts={world.name: random_starts(world, count, draw)}).episodes
        out.append((sum(e.success for e in episodes), sum(e.outcome == "collision" for e in episodes), len(episodes)))
    return out


def bench_sb3(world, seconds: float, seed: int, overrides: dict, eval_every: int = 6_400) -> None:
    """SB3's DQN on the same vector env, training starts, network and hyper-parameters as ours (where SB3 has
    them), for ``seconds`` of training; its network is evaluated on our validation starts every
    ``eval_every`` env steps (that time left out), the best kept, and then measured on the fresh draws."""
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback

    from apf_physics.envs.sb3 import SB3VecEnv, WindowCNN

    config = preset("fast", **{"seed": seed, **overrides})
    torch.set_num_threads(config.run.threads)
    phase = phases_for_world(world, config)[0]
    d, e = config.dqn, config.env
    starts = training_starts(world, e.train_starts, seed)  # the same training starts as ours
    vec = SB3VecEnv(world=world, num_envs=e.num_envs, starts=starts, observer=config.observer,
                    reward=e.reward_weights, max_episode_steps=e.max_episode_steps, reward_scale=d.reward_scale,
                    seed=seed)
    # ε decays over about as many env steps as ours takes to reach ε_f (measured in our run's train.csv)
    model = DQN("CnnPolicy", vec, learning_rate=config.network.learning_rate, buffer_size=d.buffer_size,
                learning_starts=d.learning_starts, batch_size=d.batch_size, tau=d.tau, gamma=d.gamma,
                train_freq=d.train_frequency, gradient_steps=d.gradient_steps, n_steps=d.n_step,
                target_update_interval=1, exploration_initial_eps=d.epsilon_initial,
                exploration_final_eps=d.epsilon_final, exploration_fraction=0.04,
                max_grad_norm=config.network.max_grad_norm, seed=seed, device="cpu",
                policy_kwargs=WindowCNN.policy_kwargs(filters=config.network.filters,
                                                      obs_transform=config.network.obs_transform))

    class Clocked(BaseCallback):
        def __init__(self):
            super().__init__()
            self.start = time.perf_counter()
            self.evaluating = 0.0   # seconds in our evaluator, left out of the training time
            self.next_eval, self.best, self.best_state = eval_every, -1.0, None

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:
                self.next_eval += eval_every
                t = time.perf_counter()
                network = _SB3Network(self.model.q_net, config.observer.shape)
                episodes = validation.run(network, config.observer, phase.validation, config.evaluation.eval_shield)
                success = validation.summarise(episodes, phase.validation)["success"]
                if success > self.best:
                    self.best = success
                    self.best_state = {k: v.clone() for k, v in self.model.q_net.state_dict().items()}
                self.evaluating += time.perf_counter() - t
            return time.perf_counter() - self.start - self.evaluating < seconds

    clock = Clocked()
    model.learn(total_timesteps=10**9, callback=clock)
    trained = time.perf_counter() - clock.start - clock.evaluating
    if clock.best_state is not None:
        model.q_net.load_state_dict(clock.best_state)
    draws = fresh_draws(world, _SB3Network(model.q_net, config.observer.shape).eval(), config.observer)
    print(f"SB3 DQN (the same {e.num_envs} envs in one SB3VecEnv, network, training starts and recipe: batch "
          f"{d.batch_size}, {d.gradient_steps} updates per vector step, {d.n_step}-step returns, lr "
          f"{config.network.learning_rate:g}): {trained:.1f} s of training, {model.num_timesteps} env steps "
          f"({model.num_timesteps / trained:.0f}/s), best validation {clock.best:.1%} of {phase.validation.starts}; "
          "that model on fresh draws 1 and 2: " + ", ".join(f"{s}/{n} ({c} collisions)" for s, c, n in draws),
          flush=True)


def _shifted_slices_forward(net, obs: torch.Tensor) -> torch.Tensor:
    """The window network's forward with each 2×2 convolution as four shifted slices, channels last, and one
    matmul, and the 2×2 stride-1 max-pool as a max of shifted views (the same values, summed in another order)."""
    import torch.nn.functional as F

    from apf_physics.models.network import relative_log

    def conv(x, weight, bias):   # x (N, H, W, C), weight (F, C, 2, 2)
        patches = torch.cat([x[:, :-1, :-1], x[:, :-1, 1:], x[:, 1:, :-1], x[:, 1:, 1:]], dim=-1)
        matrix = weight.permute(2, 3, 1, 0).reshape(-1, weight.shape[0])   # rows (dy, dx, c)
        out = torch.addmm(bias, patches.reshape(-1, patches.shape[-1]), matrix)
        return out.view(*patches.shape[:-1], weight.shape[0])

    def pool(x):
        cols = torch.maximum(x[:, :, :-1], x[:, :, 1:])
        return torch.maximum(cols[:, :-1], cols[:, 1:])

    x = relative_log(obs).permute(0, 2, 3, 1)
    for i, layer in enumerate(net.convs):
        x = F.leaky_relu(conv(x, layer.weight, layer.bias), net.negative_slope)
        if i < net.pooled_convs:
            x = pool(x)
    x = x.permute(0, 3, 1, 2).flatten(1)
    for layer in net.hidden:
        x = F.leaky_relu(layer(x), net.negative_slope)
    return net.head(x)


def bench_updates(overrides: dict, batches=(64, 128, 256), repeats: int = 5, updates: int = 40) -> None:
    """Milliseconds of one double-DQN update of the window network (three forward passes, a backward, Adam), as
    it is (oneDNN's 2×2 convolutions) and three other ways to compute the same network, interleaved in one
    process; the median of ``repeats`` blocks of ``updates`` updates, and the ratio to the first."""
    import copy

    import torch.nn.functional as F

    config = preset("fast", **overrides)
    torch.set_num_threads(config.run.threads)
    ways = {"as it is (oneDNN)": None, "channels-last memory": "channels_last", "native convolution": "native",
            "shifted slices + matmul": "slices"}
    for batch in batches:
        runs = {}
        for name, way in ways.items():
            torch.manual_seed(0)
            net = q_network(config)
            if way == "channels_last":
                net = net.to(memory_format=torch.channels_last)
            target = copy.deepcopy(net).requires_grad_(False)
            optimizer = torch.optim.Adam(net.parameters(), 1e-3, fused=True)
            obs, next_obs = (torch.randn(batch, *config.observer.shape) * 30 for _ in range(2))
            if way == "channels_last":
                obs, next_obs = (o.contiguous(memory_format=torch.channels_last) for o in (obs, next_obs))
            actions = torch.randint(0, 9, (batch, 1))
            forward = _shifted_slices_forward if way == "slices" else (lambda n, x: n(x))

            def update(net=net, target=target, optimizer=optimizer, obs=obs, next_obs=next_obs, actions=actions,
                       forward=forward):
                with torch.no_grad():
                    chosen = forward(net, next_obs).argmax(1, keepdim=True)
                    td = forward(target, next_obs).gather(1, chosen).squeeze(1)
                loss = F.smooth_l1_loss(forward(net, obs).gather(1, actions).squeeze(1), td)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
            runs[name] = (update, way == "native", [])
        for _ in range(repeats):
            for update, native, times in runs.values():
                with torch.backends.mkldnn.flags(enabled=not native):
                    for _ in range(5):
                        update()
                    t = time.perf_counter()
                    for _ in range(updates):
                        update()
                    times.append((time.perf_counter() - t) / updates * 1e3)
        base = statistics.median(runs["as it is (oneDNN)"][2])
        print(f"batch {batch}: " + ", ".join(f"{name} {statistics.median(times):.2f} ms "
                                             f"({statistics.median(times) / base:.2f}x)"
                                             for name, (_, _, times) in runs.items()), flush=True)


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
    parser.add_argument("--recipe", choices=list(RECIPES), default="fast",
                        help="fast (default): the preset as it is; 40of40: stop at 100%% of the world's starts")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="change a field of the recipe (as `apf-physics train --set`)")
    parser.add_argument("--sb3", action="store_true", help="also train Stable-Baselines3 DQN for the median time")
    parser.add_argument("--profile", action="store_true", help="profile a short training run instead")
    parser.add_argument("--updates", action="store_true",
                        help="time one update of the network computed four ways instead (convolutions as they are, "
                             "channels-last, native, shifted slices)")
    args = parser.parse_args()
    world = load_world(args.world)
    overrides = {**RECIPES[args.recipe], **parse_overrides(args.set)}
    if args.profile:
        profile(world, overrides)
        return
    if args.updates:
        print(f"load average at start: {os.getloadavg()[0]:.2f}", flush=True)
        bench_updates(overrides)
        print(f"load average at end: {os.getloadavg()[0]:.2f}")
        return
    print(f"load average at start: {os.getloadavg()[0]:.2f}; torch threads {preset('fast', **overrides).run.threads}; "
          f"recipe {args.recipe}: changes to fast: {overrides or 'none'}", flush=True)
    seconds, rates = bench_ours(world, args.seeds, overrides)
    median = statistics.median(seconds)
    print(f"ours: median training time over {len(seconds)} seeds {median:.1f} s (times "
          f"{[round(t, 1) for t in seconds]}); median {statistics.median(rates):.0f} env steps/s without the "
          "evaluations", flush=True)
    if args.sb3:
        print(f"load average before SB3: {os.getloadavg()[0]:.2f}", flush=True)
        bench_sb3(world, median, seed=args.seeds[0], overrides=overrides)
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
