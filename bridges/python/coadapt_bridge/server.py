"""The gRPC server of the bridge: one ``BridgeServer`` serves one backend's dm_env_rpc
``Environment`` service (``service.py``) on a port, with TLS and role tokens when asked, keep-alive
for vanished clients, and an orderly stop (a robot's ``safe_stop`` first, then every world).
"""

from __future__ import annotations

import threading
from concurrent import futures
from typing import Any, Dict, Optional

import grpc
from dm_env_rpc.v1 import dm_env_rpc_pb2_grpc

from .backends import Backend, DriverBackend
from .service import EnvironmentService

def _grpc_options() -> list:
    return [
        # Keep-alive: ping idle clients (a vanished client is noticed), and accept clients'
        # pings (coadapt's client pings every 10 s) without counting strikes against them.
        ("grpc.keepalive_time_ms", 10_000),
        ("grpc.keepalive_timeout_ms", 20_000),
        ("grpc.keepalive_permit_without_calls", 1),
        ("grpc.http2.max_pings_without_data", 0),
        ("grpc.http2.min_recv_ping_interval_without_data_ms", 1_000),
        ("grpc.http2.max_ping_strikes", 0),
        # A port another server listens on is an error, not a silent share (gRPC's default
        # SO_REUSEPORT would split the connections between the two).
        ("grpc.so_reuseport", 0),
    ]


class BridgeServer:
    """A gRPC server for one backend. ``start()`` returns the bound port; ``stop()`` closes
    every world and, for a robot, calls ``safe_stop`` then the driver's ``close``."""

    def __init__(
        self,
        backend: Backend,
        host: str = "127.0.0.1",
        port: int = 0,
        max_episode_steps: Optional[int] = None,
        seed: Optional[int] = None,
        step_timeout: float = 1.0,
        max_connections: int = 32,
        tls: Optional[tuple] = None,
        tokens: Optional[Dict[str, str]] = None,
    ):
        """``tls``: (certificate PEM, key PEM) to serve TLS only; ``tokens``: {sha256: role} of
        the accepted tokens (see ``coadapt_bridge.auth``)."""
        from .auth import TokenGate

        self.backend = backend
        self.tls = tls
        self.gate = TokenGate(tokens) if tokens else None
        self.host = host
        self.requested_port = port
        self.service = EnvironmentService(backend, max_episode_steps, seed, step_timeout)
        self._server = grpc.server(
            futures.ThreadPoolExecutor(max_workers=max_connections + 2, thread_name_prefix="coadapt-rpc"),
            options=_grpc_options(),
            maximum_concurrent_rpcs=max_connections,
            interceptors=[self.gate] if self.gate else None,
        )
        dm_env_rpc_pb2_grpc.add_EnvironmentServicer_to_server(self.service, self._server)
        self.port: Optional[int] = None
        self._stopped = False
        self._stop_lock = threading.Lock()

    @property
    def address(self) -> str:
        host = f"[{self.host}]" if ":" in self.host and not self.host.startswith("[") else self.host
        return f"{host}:{self.port if self.port is not None else self.requested_port}"

    def start(self) -> int:
        host = f"[{self.host}]" if ":" in self.host and not self.host.startswith("[") else self.host
        try:
            if self.tls is not None:
                creds = grpc.ssl_server_credentials([(self.tls[1], self.tls[0])])
                port = self._server.add_secure_port(f"{host}:{self.requested_port}", creds)
            else:
                port = self._server.add_insecure_port(f"{host}:{self.requested_port}")
        except RuntimeError as e:
            raise OSError(f"cannot listen on {host}:{self.requested_port}: {e}") from None
        if not port:
            raise OSError(f"cannot listen on {host}:{self.requested_port}")
        self.port = port
        self._server.start()
        return port

    def stop(self, grace: float = 0.5) -> None:
        with self._stop_lock:
            if self._stopped:
                return
            self._stopped = True
        backend = self.backend
        if isinstance(backend, DriverBackend):
            # The robot first: stop it now, refuse further driver calls.
            backend.begin_shutdown()
        self.service.stopping = True
        self._server.stop(grace).wait()
        self.service.close_all()
        backend.close()

    def __enter__(self) -> "BridgeServer":
        if self.port is None:
            self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()
