"""Environments that misbehave on cue, served by coadapt-gym-serve in cli/tests/env_rpc.rs.

Each factory builds a 50-step toy robot with HalfCheetah's design box ([0.8, 2.0]^6, so the
tiny co-adaptation config runs on it). Counters are per server process: `nan_once` sends a NaN
observation at step 10 of the second episode that gets that far (connections that only read
the specs start episodes too), `stall_once` stops answering for 3 s there instead,
`wrong_shape` always sends 4 values where 3 are declared.
"""
import time

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit

from coadapt_bridge import design_space

REACHED_10 = {"count": 0}


class Toy(gymnasium.Env):
    observation_space = spaces.Box(-np.inf, np.inf, (3,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    def __init__(self, design, fault):
        self.design = np.asarray(design, dtype=np.float32)
        self.fault = fault
        self.x = np.zeros(2)
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.np_random.uniform(-1.0, 1.0, size=2)
        self.t = 0
        return self._obs(), {}

    def _obs(self):
        return np.array([self.x[0], self.x[1], self.design[0]], dtype=np.float32)

    def step(self, action):
        self.t += 1
        self.x = self.x + 0.1 * self.design[:2] * np.asarray(action, dtype=np.float64)
        obs = self._obs()
        if self.t == 10:
            REACHED_10["count"] += 1
            if REACHED_10["count"] == 2 and self.fault == "nan":
                obs[0] = np.nan
            if REACHED_10["count"] == 2 and self.fault == "stall":
                time.sleep(3.0)
        if self.t == 3 and self.fault == "shape":
            obs = np.zeros(4, dtype=np.float32)
        return obs, -float(np.linalg.norm(self.x)), False, False, {}


def _factory(fault):
    @design_space(low=[0.8] * 6, high=[2.0] * 6, default=[1.0] * 6)
    def make(design):
        return TimeLimit(Toy(design, fault), max_episode_steps=50)

    return make


nan_once = _factory("nan")
stall_once = _factory("stall")
wrong_shape = _factory("shape")
