"""The state the dm_env_rpc service keeps: worlds, connections (sessions) and the watchdog
that enforces a robot driver's step deadline (``service.py`` holds the service that uses them)."""

from __future__ import annotations

import logging
import threading
import time
from typing import Dict, Optional

import numpy as np

from .backends import Body

log = logging.getLogger("coadapt_bridge")


class World:
    """A world: its body, the design and seed of the next episode, the running episode."""

    def __init__(self, name: str, body: Body, design: np.ndarray, seed: Optional[int], owner: int):
        self.name = name
        self.body = body
        self.design = design
        self.pending_seed = seed
        self.owner: Optional[int] = owner
        self.lock = threading.RLock()
        self.agent: Optional["Session"] = None
        self.running = False
        # The next step answers INTERRUPTED (a ResetWorld from another connection, a safety stop).
        self.interrupted = False
        self.steps = 0
        self.obs = np.zeros(body.profile.obs_dim, dtype=np.float32)
        self.reward = 0.0
        self.discount = 1.0
        # Robots: the robot may be moving (commanded since the last safe_stop), and the time
        # by which the next StepRequest must arrive.
        self.robot_active = False
        self.deadline: Optional[float] = None
        self.closed = False


class Session:
    """One connection (one Process stream). Its lock is held while one of its requests is
    handled and while it ends (lock order: session, then world, then the driver)."""

    def __init__(self, sid: int, peer: str):
        self.id = sid
        self.peer = peer
        self.world: Optional[World] = None
        self.closed = False
        self.lock = threading.Lock()


class Watchdog:
    """Calls ``on_expire(world, deadline)`` when a world's step deadline passes."""

    def __init__(self, on_expire):
        self._on_expire = on_expire
        self._cond = threading.Condition()
        self._deadlines: Dict[World, float] = {}
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="coadapt-step-watchdog", daemon=True)
        self._thread.start()

    def arm(self, world: World, deadline: float) -> None:
        with self._cond:
            self._deadlines[world] = deadline
            self._cond.notify()

    def disarm(self, world: World) -> None:
        with self._cond:
            self._deadlines.pop(world, None)

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout=5)

    def _run(self) -> None:
        with self._cond:
            while not self._stopped:
                if not self._deadlines:
                    self._cond.wait()
                    continue
                world, deadline = min(self._deadlines.items(), key=lambda kv: kv[1])
                now = time.monotonic()
                if deadline > now:
                    self._cond.wait(deadline - now)
                    continue
                del self._deadlines[world]
                self._cond.release()
                try:
                    self._on_expire(world, deadline)
                except Exception:  # noqa: BLE001
                    log.exception("step watchdog")
                finally:
                    self._cond.acquire()
