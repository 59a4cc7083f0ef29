"""MuJoCo HalfCheetah-v5 through gymnasium: env steps per second with uniform random actions on one
core, the peer of `coadapt bench sim` (resets included, as in ours).

Like ours, the actions are drawn BEFORE the timed loop (4096 of them, cycled):
`env.action_space.sample()` inside the loop costs about 40 us a step, more than MuJoCo's step
itself, and timed the random number generator instead of the simulator.

usage: .venv-peers/bin/python bench/peers/sim_mujoco.py [--seconds 10]
prints: {"bench": "env_steps", "config": "half-cheetah", "value": ..., "unit": "steps/s", "impl": "mujoco"}
        {"bench": "sim_seconds", "config": "half-cheetah", "value": ..., "unit": "sim-s/s", "impl": "mujoco"}
"""
import argparse
import json
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

PREDRAWN_ACTIONS = 4096


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    env = gym.make("HalfCheetah-v5")
    env.reset(seed=0)
    space = env.action_space
    rng = np.random.default_rng(0)
    actions = rng.uniform(space.low, space.high, size=(PREDRAWN_ACTIONS, space.shape[0])).astype(space.dtype)
    n, t0 = 0, time.perf_counter()
    while True:
        _, _, term, trunc, _ = env.step(actions[n % PREDRAWN_ACTIONS])
        n += 1
        if term or trunc:
            env.reset()
        if n % 256 == 0 and time.perf_counter() - t0 >= args.seconds:
            break
    rate = n / (time.perf_counter() - t0)
    dt = env.unwrapped.dt  # 5 MuJoCo steps of 0.01 s
    for bench, value, unit in [("env_steps", rate, "steps/s"), ("sim_seconds", rate * dt, "sim-s/s")]:
        print(json.dumps({"bench": bench, "config": "half-cheetah", "value": round(value, 1), "unit": unit, "impl": "mujoco"}))


if __name__ == "__main__":
    main()
