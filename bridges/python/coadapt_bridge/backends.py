"""What a world runs: a gymnasium environment (``--env``, ``--factory``) or a robot driver
(``--driver``), behind one small interface (``Body``), with the profile they publish.
"""

from __future__ import annotations

import importlib
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np

from .design import DesignSpace
from .driver import DriverDeclaration, StepResult

log = logging.getLogger("coadapt_bridge")


class BackendError(ValueError):
    """An environment, factory or driver that cannot be served (the message says why)."""


class RobotBusy(RuntimeError):
    """The robot already serves a world."""


class ShuttingDown(RuntimeError):
    """The server is stopping."""


@dataclass(frozen=True)
class Profile:
    """What the specs publish: action box, state width (and its bounds if finite), design box."""

    action_low: np.ndarray
    action_high: np.ndarray
    obs_dim: int
    obs_low: Optional[np.ndarray]
    obs_high: Optional[np.ndarray]
    design: DesignSpace

    @property
    def action_dim(self) -> int:
        return int(self.action_low.shape[0])

    def same_spaces(self, other: "Profile") -> bool:
        return (
            self.obs_dim == other.obs_dim
            and np.array_equal(self.action_low, other.action_low)
            and np.array_equal(self.action_high, other.action_high)
        )

    def describe(self) -> str:
        return (
            f"action [{self.action_dim}] in [{self.action_low.tolist()}, {self.action_high.tolist()}], "
            f"observation [{self.obs_dim}], design [{self.design.dim}]"
        )


class Body:
    """One world's robot or simulator."""

    profile: Profile
    is_robot = False

    def start_episode(self, design: np.ndarray, seed: Optional[int]) -> np.ndarray:
        raise NotImplementedError

    def step(self, action: np.ndarray) -> StepResult:
        raise NotImplementedError

    def close(self) -> None:
        pass


class Backend:
    """Makes the bodies of the worlds."""

    profile: Profile
    is_robot = False
    #: World settings beyond ``design`` and ``seed`` that CreateWorld may give (a scalar each,
    #: e.g. ``friction``), as the client names them; each becomes a keyword argument of the
    #: body's construction (``-`` read as ``_``).
    world_settings: frozenset = frozenset()

    def new_body(self, design: np.ndarray, world: Optional[dict] = None) -> Body:
        raise NotImplementedError

    def close(self) -> None:
        pass


# ---------------------------------------------------------------------------------------------
# gymnasium


def load_attr(spec: str, what: str) -> Any:
    """``module:attribute`` (attribute may be dotted) -> the object."""
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise BackendError(f"{what} `{spec}`: expected module:name (e.g. my_robots:make_walker)")
    try:
        obj: Any = importlib.import_module(module_name)
    except Exception as e:  # noqa: BLE001 - anything an import raises
        raise BackendError(f"{what} `{spec}`: cannot import module `{module_name}`: {type(e).__name__}: {e}") from e
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise BackendError(f"{what} `{spec}`: module `{module_name}` has no `{attr}`") from None
    return obj


def gym_profile(env: Any, design: DesignSpace, what: str) -> Profile:
    """The profile of a gymnasium env: continuous Box actions only; observations flattened."""
    from gymnasium import spaces

    act = env.action_space
    if not isinstance(act, spaces.Box):
        raise BackendError(
            f"{what}: action space {act} is not a continuous Box; the coadapt profile serves continuous "
            "actions only (a FLOAT `action` with min/max)"
        )
    if not np.issubdtype(act.dtype, np.floating):
        raise BackendError(f"{what}: action space {act} has dtype {act.dtype}; a floating-point Box is required")
    low = np.asarray(act.low, dtype=np.float32).ravel()
    high = np.asarray(act.high, dtype=np.float32).ravel()
    if low.size == 0:
        raise BackendError(f"{what}: action space {act} is empty")
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        raise BackendError(f"{what}: action space {act} is unbounded; the coadapt profile needs a finite action box")
    if np.any(low >= high):
        i = int(np.flatnonzero(low >= high)[0])
        raise BackendError(f"{what}: action space {act}: low[{i}] = {low[i]} is not below high[{i}] = {high[i]}")

    obs = env.observation_space
    if isinstance(obs, spaces.Box):
        flat = obs
    else:
        try:
            flat = spaces.flatten_space(obs)
        except Exception as e:  # noqa: BLE001
            raise BackendError(f"{what}: observation space {obs} cannot be flattened to a vector: {e}") from e
        if not isinstance(flat, spaces.Box):
            raise BackendError(f"{what}: observation space {obs} does not flatten to a Box")
    olow = np.asarray(flat.low, dtype=np.float32).ravel()
    ohigh = np.asarray(flat.high, dtype=np.float32).ravel()
    bounded = bool(np.all(np.isfinite(olow)) and np.all(np.isfinite(ohigh)) and np.all(olow <= ohigh))
    return Profile(
        action_low=low,
        action_high=high,
        obs_dim=int(olow.size),
        obs_low=olow if bounded else None,
        obs_high=ohigh if bounded else None,
        design=design,
    )


class GymBody(Body):
    """A gymnasium env, rebuilt by the factory when an episode starts with a different design."""

    def __init__(self, backend: "GymBackend", design: np.ndarray, world: Optional[dict] = None):
        self._backend = backend
        self.profile = backend.profile
        self._world = dict(world or {})
        self._design = np.asarray(design, dtype=np.float32).copy()
        self.env = backend.build(self._design, self._world)

    def start_episode(self, design: np.ndarray, seed: Optional[int]) -> np.ndarray:
        design = np.asarray(design, dtype=np.float32)
        if not np.array_equal(design, self._design):
            if seed is None:
                # Keep a seeded run reproducible across bodies: the old env's generator seeds
                # the new one.
                seed = int(self.env.np_random.integers(0, 2**31 - 1))
            old = self.env
            self.env = None
            _close_env(old)
            self.env = self._backend.build(design, self._world)
            self._design = design.copy()
        obs, _info = self.env.reset(seed=seed) if seed is not None else self.env.reset()
        return self._flatten(obs)

    def step(self, action: np.ndarray) -> StepResult:
        space = self.env.action_space
        a = np.asarray(action, dtype=space.dtype).reshape(space.shape)
        obs, reward, terminated, truncated, _info = self.env.step(a)
        return self._flatten(obs), float(reward), bool(terminated), bool(truncated)

    def _flatten(self, obs: Any) -> np.ndarray:
        from gymnasium import spaces

        space = self.env.observation_space
        if not isinstance(space, spaces.Box):
            obs = spaces.flatten(space, obs)
        flat = np.asarray(obs, dtype=np.float32).ravel()
        if flat.size != self.profile.obs_dim:
            raise RuntimeError(f"the environment returned {flat.size} observation values, {self.profile.obs_dim} expected")
        return flat

    def close(self) -> None:
        env, self.env = self.env, None
        if env is not None:
            _close_env(env)


def _close_env(env: Any) -> None:
    try:
        env.close()
    except Exception:  # noqa: BLE001
        log.exception("closing an environment failed")


class GymBackend(Backend):
    """``--env ID`` (``make(design)`` ignores the design) or ``--factory module:function``."""

    def __init__(self, make: Callable[[np.ndarray], Any], design: DesignSpace, what: str):
        self._make = make
        self.what = what
        self.design = design
        self.world_settings = _keyword_settings(make)
        # Build one env now: a broken environment fails at start, with its reason.
        probe = self._call_make(design.default)
        try:
            self.profile = gym_profile(probe, design, what)
        finally:
            _close_env(probe)

    @staticmethod
    def from_env_id(env_id: str, max_episode_steps: Optional[int] = None) -> "GymBackend":
        import gymnasium

        kwargs = {} if max_episode_steps is None else {"max_episode_steps": int(max_episode_steps)}

        def make(_design: np.ndarray) -> Any:
            return gymnasium.make(env_id, **kwargs)

        return GymBackend(make, DesignSpace.empty(), f"environment {env_id}")

    @staticmethod
    def from_factory(spec: str) -> "GymBackend":
        fn = load_attr(spec, "factory")
        if not callable(fn):
            raise BackendError(f"factory `{spec}` is not callable")
        try:
            design = DesignSpace.of(fn, f"factory {spec}")
        except ValueError as e:
            raise BackendError(str(e)) from None
        return GymBackend(fn, design, f"factory {spec}")

    def _call_make(self, design: np.ndarray, world: Optional[dict] = None) -> Any:
        kwargs = {name.replace("-", "_"): value for name, value in (world or {}).items()}
        try:
            env = self._make(np.asarray(design, dtype=np.float32).copy(), **kwargs)
        except Exception as e:
            at = f"design {design.tolist()}" + (f" in world {world}" if world else "")
            raise BackendError(f"{self.what} failed to build the environment for {at}: {type(e).__name__}: {e}") from e
        if not hasattr(env, "step") or not hasattr(env, "reset") or not hasattr(env, "action_space"):
            raise BackendError(f"{self.what} returned {type(env).__name__}, not a gymnasium.Env")
        return env

    def build(self, design: np.ndarray, world: Optional[dict] = None) -> Any:
        env = self._call_make(design, world)
        profile = gym_profile(env, self.design, self.what)
        if not profile.same_spaces(self.profile):
            _close_env(env)
            raise BackendError(
                f"{self.what} built an environment with other spaces for design {np.asarray(design).tolist()} "
                f"({profile.describe()}, expected {self.profile.describe()}); the action box and the "
                "observation size must not depend on the design"
            )
        return env

    def new_body(self, design: np.ndarray, world: Optional[dict] = None) -> Body:
        return GymBody(self, design, world)


def _keyword_settings(make: Callable) -> frozenset:
    """The world settings a factory takes: its keyword parameters after the design, named as a
    client sends them (``actuator_scale`` -> ``actuator-scale``)."""
    import inspect

    try:
        params = list(inspect.signature(make).parameters.values())[1:]
    except (TypeError, ValueError):
        return frozenset()
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return frozenset(p.name.replace("_", "-") for p in params if p.kind in kinds and p.default is not inspect.Parameter.empty)


# ---------------------------------------------------------------------------------------------
# Robot drivers


class DriverBody(Body):
    """The robot, with the bridge's safety rules around the driver: clipping, change and rate
    limits, serialised calls, and ``safe_stop`` that never raises."""

    is_robot = True

    def __init__(self, backend: "DriverBackend"):
        self._backend = backend
        self.profile = backend.profile
        self.decl = backend.decl

    def start_episode(self, design: np.ndarray, seed: Optional[int]) -> np.ndarray:
        b = self._backend
        with b.lock:
            if b.stopping.is_set():
                raise ShuttingDown("the server is stopping")
            b.stopped = False
            obs = b.driver.reset(np.asarray(design, dtype=np.float32).copy())
            b.previous_action = None if self.decl.rest_action is None else self.decl.rest_action.copy()
        return self._observation(obs)

    def step(self, action: np.ndarray) -> StepResult:
        b = self._backend
        decl = self.decl
        a = np.clip(np.asarray(action, dtype=np.float32), decl.action_low, decl.action_high)
        with b.lock:
            if decl.max_action_change is not None and b.previous_action is not None:
                a = np.clip(a, b.previous_action - decl.max_action_change, b.previous_action + decl.max_action_change)
                a = np.clip(a, decl.action_low, decl.action_high).astype(np.float32)
            # Rate limit: wait until one period after the last forwarded action.
            if math.isfinite(decl.max_action_rate_hz) and b.last_action_time is not None:
                wait = b.last_action_time + 1.0 / decl.max_action_rate_hz - time.monotonic()
                if wait > 0 and b.stopping.wait(wait):
                    raise ShuttingDown("the server is stopping")
            if b.stopping.is_set():
                raise ShuttingDown("the server is stopping")
            b.last_action_time = time.monotonic()
            b.previous_action = a.copy()
            b.stopped = False
            result = b.driver.step(a.copy())
        try:
            obs, reward, terminated, truncated = result
        except (TypeError, ValueError):
            raise RuntimeError(
                f"driver step() returned {result!r}, expected (observation, reward, terminated, truncated)"
            ) from None
        return self._observation(obs), float(reward), bool(terminated), bool(truncated)

    def _observation(self, obs: Any) -> np.ndarray:
        flat = np.asarray(obs, dtype=np.float32).ravel()
        if flat.size != self.decl.observation_size:
            raise RuntimeError(f"the driver returned {flat.size} observation values, observation_size is {self.decl.observation_size}")
        return flat

    def safe_stop(self, reason: str) -> None:
        self._backend.safe_stop(reason)

    def close(self) -> None:
        self._backend.release(self)


class DriverBackend(Backend):
    """One driver instance, serving one world at a time."""

    is_robot = True

    def __init__(self, driver: Any, what: Optional[str] = None):
        self.what = what or f"driver {type(driver).__name__}"
        try:
            self.decl = DriverDeclaration.of(driver)
        except ValueError as e:
            raise BackendError(str(e)) from None
        self.driver = driver
        d = self.decl
        self.profile = Profile(d.action_low, d.action_high, d.observation_size, None, None, d.design)
        # Serialises every call into the driver (reset, step, safe_stop, close).
        self.lock = threading.RLock()
        self.stopping = threading.Event()
        self.last_action_time: Optional[float] = None
        self.previous_action: Optional[np.ndarray] = None
        self.safe_stops = 0
        # Nothing was sent to the robot since the last safe_stop (False at start: unknown).
        self.stopped = False
        self._in_use: Optional[DriverBody] = None
        self._claim = threading.Lock()
        self._closed = False
        self._shutting_down = False
        self._final_stop_done = False

    @staticmethod
    def from_spec(spec: str) -> "DriverBackend":
        cls = load_attr(spec, "driver")
        if not callable(cls):
            raise BackendError(f"driver `{spec}` is not a class")
        try:
            driver = cls()
        except Exception as e:
            raise BackendError(f"driver `{spec}`: creating it failed: {type(e).__name__}: {e}") from e
        return DriverBackend(driver, f"driver {spec}")

    def new_body(self, design: np.ndarray, world: Optional[dict] = None) -> Body:
        with self._claim:
            if self._shutting_down:
                raise ShuttingDown("the server is stopping")
            if self._in_use is not None:
                raise RobotBusy("the robot already serves a world (a driver serves one world at a time): destroy it first")
            body = DriverBody(self)
            self._in_use = body
            return body

    def release(self, body: DriverBody) -> None:
        with self._claim:
            if self._in_use is body:
                self._in_use = None

    def safe_stop(self, reason: str, lock_timeout: Optional[float] = None, final: bool = False) -> None:
        """Calls the driver's ``safe_stop``; logs (never raises) its failures. With
        ``lock_timeout``, calls it even if another driver call still holds the lock after
        that long (server shutdown). Skipped when nothing was sent to the robot since the last
        ``safe_stop`` (leaving then destroying a world stops the robot once); after the
        shutdown's (``final``) call no more are made, as no driver call can follow it."""
        if self._final_stop_done and not final:
            log.debug("safe_stop (%s): already stopped for shutdown", reason)
            return
        acquired = self.lock.acquire(timeout=-1 if lock_timeout is None else lock_timeout)
        try:
            if self.stopped and not final:
                log.debug("safe_stop (%s): the robot is still stopped", reason)
                return
            if not acquired:
                log.warning("safe_stop: a driver call is still running after %.1f s; calling safe_stop anyway", lock_timeout)
            log.info("safe_stop (%s)", reason)
            self.safe_stops += 1
            try:
                self.driver.safe_stop()
                # A failed safe_stop is tried again at the next occasion.
                self.stopped = True
            except Exception:  # noqa: BLE001 - safe_stop failures are logged, never fatal
                log.exception("driver safe_stop() raised (%s)", reason)
            self.previous_action = None if self.decl.rest_action is None else self.decl.rest_action.copy()
        finally:
            if final:
                self._final_stop_done = True
            if acquired:
                self.lock.release()

    def begin_shutdown(self) -> None:
        """Refuse every further driver call (a step waiting for the rate limit gives up), then
        ``safe_stop`` the robot once, for good."""
        with self._claim:
            if self._shutting_down:
                return
            self._shutting_down = True
        self.stopping.set()
        self.safe_stop("server shutdown", lock_timeout=2.0, final=True)

    def close(self) -> None:
        """Server shutdown: ``begin_shutdown`` if not done, then the driver's ``close``."""
        self.begin_shutdown()
        with self._claim:
            if self._closed:
                return
            self._closed = True
        acquired = self.lock.acquire(timeout=2.0)
        try:
            close = getattr(self.driver, "close", None)
            if callable(close):
                close()
        except Exception:  # noqa: BLE001
            log.exception("driver close() raised")
        finally:
            if acquired:
                self.lock.release()
