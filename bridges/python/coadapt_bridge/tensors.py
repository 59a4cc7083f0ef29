"""dm_env_rpc tensors and specs of the coadapt profile, validated as the protocol requires.

Readers resolve the protocol's shape rules (one element broadcasts to the whole shape, one
negative dimension takes what the payload leaves), insist on the expected shape and type, and
refuse non-finite values, naming the tensor and the element. The failure is a
``TensorError`` whose message goes back to the client as an ``INVALID_ARGUMENT`` error.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np
from dm_env_rpc.v1 import dm_env_rpc_pb2 as pb
from dm_env_rpc.v1 import tensor_spec_utils

# The coadapt profile (proto/README.md, "The coadapt profile").
ACTION_UID = 1
OBSERVATION_UID = 1
REWARD_UID = 2
DISCOUNT_UID = 3
DESIGN_UID = 4
OBSERVATION_UIDS = (OBSERVATION_UID, REWARD_UID, DISCOUNT_UID, DESIGN_UID)
SETTING_DESIGN = "design"
SETTING_SEED = "seed"


class TensorError(ValueError):
    """A tensor that cannot be accepted; the message names it."""


def resolve_shape(name: str, shape: Sequence[int], n: int) -> list[int]:
    """The dimensions of a tensor of ``n`` elements declared with ``shape`` (dm_env_rpc's rules,
    the same as coadapt's Rust reader)."""
    shape = list(shape)
    negative = [i for i, d in enumerate(shape) if d < 0]
    if len(negative) > 1:
        raise TensorError(f"tensor `{name}`: shape {shape} has more than one negative dimension")
    known = math.prod(d for d in shape if d >= 0)
    dims = [max(d, 0) for d in shape]
    if negative:
        if known == 0:
            fill = 0
        elif n == 1:
            fill = 1  # a broadcast scalar
        else:
            fill = n // known
        if n != 1 and fill * known != n:
            raise TensorError(f"tensor `{name}`: {n} elements do not fill shape {shape}")
        dims[negative[0]] = fill
    total = math.prod(dims)
    if n != total and n != 1:
        raise TensorError(f"tensor `{name}`: {n} elements for shape {shape} ({total} expected)")
    return dims


def read_scalar_float(name: str, t: pb.Tensor) -> float:
    """One finite number (a ``floats`` or ``doubles`` tensor of shape ``[]`` or ``[1]``)."""
    which = t.WhichOneof("payload")
    if which == "floats":
        values = list(t.floats.array)
    elif which == "doubles":
        values = list(t.doubles.array)
    else:
        raise TensorError(f"tensor `{name}` has {which or 'no'} values, one float expected")
    dims = resolve_shape(name, t.shape, len(values))
    if len(values) != 1 or dims not in ([], [1]):
        raise TensorError(f"tensor `{name}` has shape {dims}, one float expected")
    v = float(values[0])
    if not np.isfinite(v):
        raise TensorError(f"tensor `{name}` is {v}, not finite")
    return v


def read_floats(name: str, t: pb.Tensor, dim: int, allow_doubles: bool) -> np.ndarray:
    """A finite float32 vector of shape ``[dim]`` from tensor ``t``.

    Only a ``floats`` payload is accepted unless ``allow_doubles`` (settings from other
    implementations); actions must match their ``FLOAT`` spec exactly (the compliance suite
    sends doubles and expects a refusal)."""
    which = t.WhichOneof("payload")
    if which == "floats":
        values = np.asarray(t.floats.array, dtype=np.float32)
    elif which == "doubles" and allow_doubles:
        doubles = np.asarray(t.doubles.array, dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(doubles))
        if bad.size:
            raise TensorError(f"tensor `{name}`: element {bad[0]} is {doubles[bad[0]]}, not finite")
        values = doubles.astype(np.float32)
    elif which is None and dim == 0 and list(t.shape) == [0]:
        # An empty tensor packed by numpy-based clients has no payload at all.
        values = np.zeros(0, dtype=np.float32)
    elif which is None:
        raise TensorError(f"tensor `{name}` has no payload")
    else:
        want = "floats or doubles" if allow_doubles else "floats (the spec's dtype is FLOAT)"
        raise TensorError(f"tensor `{name}` has {which} values, {want} expected")
    dims = resolve_shape(name, t.shape, values.size)
    if dims != [dim]:
        raise TensorError(f"tensor `{name}` has shape {dims}, [{dim}] expected")
    if values.size == 1 and dim != 1:
        values = np.full(dim, values[0], dtype=np.float32)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise TensorError(f"tensor `{name}`: element {bad[0]} is {values[bad[0]]}, not finite")
    return values


def check_in_box(name: str, values: np.ndarray, low: np.ndarray, high: np.ndarray, what: str = "box") -> None:
    """Raises TensorError naming the first element of ``values`` outside ``[low, high]``."""
    bad = np.flatnonzero((values < low) | (values > high))
    if bad.size:
        i = int(bad[0])
        raise TensorError(f"tensor `{name}`: element {i} is {values[i]}, outside the {what} [{low[i]}, {high[i]}]")


def read_seed(name: str, t: pb.Tensor) -> int:
    """A non-negative integer scalar of any integer type (shape ``[]`` or ``[1]``)."""
    which = t.WhichOneof("payload")
    if which not in ("int32s", "int64s", "uint32s", "uint64s"):
        raise TensorError(
            f"tensor `{name}` has {which or 'no'} values, an integer scalar (int32, int64, uint32 or uint64) expected"
        )
    values = [int(v) for v in getattr(t, which).array]
    dims = resolve_shape(name, t.shape, len(values))
    if len(values) != 1 or math.prod(dims) != 1:
        raise TensorError(f"tensor `{name}` has shape {dims} with {len(values)} elements, a scalar expected")
    if values[0] < 0:
        raise TensorError(f"tensor `{name}`: {values[0]} is negative")
    return values[0]


def floats_tensor(values: np.ndarray, shape: Sequence[int]) -> pb.Tensor:
    """A ``FLOAT`` tensor; an empty one still carries its (empty) ``floats`` payload, so its
    type is readable (``tensor_utils.get_tensor_type`` needs the oneof set)."""
    t = pb.Tensor()
    t.floats.SetInParent()
    t.floats.array.extend(np.asarray(values, dtype=np.float32).ravel().tolist())
    t.shape[:] = list(shape)
    return t


def scalar_tensor(value: float) -> pb.Tensor:
    t = pb.Tensor()
    t.floats.array.append(float(np.float32(value)))
    return t


def float_spec(name: str, shape: Sequence[int], low: Optional[np.ndarray] = None, high: Optional[np.ndarray] = None) -> pb.TensorSpec:
    spec = pb.TensorSpec(name=name, dtype=pb.DataType.FLOAT)
    spec.shape[:] = list(shape)
    if low is not None or high is not None:
        tensor_spec_utils.set_bounds(spec, low, high)
    return spec
