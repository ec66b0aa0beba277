"""Benchmark the environments: Navigate-v0 beside CartPole-v1, and the vectorised env.

    python tools/bench_env.py [--steps 20000]

Prints steps per second of ``apf_physics/Navigate-v0`` (through ``gymnasium.make``, random
actions) beside Gymnasium's ``CartPole-v1`` run the same way in the same process, their
ratio, and robot-steps per second of ``NavigateVectorEnv`` at N = 64 and 256.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import apf_physics  # noqa: F401
from apf_physics.envs import NavigateVectorEnv

FIXED20 = Path(__file__).resolve().parent.parent / "worlds" / "fixed20.yaml"


def single_rate(env_id: str, steps: int, **kwargs) -> float:
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, env.action_space.n, steps)
    t = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(int(a))
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t)


def vector_rate(num_envs: int, steps: int) -> float:
    env = NavigateVectorEnv(world=str(FIXED20), num_envs=num_envs, starts="random")
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 9, (steps, num_envs))
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    return steps * num_envs / (time.perf_counter() - t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    args = parser.parse_args()
    cart = single_rate("CartPole-v1", args.steps)
    ours = single_rate("apf_physics/Navigate-v0", args.steps, world=str(FIXED20))
    print("single environment, random actions, through gymnasium.make (wrappers included)")
    print(f"  CartPole-v1                {cart:10.0f} steps/s   {1e6 / cart:7.1f} us/step")
    print(f"  apf_physics/Navigate-v0    {ours:10.0f} steps/s   {1e6 / ours:7.1f} us/step")
    print(f"  a Navigate step costs      {cart / ours:10.1f} x a CartPole step")
    print("vectorised (NavigateVectorEnv, fixed20, random starts and actions)")
    for n in (64, 256):
        rate = vector_rate(n, max(50, args.steps // n))
        print(f"  N = {n:<4}                   {rate:10.0f} robot-steps/s")


if __name__ == "__main__":
    main()
