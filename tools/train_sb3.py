"""Train Stable-Baselines3 SAC (or PPO) on ``apf_physics/Navigate-v0`` for a wall-clock budget, then evaluate.

    python tools/train_sb3.py --algo sac --world fixed20 --kinematics holonomic --observation lidar \\
        --minutes 20 --seed 0 --out /tmp/sac_fixed20
    python tools/train_sb3.py --eval-only /tmp/sac_fixed20/model.zip --world fixed20 --kinematics holonomic \\
        --observation lidar

Training: ``--envs`` copies of ``Navigate-v0`` in one :class:`NavigateVectorEnv` seen by SB3 through
:class:`apf_physics.envs.sb3.SB3VecEnv` (``--vector dummy``: SB3's ``make_vec_env``, a ``DummyVecEnv`` of single envs),
random starts (``starts="random"``), the robot given by ``--action`` (default: continuous for SAC,
discrete for PPO), ``--kinematics`` and ``--observation`` (lidar of ``--beams`` beams), the
env's reward preset ``--reward`` (``apf_physics/envs/reward.py``; default ``general``: on fixed20
SAC learned with ``thesis-fixed`` to circle in a well, where W4 pays nothing) with every reward multiplied by
``--reward-scale`` (SB3 sees the scaled reward; the env's own reward is unchanged), for
``--minutes`` of wall clock (or ``--steps`` env steps, whichever comes first). The model is
checkpointed to ``OUT/model.zip`` every ``--checkpoint-minutes`` and at the end, atomically
(written beside it, then renamed), with ``OUT/run.json`` (the options, steps, time).

Evaluation (also ``--eval-only MODEL``): the deterministic policy from each of the world's
own starts (``reset(options={"start": i})``) and from ``--random-starts`` random free starts (the
first episode of copy ``i`` of a vector env seeded ``eval_seed + i``: the start ``Navigate-v0``
draws at ``reset(seed=eval_seed + i)``); the step limit is the registration's (100, as in training).
Prints success / collision / timeout counts and writes them to ``OUT/eval.json``
(``--stochastic-too``: also of the stochastic policy, actions sampled, on the same starts).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import apf_physics  # noqa: E402,F401  (registers the ids)
from apf_physics.envs import NavigateVectorEnv  # noqa: E402
from apf_physics.envs.sb3 import SB3VecEnv  # noqa: E402

ENV_ID = "apf_physics/Navigate-v0"


def env_kwargs(args, starts: str = "random") -> dict:
    kwargs = dict(world=args.world, action=args.action, kinematics=args.kinematics, observation=args.observation,
                  reward=args.reward, starts=starts)
    if "lidar" in args.observation:
        kwargs["lidar"] = {"beams": args.beams, "max_range": args.max_range}
    return kwargs


class ScaleReward(gym.RewardWrapper):
    """The env's reward times a constant (the preset's ±1000 make large Q-values otherwise)."""

    def __init__(self, env, scale: float):
        super().__init__(env)
        self.scale = float(scale)

    def reward(self, reward):
        return reward * self.scale


def sb3_vec_env(args, starts: str = "random", seed: int = 0) -> SB3VecEnv:
    """``NavigateVectorEnv`` (``--envs`` copies in one batch) as an SB3 ``VecEnv``."""
    return SB3VecEnv(num_envs=args.envs, reward_scale=args.reward_scale, seed=seed, **env_kwargs(args, starts))


def atomic_save(model, path: Path) -> None:
    """``model.save`` to a file beside ``path``, then rename it over ``path``."""
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".zip", dir=path.parent)
    os.close(fd)
    try:
        model.save(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def atomic_json(data: dict, path: Path) -> None:
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=path.parent)
    with os.fdopen(fd, "w") as f:
        json.dump(data, f, indent=2)
    os.replace(tmp, path)


def policy_kwargs(args) -> dict:
    return {"net_arch": [args.hidden] * args.layers}


def make_model(args, env):
    import torch
    from stable_baselines3 import PPO, SAC

    policy = "MultiInputPolicy" if args.observation == "window+lidar" else "MlpPolicy"
    if args.algo == "sac":
        return SAC(policy, env, learning_rate=args.lr, buffer_size=args.buffer, batch_size=args.batch,
                   learning_starts=args.learning_starts, gamma=args.gamma, train_freq=1,
                   gradient_steps=args.gradient_steps, policy_kwargs=policy_kwargs(args), seed=args.seed,
                   device="cpu", verbose=0)
    return PPO(policy, env, learning_rate=args.lr, n_steps=args.n_steps, batch_size=args.batch, gamma=args.gamma,
               ent_coef=args.ent_coef, policy_kwargs=dict(policy_kwargs(args), activation_fn=torch.nn.Tanh),
               seed=args.seed, device="cpu", verbose=0)


def train(args) -> Path:
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.vector == "apf":
        env = sb3_vec_env(args, "random", args.seed)
    else:
        env = make_vec_env(ENV_ID, n_envs=args.envs, seed=args.seed, env_kwargs=env_kwargs(args, "random"),
                           wrapper_class=ScaleReward, wrapper_kwargs={"scale": args.reward_scale})
    model = make_model(args, env)
    model_path = out / "model.zip"
    started = time.perf_counter()
    deadline = started + args.minutes * 60
    record = {"options": vars(args), "env_kwargs": env_kwargs(args), "log": []}

    class Budget(BaseCallback):
        def __init__(self):
            super().__init__()
            self.next_save = started + args.checkpoint_minutes * 60
            self.next_log = started + 60
            self.episodes = {"success": 0, "collision": 0, "timeout": 0}

        def _on_step(self) -> bool:
            for info, done in zip(self.locals["infos"], self.locals["dones"]):
                if done:
                    kind = ("success" if info.get("success") else "collision" if info.get("collision")
                            else "timeout")
                    self.episodes[kind] += 1
            now = time.perf_counter()
            if now >= self.next_log:
                total = max(1, sum(self.episodes.values()))
                entry = {"minutes": round((now - started) / 60, 2), "steps": self.num_timesteps,
                         **{k: round(v / total, 3) for k, v in self.episodes.items()}, "episodes": total}
                record["log"].append(entry)
                print(f"  {entry['minutes']:6.1f} min {self.num_timesteps:>9,} steps  training episodes "
                      f"since last line: {total:>5}  success {entry['success']:.0%}  "
                      f"collision {entry['collision']:.0%}  timeout {entry['timeout']:.0%}", flush=True)
                self.episodes = dict.fromkeys(self.episodes, 0)
                self.next_log = now + 60
            if now >= self.next_save:
                atomic_save(self.model, model_path)
                self.next_save = now + args.checkpoint_minutes * 60
            return now < deadline

    print(f"training {args.algo.upper()} on {args.world} ({args.kinematics}, {args.action}, {args.observation}, "
          f"reward {args.reward} x {args.reward_scale:g}) for {args.minutes:g} min, {args.envs} envs, "
          f"seed {args.seed}; load average {os.getloadavg()[0]:.2f}", flush=True)
    model.learn(total_timesteps=args.steps, callback=Budget())
    elapsed = time.perf_counter() - started
    atomic_save(model, model_path)
    record.update(steps=int(model.num_timesteps), seconds=round(elapsed, 1),
                  steps_per_second=round(model.num_timesteps / elapsed, 1),
                  load_average_end=round(os.getloadavg()[0], 2))
    atomic_json(record, out / "run.json")
    print(f"trained {model.num_timesteps:,} env steps in {elapsed / 60:.1f} min "
          f"({model.num_timesteps / elapsed:.0f} steps/s); saved {model_path}", flush=True)
    env.close()
    return model_path


def run_episode(env, model, options: dict | None = None, seed: int | None = None,
                deterministic: bool = True) -> tuple[str, int, float]:
    """``(outcome, steps, path length)`` of one episode."""
    obs, info = env.reset(seed=seed, options=options)
    steps, length, position = 0, 0.0, info["position"]
    while True:
        action, _ = model.predict(obs, deterministic=deterministic)
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        length += float(np.hypot(*(info["position"] - position)))
        position = info["position"]
        if terminated or truncated:
            return ("success" if info["success"] else "collision" if info["collision"] else "timeout"), steps, length


def random_start_outcomes(args, model, deterministic: bool = True) -> dict:
    """Outcomes of the first episode of each of ``--random-starts`` copies of the vector env,
    copy ``i`` seeded ``eval_seed + i``: the start ``Navigate-v0`` draws at ``reset(seed=eval_seed + i)``."""
    env = NavigateVectorEnv(num_envs=args.random_starts, **env_kwargs(args, "random"))
    obs, _ = env.reset(seed=args.eval_seed)
    outcome = np.full(args.random_starts, "", dtype=object)
    while (outcome == "").any():
        action, _ = model.predict(obs, deterministic=deterministic)
        obs, _, terminated, truncated, info = env.step(action)
        for i in np.flatnonzero((terminated | truncated) & (outcome == "")).tolist():
            outcome[i] = ("success" if info["success"][i] else "collision" if info["collision"][i] else "timeout")
    return {k: int((outcome == k).sum()) for k in ("success", "collision", "timeout")}


def evaluate(args, model_path: str) -> dict:
    from stable_baselines3 import PPO, SAC

    cls = SAC if args.algo == "sac" else PPO
    model = cls.load(model_path, device="cpu")
    results = {}
    env = gym.make(ENV_ID, **env_kwargs(args, "world"))
    world = env.unwrapped.worlds[0]
    for deterministic in (True, False) if args.stochastic_too else (True,):
        policy = "" if deterministic else " (stochastic)"
        counts = dict.fromkeys(("success", "collision", "timeout"), 0)
        per_start, steps, lengths = [], [], []
        for i in range(len(world.starts)):
            outcome, n, length = run_episode(env, model, options={"start": i},
                                             seed=args.eval_seed if i == 0 else None, deterministic=deterministic)
            counts[outcome] += 1
            per_start.append(outcome)
            if outcome == "success":
                steps.append(n)
                lengths.append(length)
        results["world starts" + policy] = dict(
            episodes=len(world.starts), **counts, outcomes=per_start,
            mean_steps=round(float(np.mean(steps)), 2) if steps else None,
            mean_length=round(float(np.mean(lengths)), 2) if lengths else None)
        if args.random_starts > 0:
            counts = random_start_outcomes(args, model, deterministic)
            results[f"random starts (seed {args.eval_seed}+i)" + policy] = dict(episodes=args.random_starts, **counts)
    print(f"evaluation of {model_path} ({args.world}, {args.kinematics}, {args.action}, "
          f"{args.observation}, step limit 100)")
    for name, r in results.items():
        means = (f"  (successes: {r['mean_steps']} steps, path {r['mean_length']} on average)"
                 if r.get("mean_steps") else "")
        print(f"  {name:<42} {r['episodes']:>4} episodes: success {r['success']:>4}  "
              f"collision {r['collision']:>4}  timeout {r['timeout']:>4}{means}")
    return results


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=("sac", "ppo"), default="sac")
    parser.add_argument("--world", default="fixed20", help="world file or bundled name (default fixed20)")
    parser.add_argument("--action", choices=("discrete", "continuous"), default=None,
                        help="default: continuous for SAC, discrete for PPO")
    parser.add_argument("--kinematics", choices=("holonomic", "unicycle"), default="holonomic")
    parser.add_argument("--observation", choices=("window", "lidar", "window+lidar"), default="lidar")
    parser.add_argument("--beams", type=int, default=64, help="lidar beams (default 64)")
    parser.add_argument("--max-range", type=float, default=8.0, help="lidar range (default 8)")
    parser.add_argument("--reward", default="general",
                        help="reward preset of apf_physics/envs/reward.py (default general: Table 3's weights and "
                             "the revisit and length terms; thesis-fixed lets SAC learn to circle in a well)")
    parser.add_argument("--reward-scale", type=float, default=0.01, help="multiply rewards by this (default 0.01)")
    parser.add_argument("--minutes", type=float, default=20.0, help="wall-clock training budget (default 20)")
    parser.add_argument("--steps", type=int, default=10**9, help="env-step budget (default: the clock's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="/tmp/train_sb3", help="directory for model.zip, run.json, eval.json")
    parser.add_argument("--eval-only", metavar="MODEL", help="evaluate this model, do not train")
    parser.add_argument("--eval-seed", type=int, default=12345, help="seed of the random evaluation starts")
    parser.add_argument("--random-starts", type=int, default=200, help="random evaluation starts (default 200)")
    parser.add_argument("--stochastic-too", action="store_true",
                        help="also evaluate the stochastic policy (sampled actions) on the same starts")
    parser.add_argument("--checkpoint-minutes", type=float, default=2.0)
    parser.add_argument("--envs", type=int, default=16, help="env copies (default 16)")
    parser.add_argument("--vector", choices=("apf", "dummy"), default="apf",
                        help="apf: NavigateVectorEnv (one batch) adapted to SB3 (default); dummy: SB3's DummyVecEnv "
                             "of Navigate-v0 copies")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--hidden", type=int, default=256)
    parser.add_argument("--layers", type=int, default=2)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--gamma", type=float, default=0.99)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--buffer", type=int, default=300_000)
    parser.add_argument("--learning-starts", type=int, default=2000)
    parser.add_argument("--gradient-steps", type=int, default=4, help="SAC updates per vector step (default 4)")
    parser.add_argument("--n-steps", type=int, default=256, help="PPO rollout per env (default 256)")
    parser.add_argument("--ent-coef", type=float, default=0.01, help="PPO entropy bonus (default 0.01)")
    args = parser.parse_args(argv)
    if args.action is None:
        args.action = "continuous" if args.algo == "sac" else "discrete"
    if args.algo == "sac" and args.action != "continuous":
        parser.error("SAC needs --action continuous")
    model_path = args.eval_only or str(train(args))
    results = evaluate(args, model_path)
    if not args.eval_only:
        atomic_json({"model": model_path, "results": results}, Path(args.out) / "eval.json")


if __name__ == "__main__":
    main()
