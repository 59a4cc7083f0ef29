"""TLS and role tokens for a bridge served across machines, as coadapt's own servers do them.

The tokens file holds ``ROLE SHA256-HEX`` lines (``coadapt token new --tokens-file``): the bridge
keeps no secret. A call must carry ``authorization: Bearer <token>`` of role ``actor`` or
``operator``; a missing or unknown token is refused with UNAUTHENTICATED, another role with
PERMISSION_DENIED. Tokens are never logged.
"""

from __future__ import annotations

import hashlib
import ipaddress
import logging
import threading
from typing import Callable, Dict, Optional

import grpc

ROLES = ("actor", "optimizer", "client", "operator")
# Who may step an environment.
SERVED = ("actor", "operator")

log = logging.getLogger("coadapt_bridge")


class AuthError(ValueError):
    """A bad tokens file or TLS file, named."""


def load_tokens(path: str) -> Dict[str, str]:
    """The tokens file as {sha256 hex: role}; errors name the file and line."""
    try:
        text = open(path, encoding="utf-8").read()
    except OSError as e:
        raise AuthError(f"--tokens-file {path}: {e.strerror}") from None
    table: Dict[str, str] = {}
    for i, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2:
            raise AuthError(f"--tokens-file {path} line {i}: expected `ROLE SHA256-HEX`")
        role, digest = parts
        if role not in ROLES:
            raise AuthError(f"--tokens-file {path} line {i}: {role!r} is not a role: {', '.join(ROLES)}")
        if len(digest) != 64 or any(c not in "0123456789abcdefABCDEF" for c in digest):
            raise AuthError(f"--tokens-file {path} line {i}: the hash is not 64 hex digits (the file holds hashes, never tokens)")
        table[digest.lower()] = role
    if not table:
        raise AuthError(f"--tokens-file {path}: no tokens: every call would be refused")
    return table


def read_pem(flag: str, path: str) -> bytes:
    try:
        data = open(path, "rb").read()
    except OSError as e:
        raise AuthError(f"{flag} {path}: {e.strerror}") from None
    if b"-----BEGIN " not in data:
        raise AuthError(f"{flag} {path}: not a PEM file")
    return data


def is_loopback(host: str) -> bool:
    if host in ("localhost",):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _refuse(code: grpc.StatusCode, message: str) -> grpc.RpcMethodHandler:
    def abort(_request, context):
        context.abort(code, message)

    return grpc.stream_stream_rpc_method_handler(abort)


class TokenGate(grpc.ServerInterceptor):
    """Refuses calls without an accepted token of a served role; counts what it refused."""

    def __init__(self, table: Dict[str, str]):
        self.table = table
        self.lock = threading.Lock()
        self.refused = {"unauthenticated": 0, "permission_denied": 0}

    def _count(self, what: str) -> None:
        with self.lock:
            self.refused[what] += 1

    def intercept_service(self, continuation: Callable, details: grpc.HandlerCallDetails):
        header: Optional[str] = None
        for key, value in details.invocation_metadata or ():
            if key == "authorization":
                header = value if isinstance(value, str) else value.decode("ascii", "replace")
        if header is None:
            self._count("unauthenticated")
            return _refuse(grpc.StatusCode.UNAUTHENTICATED, "authorization: missing; send `authorization: Bearer <token>`")
        if not header.startswith("Bearer "):
            self._count("unauthenticated")
            return _refuse(grpc.StatusCode.UNAUTHENTICATED, "authorization: not `Bearer <token>`")
        role = self.table.get(hashlib.sha256(header[7:].strip().encode()).hexdigest())
        if role is None:
            self._count("unauthenticated")
            return _refuse(grpc.StatusCode.UNAUTHENTICATED, "authorization: this token is not accepted here")
        if role not in SERVED:
            self._count("permission_denied")
            return _refuse(grpc.StatusCode.PERMISSION_DENIED, f"role {role} may not step this environment (actors and operators may)")
        return continuation(details)
