"""Small bodies for the bridge's tests: a toy factory env with a 2-d design, and fake robots."""

from __future__ import annotations

import json
import os
import threading
import time

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit

from coadapt_bridge import RobotDriver, design_space

# How many envs make_toy built, and for which designs (tests read it in-process).
BUILDS: list = []


class ToyReacher(gymnasium.Env):
    """A point in the plane pushed by the action, scaled by the design (its 'leg lengths').
    Observation: position (2) and the design's first element; terminates far from the origin."""

    observation_space = spaces.Box(-np.inf, np.inf, (3,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    def __init__(self, design, gain: float = 1.0):
        self.design = np.asarray(design, dtype=np.float32)
        self.gain = gain
        self.x = np.zeros(2)

    def _obs(self):
        return np.array([self.x[0], self.x[1], self.design[0]], dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.np_random.uniform(-1.0, 1.0, size=2)
        return self._obs(), {}

    def step(self, action):
        self.x = self.x + 0.1 * self.gain * self.design * np.asarray(action, dtype=np.float64)
        dist = float(np.linalg.norm(self.x))
        return self._obs(), -dist, dist > 3.0, False, {}


@design_space(low=[0.5, 0.5], high=[2.0, 2.0], default=[1.0, 1.0])
def make_toy(design):
    BUILDS.append(np.asarray(design).tolist())
    return TimeLimit(ToyReacher(design), max_episode_steps=100)


# The designs and frictions make_toy_world built.
WORLD_BUILDS: list = []


@design_space(low=[0.5, 0.5], high=[2.0, 2.0], default=[1.0, 1.0])
def make_toy_world(design, friction=None):
    """make_toy with a world setting: the point's push is divided by ``friction``."""
    if friction is not None and not friction > 0:
        raise ValueError(f"friction must be > 0, got {friction}")
    WORLD_BUILDS.append((np.asarray(design).tolist(), friction))
    return TimeLimit(ToyReacher(design, gain=1.0 / (friction or 1.0)), max_episode_steps=100)


def make_discrete(design):
    return gymnasium.make("CartPole-v1")


class FakeDevice(RobotDriver):
    """A robot that records every call with its time."""

    action_low = [-1.0, -1.0]
    action_high = [1.0, 1.0]
    observation_size = 2
    max_action_rate_hz = float("inf")
    design_low = [0.1]
    design_high = [0.3]
    default_design = [0.2]

    def __init__(self, fail_safe_stop: bool = False, **declarations):
        super().__init__(**declarations)
        self.calls: list = []
        self.fail_safe_stop = fail_safe_stop
        self.lock = threading.Lock()
        self.pos = np.zeros(2, dtype=np.float32)

    def _record(self, name, value=None):
        with self.lock:
            self.calls.append((time.monotonic(), name, value))

    def names(self):
        with self.lock:
            return [c[1] for c in self.calls]

    def of(self, name):
        with self.lock:
            return [c for c in self.calls if c[1] == name]

    def reset(self, design):
        self._record("reset", np.asarray(design).tolist())
        self.pos = np.zeros(2, dtype=np.float32)
        return self.pos.copy()

    def step(self, action):
        self._record("step", np.asarray(action).tolist())
        self.pos = self.pos + action
        return self.pos.copy(), 1.0, False, False

    def safe_stop(self):
        self._record("safe_stop")
        if self.fail_safe_stop:
            raise RuntimeError("the fake robot's brake is stuck")

    def close(self):
        self._record("close")


class FileLoggingDevice(FakeDevice):
    """FakeDevice for a server in another process: appends each call to the file named by
    $COADAPT_FAKE_DEVICE_LOG (one JSON line per call)."""

    def _record(self, name, value=None):
        super()._record(name, value)
        with open(os.environ["COADAPT_FAKE_DEVICE_LOG"], "a") as f:
            f.write(json.dumps({"call": name, "value": value}) + "\n")
