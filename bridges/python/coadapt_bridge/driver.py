"""``RobotDriver``: the base class of a real robot served by ``coadapt-gym-serve --driver``.

A driver is the thin layer that talks to hardware: it moves the robot to a start pose and
reads its state (``reset``), applies one action and reads the result (``step``), and brings the
robot to a safe standstill (``safe_stop``). Everything else is the bridge's job, including the
safety rules, which the bridge enforces itself rather than trusting the driver to:

* every action is checked against the declared action box at the protocol level (a request
  outside it is refused with an error and never reaches the driver), then clipped to
  ``[action_low, action_high]`` and, when ``max_action_change`` is declared, to within that
  much of the previous action, before ``step`` sees it;
* actions are forwarded at most ``max_action_rate_hz`` times per second: a request that comes
  sooner waits in the bridge;
* ``safe_stop()`` is called when no StepRequest arrives within the step timeout
  (``--step-timeout``, default 1 s) after a step (the running episode is then cut: the next
  step answers ``INTERRUPTED`` and the one after starts a new episode with ``reset``), when
  the client's connection is lost or its stream cancelled, when the agent leaves the world or
  the world is destroyed, and when the server stops (Ctrl-C, SIGTERM). Exceptions from
  ``safe_stop`` are logged and never stop the server.

Calls into a driver never overlap: ``reset``, ``step``, ``safe_stop`` and ``close`` are made
one at a time (from the server's threads, not always the same one). ``safe_stop`` may be called
several times in a row and at any moment, also before the first ``reset``: make it idempotent.

Declaring the robot (class attributes, or the same names as keyword arguments to
``RobotDriver.__init__``)::

    class MyArm(RobotDriver):
        action_low = [-1.0, -1.0]        # the action box, one entry per actuator (required)
        action_high = [1.0, 1.0]
        observation_size = 6             # length of the observation vector (required)
        max_action_rate_hz = 50.0        # at most this many actions per second (required)
        max_action_change = 0.2          # optional: per-step limit |a_t - a_{t-1}| (scalar or per actuator)
        rest_action = [0.0, 0.0]         # optional: the first action of an episode is limited relative to it
        design_low = [0.1]               # optional design box (the body's adjustable parameters)
        design_high = [0.3]
        default_design = [0.2]

The bridge instantiates the class once, with no arguments, when the server starts (so a
robot that cannot be reached fails at start), and serves one world at a time with it.
See ``examples/robot_driver_template.py`` for a template to copy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional, Sequence, Tuple

import numpy as np

from .design import DesignSpace

StepResult = Tuple[np.ndarray, float, bool, bool]


class RobotDriver:
    """Base class of a robot driver. Override ``reset``, ``step`` and ``safe_stop``
    (and ``close`` when the connection to the robot must be released)."""

    #: Lower bounds of the action box, one per actuator. Required.
    action_low: Optional[Sequence[float]] = None
    #: Upper bounds of the action box. Required.
    action_high: Optional[Sequence[float]] = None
    #: Length of the observation vector ``reset`` and ``step`` return. Required.
    observation_size: Optional[int] = None
    #: The largest number of actions per second the robot may receive. Required
    #: (``math.inf`` explicitly disables the limit).
    max_action_rate_hz: Optional[float] = None
    #: Optional per-step limit on the change of each action element (scalar or one per
    #: actuator): the bridge clips ``a_t`` to ``[a_{t-1} - d, a_{t-1} + d]``.
    max_action_change: Optional[Any] = None
    #: Optional action the robot holds at rest: the change limit of an episode's first action
    #: is taken relative to it (without it the first action is only clipped to the box).
    rest_action: Optional[Sequence[float]] = None
    #: Optional design box (the adjustable body), as with ``coadapt_bridge.design_space``.
    design_low: Optional[Sequence[float]] = None
    design_high: Optional[Sequence[float]] = None
    default_design: Optional[Sequence[float]] = None

    def __init__(self, **declarations: Any) -> None:
        """Keyword arguments override the class attributes of the same names."""
        known = {
            "action_low", "action_high", "observation_size", "max_action_rate_hz", "max_action_change",
            "rest_action", "design_low", "design_high", "default_design",
        }
        for key, value in declarations.items():
            if key not in known:
                raise TypeError(f"RobotDriver: unknown declaration `{key}` (known: {', '.join(sorted(known))})")
            setattr(self, key, value)

    def reset(self, design: np.ndarray) -> np.ndarray:
        """Start an episode: build or adjust the body to ``design`` (float32, shape ``[D]``,
        inside the design box; empty without a design box), bring the robot to its start
        pose, and return the first observation (``observation_size`` floats)."""
        raise NotImplementedError

    def step(self, action: np.ndarray) -> StepResult:
        """Apply ``action`` (float32, shape ``[A]``, already inside the box and rate
        limited), wait for the control period if the robot needs it, and return
        ``(observation, reward, terminated, truncated)``: ``terminated`` for a true end (a
        fall, a collision: discount 0), ``truncated`` for an end that is not the robot's
        doing (a time limit: the learner bootstraps through it). When an episode ends the
        robot should be left safe; ``safe_stop`` follows anyway if the client goes quiet."""
        raise NotImplementedError

    def safe_stop(self) -> None:
        """Bring the robot to a safe standstill now (zero torque, brakes, hold position...).
        Must be idempotent and must not block for long."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the robot (called once when the server stops, after ``safe_stop``)."""


@dataclass(frozen=True)
class DriverDeclaration:
    """A driver's declarations, checked and as float32 arrays."""

    action_low: np.ndarray
    action_high: np.ndarray
    observation_size: int
    max_action_rate_hz: float
    max_action_change: Optional[np.ndarray]
    rest_action: Optional[np.ndarray]
    design: DesignSpace

    @property
    def action_dim(self) -> int:
        return int(self.action_low.shape[0])

    @staticmethod
    def of(driver: Any) -> "DriverDeclaration":
        what = f"driver {type(driver).__name__}"
        for method in ("reset", "step", "safe_stop"):
            fn = getattr(driver, method, None)
            if not callable(fn):
                raise ValueError(f"{what} has no `{method}()` method")
            if getattr(type(driver), method, None) is getattr(RobotDriver, method, object()):
                raise ValueError(f"{what} does not implement `{method}()` (RobotDriver's raises NotImplementedError)")

        def vector(name: str, value: Any) -> np.ndarray:
            if value is None:
                raise ValueError(f"{what} does not declare `{name}`")
            arr = np.asarray(value, dtype=np.float64)
            if arr.ndim != 1 or arr.size == 0:
                raise ValueError(f"{what}: `{name}` must be a non-empty list of numbers, got shape {list(arr.shape)}")
            if not np.all(np.isfinite(arr.astype(np.float32))):
                raise ValueError(f"{what}: `{name}` must be finite float32 values, got {arr.tolist()}")
            return arr.astype(np.float32)

        low = vector("action_low", getattr(driver, "action_low", None))
        high = vector("action_high", getattr(driver, "action_high", None))
        if low.shape != high.shape:
            raise ValueError(f"{what}: `action_low` has {low.size} elements but `action_high` has {high.size}")
        if np.any(low >= high):
            i = int(np.flatnonzero(low >= high)[0])
            raise ValueError(f"{what}: action_low[{i}] = {low[i]} is not below action_high[{i}] = {high[i]}")

        size = getattr(driver, "observation_size", None)
        if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 0:
            raise ValueError(f"{what}: `observation_size` must be a non-negative integer, got {size!r}")

        rate = getattr(driver, "max_action_rate_hz", None)
        if rate is None:
            raise ValueError(f"{what} does not declare `max_action_rate_hz` (use math.inf to allow any rate)")
        rate = float(rate)
        if not rate > 0 or math.isnan(rate):
            raise ValueError(f"{what}: `max_action_rate_hz` must be positive, got {rate}")

        change = getattr(driver, "max_action_change", None)
        change_arr = None
        if change is not None:
            change_arr = np.broadcast_to(np.asarray(change, dtype=np.float32), low.shape).copy()
            if not np.all(change_arr > 0):
                raise ValueError(f"{what}: `max_action_change` must be positive, got {np.asarray(change).tolist()}")

        rest = getattr(driver, "rest_action", None)
        rest_arr = None
        if rest is not None:
            rest_arr = vector("rest_action", rest)
            if rest_arr.shape != low.shape or np.any(rest_arr < low) or np.any(rest_arr > high):
                raise ValueError(f"{what}: `rest_action` {rest_arr.tolist()} is not inside the action box")

        design = DesignSpace.of(driver, what)
        return DriverDeclaration(low, high, int(size), rate, change_arr, rest_arr, design)
