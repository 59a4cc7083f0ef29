"""The dm_env_rpc v1 ``Environment`` service of the coadapt profile, over a ``Backend``.

Worlds are created by CreateWorld (settings ``design`` and ``seed``, both optional, and the
world settings the factory takes as keyword arguments, e.g. ``friction``) and named
``world-1``, ``world-2``...; one agent joins each. A world lives until DestroyWorld or until
the connection that created it closes (a client that goes away without DestroyWorld leaks
nothing; a world another agent is still joined to lives until that agent leaves). Every
request gets one response, in order; a bad request gets an ``error`` (google.rpc.Status) and
the stream goes on.

For a robot driver the server adds the safety rules described in ``driver.py``: a step
deadline watched by a watchdog thread, and ``safe_stop`` on leave, destroy, lost connection
and shutdown. The state it keeps (worlds, sessions, the watchdog) is in ``worlds.py``; the gRPC
server that serves it (listening, TLS, tokens, keep-alive, shutdown) in ``server.py``.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from typing import Dict, Iterable, Iterator, Optional

import grpc
import numpy as np
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import dm_env_rpc_pb2_grpc
from google.rpc import status_pb2

from . import tensors as T
from .backends import Backend, BackendError, DriverBody, Profile, RobotBusy, ShuttingDown
from .worlds import Session, Watchdog, World

log = logging.getLogger("coadapt_bridge")

RUNNING = pb.EnvironmentStateType.RUNNING
TERMINATED = pb.EnvironmentStateType.TERMINATED
INTERRUPTED = pb.EnvironmentStateType.INTERRUPTED


class RequestError(Exception):
    """A request refused with a gRPC status code (sent back in the stream)."""

    def __init__(self, code: grpc.StatusCode, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


def build_specs(profile: Profile) -> pb.ActionObservationSpecs:
    """The specs of the coadapt profile (proto/README.md)."""
    specs = pb.ActionObservationSpecs()
    specs.actions[T.ACTION_UID].CopyFrom(
        T.float_spec("action", [profile.action_dim], profile.action_low, profile.action_high)
    )
    specs.observations[T.OBSERVATION_UID].CopyFrom(
        T.float_spec("observation", [profile.obs_dim], profile.obs_low, profile.obs_high)
    )
    specs.observations[T.REWARD_UID].CopyFrom(T.float_spec("reward", []))
    specs.observations[T.DISCOUNT_UID].CopyFrom(
        T.float_spec("discount", [], np.float32(0.0), np.float32(1.0))
    )
    d = profile.design
    if d.dim > 0:
        design_spec = T.float_spec("design", [d.dim], d.low, d.high)
    else:
        design_spec = T.float_spec("design", [0])
    specs.observations[T.DESIGN_UID].CopyFrom(design_spec)
    return specs


class EnvironmentService(dm_env_rpc_pb2_grpc.EnvironmentServicer):
    """The dm_env_rpc ``Environment`` service over a backend."""

    def __init__(
        self,
        backend: Backend,
        max_episode_steps: Optional[int] = None,
        seed: Optional[int] = None,
        step_timeout: float = 1.0,
    ):
        self.backend = backend
        self.profile = backend.profile
        self.specs = build_specs(backend.profile)
        self.max_episode_steps = max_episode_steps
        self.default_seed = seed
        self.step_timeout = float(step_timeout)
        self.worlds: Dict[str, World] = {}
        self._lock = threading.Lock()
        self._world_numbers = itertools.count(1)
        self._session_numbers = itertools.count(1)
        self.stopping = False
        self.watchdog = Watchdog(self._deadline_expired) if backend.is_robot else None

    # -- the stream -----------------------------------------------------------------------

    def Process(self, request_iterator: Iterable[pb.EnvironmentRequest], context: grpc.ServicerContext) -> Iterator[pb.EnvironmentResponse]:  # noqa: N802
        session = Session(next(self._session_numbers), context.peer())
        log.debug("connection %d from %s", session.id, session.peer)

        def on_rpc_done() -> None:
            # gRPC calls this on its own thread when the stream ends or is cancelled; the
            # clean-up may wait for a driver call in progress, so it runs on a thread of its own.
            threading.Thread(
                target=self.end_session, args=(session, "the connection closed"), name="coadapt-session-end", daemon=True
            ).start()

        if not context.add_callback(on_rpc_done):
            self.end_session(session, "the connection closed")
            return
        try:
            for request in request_iterator:
                # A request is handled whole or not at all once the connection is gone.
                with session.lock:
                    if session.closed:
                        break
                    response = self.handle(session, request)
                yield response
        except Exception as e:  # noqa: BLE001 - a cancelled stream raises from the iterator
            log.debug("connection %d: %s: %s", session.id, type(e).__name__, e)
        finally:
            self.end_session(session, "the connection closed")

    def handle(self, session: Session, request: pb.EnvironmentRequest) -> pb.EnvironmentResponse:
        kind = request.WhichOneof("payload")
        try:
            if self.stopping:
                raise RequestError(grpc.StatusCode.UNAVAILABLE, "the server is stopping")
            if kind == "create_world":
                return pb.EnvironmentResponse(create_world=self.create_world(session, request.create_world))
            if kind == "join_world":
                return pb.EnvironmentResponse(join_world=self.join_world(session, request.join_world))
            if kind == "step":
                return pb.EnvironmentResponse(step=self.step(session, request.step))
            if kind == "reset":
                return pb.EnvironmentResponse(reset=self.reset(session, request.reset))
            if kind == "reset_world":
                return pb.EnvironmentResponse(reset_world=self.reset_world(session, request.reset_world))
            if kind == "leave_world":
                self.leave_world(session, "the agent left the world")
                return pb.EnvironmentResponse(leave_world=pb.LeaveWorldResponse())
            if kind == "destroy_world":
                return pb.EnvironmentResponse(destroy_world=self.destroy_world(session, request.destroy_world))
            if kind == "extension":
                raise RequestError(
                    grpc.StatusCode.UNIMPLEMENTED, f"no extensions are supported (got `{request.extension.type_url}`)"
                )
            raise RequestError(grpc.StatusCode.INVALID_ARGUMENT, "empty request (no payload)")
        except RequestError as e:
            return _error(e.code, e.message)
        except Exception as e:  # noqa: BLE001 - never let a request kill the stream
            log.exception("%s request failed", kind)
            return _error(grpc.StatusCode.INTERNAL, f"{kind}: {type(e).__name__}: {e}")

    # -- settings ---------------------------------------------------------------------------

    def _world_settings(self, settings, create: bool = False) -> tuple:
        """(design, seed, world): ``world`` holds the settings the backend's bodies take
        (``friction``, ...), accepted by CreateWorld only: a world's dynamics are fixed for its
        life, while ResetWorld may change its design and seed."""
        design = None
        seed = None
        world = {}
        extra = self.backend.world_settings
        for name in sorted(settings.keys()):
            t = settings[name]
            try:
                if name == T.SETTING_DESIGN:
                    d = self.profile.design
                    design = T.read_floats(name, t, d.dim, allow_doubles=True)
                    T.check_in_box(name, design, d.low, d.high, "design box")
                elif name == T.SETTING_SEED:
                    seed = T.read_seed(name, t)
                elif name in extra and create:
                    world[name] = T.read_scalar_float(name, t)
                elif name in extra:
                    raise RequestError(
                        grpc.StatusCode.INVALID_ARGUMENT,
                        f"world setting `{name}` is fixed when the world is created (CreateWorld), not at a reset",
                    )
                else:
                    known = ", ".join(f"`{n}`" for n in ["design", "seed", *sorted(extra)])
                    raise RequestError(
                        grpc.StatusCode.INVALID_ARGUMENT,
                        f"unknown world setting `{name}` (this server's worlds take {known})",
                    )
            except T.TensorError as e:
                raise RequestError(grpc.StatusCode.INVALID_ARGUMENT, f"setting `{name}`: {e}") from None
        return design, seed, world

    @staticmethod
    def _no_settings(settings, request: str) -> None:
        for name in sorted(settings.keys()):
            raise RequestError(
                grpc.StatusCode.INVALID_ARGUMENT, f"unknown {request} setting `{name}` ({request} takes no settings)"
            )

    # -- requests ---------------------------------------------------------------------------

    def _find(self, name: str) -> World:
        with self._lock:
            world = self.worlds.get(name)
        if world is None:
            raise RequestError(grpc.StatusCode.NOT_FOUND, f"no world named `{name}`")
        return world

    def create_world(self, session: Session, req: pb.CreateWorldRequest) -> pb.CreateWorldResponse:
        design, seed, world = self._world_settings(req.settings, create=True)
        if design is None:
            design = self.profile.design.default.copy()
        if seed is None:
            seed = self.default_seed
        try:
            body = self.backend.new_body(design, world)
        except RobotBusy as e:
            raise RequestError(grpc.StatusCode.FAILED_PRECONDITION, str(e)) from None
        except ShuttingDown as e:
            raise RequestError(grpc.StatusCode.UNAVAILABLE, str(e)) from None
        except BackendError as e:
            # A value the factory refuses (a friction below 0) is the request's fault.
            code = grpc.StatusCode.INVALID_ARGUMENT if world and isinstance(e.__cause__, ValueError) else grpc.StatusCode.INTERNAL
            raise RequestError(code, f"building the environment: {e}") from None
        with self._lock:
            name = f"world-{next(self._world_numbers)}"
            self.worlds[name] = World(name, body, design, seed, session.id)
        log.info("created %s (design %s%s) for connection %d", name, design.tolist(), f", world {world}" if world else "", session.id)
        return pb.CreateWorldResponse(world_name=name)

    def join_world(self, session: Session, req: pb.JoinWorldRequest) -> pb.JoinWorldResponse:
        if session.world is not None:
            raise RequestError(
                grpc.StatusCode.FAILED_PRECONDITION, f"already joined to world `{session.world.name}`: leave it first"
            )
        world = self._find(req.world_name)
        self._no_settings(req.settings, "join")
        with world.lock:
            if world.closed:
                raise RequestError(grpc.StatusCode.NOT_FOUND, f"no world named `{req.world_name}`")
            if world.agent is not None:
                raise RequestError(grpc.StatusCode.FAILED_PRECONDITION, f"world `{world.name}` already has its agent")
            world.agent = session
            world.running = False
            world.interrupted = False
        session.world = world
        log.info("connection %d joined %s", session.id, world.name)
        return pb.JoinWorldResponse(specs=self.specs)

    def leave_world(self, session: Session, reason: str) -> None:
        world = session.world
        if world is None:
            return
        session.world = None
        destroy = False
        with world.lock:
            if world.body.is_robot:
                self._safety_stop(world, reason)
            world.agent = None
            world.running = False
            world.interrupted = False
            destroy = world.owner is None and not world.closed
        log.info("connection %d left %s (%s)", session.id, world.name, reason)
        if destroy:
            self._remove(world, "its creator and its agent are gone")

    def reset(self, session: Session, req: pb.ResetRequest) -> pb.ResetResponse:
        world = session.world
        if world is None:
            raise RequestError(grpc.StatusCode.FAILED_PRECONDITION, "reset before joining a world")
        self._no_settings(req.settings, "reset")
        with world.lock:
            world.running = False
            world.interrupted = False
        return pb.ResetResponse(specs=self.specs)

    def reset_world(self, session: Session, req: pb.ResetWorldRequest) -> pb.ResetWorldResponse:
        world = self._find(req.world_name)
        design, seed, _ = self._world_settings(req.settings)
        with world.lock:
            if design is not None:
                world.design = design
            if seed is not None:
                world.pending_seed = seed
            if world.agent is session:
                # The issuer starts the next episode at once (no INTERRUPTED step).
                world.running = False
                world.interrupted = False
            elif world.running:
                # Another connection's agent is told once, then starts afresh.
                world.running = False
                world.interrupted = True
        return pb.ResetWorldResponse()

    def destroy_world(self, session: Session, req: pb.DestroyWorldRequest) -> pb.DestroyWorldResponse:
        world = self._find(req.world_name)
        if session.world is world:
            raise RequestError(grpc.StatusCode.FAILED_PRECONDITION, f"leave world `{world.name}` before destroying it")
        with world.lock:
            if world.agent is not None:
                raise RequestError(grpc.StatusCode.FAILED_PRECONDITION, f"world `{world.name}` has an agent joined")
        self._remove(world, "DestroyWorld")
        return pb.DestroyWorldResponse()

    def step(self, session: Session, req: pb.StepRequest) -> pb.StepResponse:
        world = session.world
        if world is None:
            raise RequestError(grpc.StatusCode.FAILED_PRECONDITION, "step before joining a world")
        requested = list(dict.fromkeys(req.requested_observations))
        for uid in requested:
            if uid not in T.OBSERVATION_UIDS:
                raise RequestError(
                    grpc.StatusCode.INVALID_ARGUMENT,
                    f"requested observation uid {uid} does not exist (uids: 1 observation, 2 reward, 3 discount, 4 design)",
                )
        with world.lock:
            robot = world.body.is_robot
            if robot:
                self._step_arrived(world)
            try:
                state = self._advance(world, req)
            finally:
                if robot and world.robot_active and not self.stopping:
                    world.deadline = time.monotonic() + self.step_timeout
                    self.watchdog.arm(world, world.deadline)
            response = pb.StepResponse(state=state)
            for uid in requested:
                if uid == T.OBSERVATION_UID:
                    t = T.floats_tensor(world.obs, [world.obs.size])
                elif uid == T.REWARD_UID:
                    t = T.scalar_tensor(world.reward)
                elif uid == T.DISCOUNT_UID:
                    t = T.scalar_tensor(world.discount)
                else:
                    t = T.floats_tensor(world.design, [world.design.size])
                response.observations[uid].CopyFrom(t)
        return response

    def _advance(self, world: World, req: pb.StepRequest) -> int:
        """The state machine (called with the world's lock held)."""
        if world.interrupted:
            world.interrupted = False
            world.reward = 0.0
            world.discount = 1.0
            return INTERRUPTED
        if not world.running:
            # First step of an episode: its actions are ignored.
            seed, world.pending_seed = world.pending_seed, None
            world.reward = 0.0
            world.discount = 1.0
            world.steps = 0
            try:
                world.robot_active = world.body.is_robot
                world.obs = world.body.start_episode(world.design, seed)
            except ShuttingDown as e:
                raise RequestError(grpc.StatusCode.UNAVAILABLE, str(e)) from None
            except Exception as e:
                log.exception("%s: starting an episode failed", world.name)
                if world.body.is_robot:
                    self._safety_stop(world, "the driver's reset() raised")
                raise RequestError(grpc.StatusCode.INTERNAL, f"starting an episode: {type(e).__name__}: {e}") from None
            world.running = True
            return RUNNING

        for uid in req.actions.keys():
            if uid != T.ACTION_UID:
                raise RequestError(grpc.StatusCode.INVALID_ARGUMENT, f"action uid {uid} does not exist (uid 1 is `action`)")
        if T.ACTION_UID not in req.actions:
            raise RequestError(grpc.StatusCode.INVALID_ARGUMENT, "action `action` (uid 1) is required on every running step")
        p = self.profile
        try:
            action = T.read_floats("action", req.actions[T.ACTION_UID], p.action_dim, allow_doubles=False)
            T.check_in_box("action", action, p.action_low, p.action_high, "action box")
        except T.TensorError as e:
            raise RequestError(grpc.StatusCode.INVALID_ARGUMENT, str(e)) from None
        try:
            obs, reward, terminated, truncated = world.body.step(action)
        except ShuttingDown as e:
            world.running = False
            raise RequestError(grpc.StatusCode.UNAVAILABLE, str(e)) from None
        except Exception as e:
            world.running = False
            log.exception("%s: step failed", world.name)
            if world.body.is_robot:
                self._safety_stop(world, "the driver's step() raised")
            raise RequestError(grpc.StatusCode.INTERNAL, f"environment step: {type(e).__name__}: {e}") from None
        world.steps += 1
        if self.max_episode_steps is not None and world.steps >= self.max_episode_steps and not terminated:
            truncated = True
        world.obs = obs
        world.reward = reward
        world.discount = 0.0 if terminated else 1.0
        if terminated or truncated:
            world.running = False
            return TERMINATED
        return RUNNING

    # -- robot safety -----------------------------------------------------------------------

    def _step_arrived(self, world: World) -> None:
        """A StepRequest reached a robot's world (lock held): a deadline that passed already
        counts as missed even if the watchdog has not fired yet."""
        if world.deadline is not None and time.monotonic() > world.deadline:
            self._safety_stop(world, f"no StepRequest within the step timeout ({self.step_timeout:g} s)", deadline=True)
        world.deadline = None
        self.watchdog.disarm(world)

    def _deadline_expired(self, world: World, deadline: float) -> None:
        with world.lock:
            if world.deadline == deadline and not world.closed:
                self._safety_stop(world, f"no StepRequest within the step timeout ({self.step_timeout:g} s)", deadline=True)

    def _safety_stop(self, world: World, reason: str, deadline: bool = False) -> None:
        """``safe_stop`` the robot of ``world`` (lock held); a running episode is cut and its
        agent's next step answers INTERRUPTED."""
        body = world.body
        assert isinstance(body, DriverBody)
        if world.running:
            world.running = False
            world.interrupted = True
            log.log(logging.WARNING if deadline else logging.INFO, "%s: episode cut: %s", world.name, reason)
        body.safe_stop(f"{world.name}: {reason}")
        world.robot_active = False
        world.deadline = None
        if self.watchdog is not None:
            self.watchdog.disarm(world)

    # -- ends -------------------------------------------------------------------------------

    def _remove(self, world: World, reason: str) -> None:
        with self._lock:
            if self.worlds.get(world.name) is world:
                del self.worlds[world.name]
        with world.lock:
            if world.closed:
                return
            if world.body.is_robot:
                self._safety_stop(world, f"world destroyed ({reason})")
            world.closed = True
            try:
                world.body.close()
            except Exception:  # noqa: BLE001
                log.exception("%s: closing failed", world.name)
        log.info("destroyed %s (%s)", world.name, reason)

    def end_session(self, session: Session, reason: str) -> None:
        """The connection is gone: leave its world, destroy the worlds it created."""
        with session.lock:
            if session.closed:
                return
            session.closed = True
            try:
                self.leave_world(session, reason)
            except Exception:  # noqa: BLE001
                log.exception("leaving the world of connection %d", session.id)
            with self._lock:
                owned = [w for w in self.worlds.values() if w.owner == session.id]
            for world in owned:
                with world.lock:
                    keep = world.agent is not None
                    if keep:
                        world.owner = None  # destroyed when its agent leaves
                if not keep:
                    self._remove(world, "its connection closed")
        log.debug("connection %d ended", session.id)

    def close_all(self) -> None:
        """Server shutdown: destroy every world."""
        self.stopping = True
        with self._lock:
            worlds = list(self.worlds.values())
        for world in worlds:
            self._remove(world, "server shutdown")
        if self.watchdog is not None:
            self.watchdog.stop()


def _error(code: grpc.StatusCode, message: str) -> pb.EnvironmentResponse:
    return pb.EnvironmentResponse(error=status_pb2.Status(code=code.value[0], message=message))
