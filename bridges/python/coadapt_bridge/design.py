"""The design box of a body factory: the ``design_space`` decorator and its validation."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Optional, Sequence, TypeVar

import numpy as np

F = TypeVar("F", bound=Callable[..., Any])


def design_space(low: Sequence[float], high: Sequence[float], default: Optional[Sequence[float]] = None) -> Callable[[F], F]:
    """Declares the design box of a body factory for ``coadapt-gym-serve --factory``.

    ::

        @coadapt_bridge.design_space(low=[0.5, 0.5], high=[2.0, 2.0], default=[1.0, 1.0])
        def make(design: np.ndarray) -> gymnasium.Env:
            ...

    Sets the attributes ``design_low``, ``design_high`` and ``default_design`` (lists of
    floats) on the function, which is all the bridge reads; setting them by hand is the same.
    ``default`` defaults to the middle of the box. The box is checked here (same length,
    finite, ``low <= default <= high``), so a wrong declaration fails at import.
    """
    space = DesignSpace.from_lists(low, high, default, what="design_space")

    def decorate(fn: F) -> F:
        fn.design_low = [float(v) for v in space.low]  # type: ignore[attr-defined]
        fn.design_high = [float(v) for v in space.high]  # type: ignore[attr-defined]
        fn.default_design = [float(v) for v in space.default]  # type: ignore[attr-defined]
        return fn

    return decorate


@dataclass(frozen=True)
class DesignSpace:
    """A design box: ``low <= design <= high`` element-wise, and the default design."""

    low: np.ndarray
    high: np.ndarray
    default: np.ndarray

    @property
    def dim(self) -> int:
        return int(self.low.shape[0])

    @staticmethod
    def empty() -> "DesignSpace":
        z = np.zeros(0, dtype=np.float32)
        return DesignSpace(z, z.copy(), z.copy())

    @staticmethod
    def from_lists(low: Any, high: Any, default: Any = None, what: str = "design box") -> "DesignSpace":
        def vec(name: str, values: Any) -> np.ndarray:
            try:
                arr = np.asarray(values, dtype=np.float64)
            except (TypeError, ValueError) as e:
                raise ValueError(f"{what}: `{name}` is not a list of numbers: {e}") from None
            if arr.ndim != 1:
                raise ValueError(f"{what}: `{name}` must be a flat list of numbers, got shape {arr.shape}")
            bad = [i for i, v in enumerate(arr) if not math.isfinite(v)]
            if bad:
                raise ValueError(f"{what}: `{name}`[{bad[0]}] is {arr[bad[0]]}, not finite")
            return arr

        lo, hi = vec("low", low), vec("high", high)
        if lo.shape != hi.shape:
            raise ValueError(f"{what}: `low` has {lo.shape[0]} elements but `high` has {hi.shape[0]}")
        for i in range(lo.shape[0]):
            if lo[i] > hi[i]:
                raise ValueError(f"{what}: low[{i}] = {lo[i]} is above high[{i}] = {hi[i]}")
        d = (lo + hi) / 2.0 if default is None else vec("default", default)
        if d.shape != lo.shape:
            raise ValueError(f"{what}: `default` has {d.shape[0]} elements, the box has {lo.shape[0]}")
        for i in range(lo.shape[0]):
            if not lo[i] <= d[i] <= hi[i]:
                raise ValueError(f"{what}: default[{i}] = {d[i]} is outside [{lo[i]}, {hi[i]}]")
        f32 = lambda a: a.astype(np.float32)  # noqa: E731
        return DesignSpace(f32(lo), f32(hi), f32(d))

    @staticmethod
    def of(obj: Any, what: str) -> "DesignSpace":
        """The box declared by ``obj``'s attributes (``design_low``, ``design_high``,
        ``default_design``); no attributes at all means a body without design (D = 0)."""
        low = getattr(obj, "design_low", None)
        high = getattr(obj, "design_high", None)
        default = getattr(obj, "default_design", None)
        if low is None and high is None and default is None:
            return DesignSpace.empty()
        if low is None or high is None:
            raise ValueError(
                f"{what} declares only part of a design box: set `design_low` and `design_high` "
                "(and optionally `default_design`), e.g. with @coadapt_bridge.design_space(low, high, default)"
            )
        return DesignSpace.from_lists(low, high, default, what=what)

    def check(self, design: np.ndarray, name: str = "design") -> np.ndarray:
        """``design`` as float32 of shape ``[D]`` inside the box, or ValueError naming ``name``."""
        d = np.asarray(design, dtype=np.float32)
        if d.shape != (self.dim,):
            raise ValueError(f"`{name}` has shape {list(d.shape)}, [{self.dim}] expected")
        for i in range(self.dim):
            v = float(d[i])
            if not math.isfinite(v):
                raise ValueError(f"`{name}`[{i}] is {v}, not finite")
            if v < self.low[i] or v > self.high[i]:
                raise ValueError(f"`{name}`[{i}] = {v} is outside the design box [{self.low[i]}, {self.high[i]}]")
        return d
