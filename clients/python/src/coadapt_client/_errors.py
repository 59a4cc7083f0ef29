"""What the client raises."""

from __future__ import annotations

import grpc


class CoadaptError(Exception):
    """A call the server refused or could not answer.

    ``code`` is the gRPC status code (``grpc.StatusCode.INVALID_ARGUMENT`` for a malformed
    request: its message names the field, e.g. ``designs[2]: 7 values, the design has 6``),
    ``call`` the method (``Score``, ``Optimize``, ...).
    """

    def __init__(self, call: str, code: grpc.StatusCode, message: str):
        super().__init__(f"{call}: {message} ({code.name})")
        self.call = call
        self.code = code
        self.message = message


def wrap(call: str, e: grpc.RpcError) -> CoadaptError:
    code = e.code() if hasattr(e, "code") else grpc.StatusCode.UNKNOWN
    details = e.details() if hasattr(e, "details") else str(e)
    if code == grpc.StatusCode.DEADLINE_EXCEEDED:
        details = f"no answer before the deadline ({details})"
    return CoadaptError(call, code, details or code.name)
