"""Shared servers and clients for the bridge's tests (servers run in-process on port 0)."""

from __future__ import annotations

import queue
import threading
import time

import grpc
import numpy as np
from dm_env_rpc.v1 import connection as dm_connection
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import dm_env_rpc_pb2_grpc
from dm_env_rpc.v1 import tensor_utils

from coadapt_bridge.backends import GymBackend
from coadapt_bridge.server import BridgeServer

_shared: dict = {}
_channels: dict = {}
_lock = threading.Lock()


def make_backend(kind: str):
    if kind == "pendulum":
        return GymBackend.from_env_id("Pendulum-v1")
    if kind == "toy":
        return GymBackend.from_factory("toys:make_toy")
    raise ValueError(kind)


def shared_server(kind: str) -> BridgeServer:
    """One server per kind for the whole test run (stopped by conftest at the end)."""
    with _lock:
        if kind not in _shared:
            server = BridgeServer(make_backend(kind), port=0)
            server.start()
            _shared[kind] = server
        return _shared[kind]


def shared_channel(server: BridgeServer) -> grpc.Channel:
    """One channel per server: closing a grpc channel takes 0.2 s, a stream is cheap."""
    with _lock:
        if server.address not in _channels:
            channel = grpc.insecure_channel(server.address)
            grpc.channel_ready_future(channel).result(timeout=10)
            _channels[server.address] = channel
        return _channels[server.address]


def stop_shared_servers() -> None:
    with _lock:
        servers = list(_shared.values())
        channels = list(_channels.values())
        _shared.clear()
        _channels.clear()
    for c in channels:
        c.close()
    for s in servers:
        s.stop(grace=0)


class _Stream:
    """dm_env_rpc's StreamReaderWriter, plus a way to cancel the call (the server then sees
    the connection close, as when a client process dies)."""

    def __init__(self, channel: grpc.Channel):
        self._requests: queue.Queue = queue.Queue()
        self.call = dm_env_rpc_pb2_grpc.EnvironmentStub(channel).Process(iter(self._requests.get, None))

    def write(self, request):
        self._requests.put(request)

    def read(self):
        return next(self.call)

    def cancel(self):
        self.call.cancel()
        self._requests.put(None)


class StreamConnection(dm_connection.Connection):
    """A dm_env_rpc Connection over one stream of a shared channel; ``close`` cancels it."""

    def __init__(self, channel: grpc.Channel):  # noqa: super().__init__ would open its own stream
        self._stream = _Stream(channel)

    def close(self):
        if self._stream is not None:
            self._stream.cancel()
            self._stream = None


class Client:
    """A channel and a dm_env_rpc Connection to a server."""

    def __init__(self, server: BridgeServer, own_channel: bool = False):
        """With ``own_channel`` the client has a channel of its own (``close`` closes it);
        otherwise a stream on the server's shared channel (``close`` cancels the stream)."""
        self.own_channel = own_channel
        if own_channel:
            self.channel = grpc.insecure_channel(server.address)
            grpc.channel_ready_future(self.channel).result(timeout=10)
        else:
            self.channel = shared_channel(server)
        self.connection = StreamConnection(self.channel)

    def send(self, request):
        return self.connection.send(request)

    def create(self, **settings) -> str:
        packed = {k: v if isinstance(v, pb.Tensor) else tensor_utils.pack_tensor(v) for k, v in settings.items()}
        return self.send(pb.CreateWorldRequest(settings=packed)).world_name

    def join(self, world: str) -> pb.ActionObservationSpecs:
        return self.send(pb.JoinWorldRequest(world_name=world)).specs

    def reset_world(self, world: str, **settings) -> None:
        packed = {k: v if isinstance(v, pb.Tensor) else tensor_utils.pack_tensor(v) for k, v in settings.items()}
        self.send(pb.ResetWorldRequest(world_name=world, settings=packed))

    def step(self, action=None, uids=(1, 2, 3, 4)):
        actions = {}
        if action is not None:
            actions[1] = tensor_utils.pack_tensor(np.asarray(action, dtype=np.float32))
        r = self.send(pb.StepRequest(actions=actions, requested_observations=list(uids)))
        obs = {uid: tensor_utils.unpack_tensor(t) for uid, t in r.observations.items()}
        return r.state, obs

    def close(self) -> None:
        self.connection.close()
        if self.own_channel:
            self.channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def wait_until(predicate, timeout: float = 5.0, interval: float = 0.01) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(interval)
    return predicate()
