"""MuJoCo HalfCheetah-v5 through gymnasium: env steps per second with uniform random actions on one
core, the peer of `coadapt bench sim` (resets included, as in ours).

usage: .venv-peers/bin/python bench/peers/sim_mujoco.py [--seconds 10]
prints: {"bench": "env_steps", "config": "half-cheetah", "value": ..., "unit": "steps/s", "impl": "mujoco"}
"""
import argparse
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
import gymnasium as gym  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    env = gym.make("HalfCheetah-v5")
    env.reset(seed=0)
    env.action_space.seed(0)
    n, t0 = 0, time.perf_counter()
    while True:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        n += 1
        if term or trunc:
            env.reset()
        if n % 256 == 0 and time.perf_counter() - t0 >= args.seconds:
            break
    rate = n / (time.perf_counter() - t0)
    print(json.dumps({"bench": "env_steps", "config": "half-cheetah", "value": round(rate), "unit": "steps/s", "impl": "mujoco"}))


if __name__ == "__main__":
    main()
