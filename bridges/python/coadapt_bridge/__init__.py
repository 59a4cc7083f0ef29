"""coadapt's Python bridge: gymnasium environments, body factories and real robots served over
DeepMind's dm_env_rpc v1 protocol, following the coadapt profile (proto/README.md).

- ``design_space(low, high, default)``: declares the design box of a body factory.
- ``RobotDriver``: base class of a real robot's driver (see ``coadapt_bridge.driver``).
- ``BridgeServer`` (``coadapt_bridge.server``): the server, for use in-process.
- ``coadapt-gym-serve`` (``coadapt_bridge.cli``): the command.
"""

from .design import design_space
from .driver import RobotDriver

__all__ = ["design_space", "RobotDriver", "BridgeServer", "GymBackend", "DriverBackend"]
__version__ = "0.1.0"


def __getattr__(name: str):
    # The server pulls in grpc and gymnasium: import it only when asked for.
    if name == "BridgeServer":
        from .server import BridgeServer

        return BridgeServer
    if name in ("GymBackend", "DriverBackend"):
        from . import backends

        return getattr(backends, name)
    raise AttributeError(f"module 'coadapt_bridge' has no attribute {name!r}")
