"""What the client returns: plain dataclasses with numpy arrays."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np


@dataclass(frozen=True)
class Dimension:
    """One entry of the design vector: its name (``back thigh``), unit and box."""

    name: str
    unit: str
    low: float
    high: float


@dataclass(frozen=True)
class Info:
    robot: str
    dimensions: list[Dimension]
    weights_version: int
    start_states: int
    max_score_batch: int
    max_optimize_evaluations: int
    run_id: str

    @property
    def names(self) -> list[str]:
        return [d.name for d in self.dimensions]

    @property
    def low(self) -> np.ndarray:
        return np.array([d.low for d in self.dimensions], dtype=np.float32)

    @property
    def high(self) -> np.ndarray:
        return np.array([d.high for d in self.dimensions], dtype=np.float32)


@dataclass(frozen=True)
class Scores:
    """Eq. 5.6 of each design (``value``), its spread over the start states (sd), and the
    critics' disagreement (``None`` from a server whose run has one critic)."""

    value: np.ndarray
    spread: np.ndarray
    disagreement: Optional[np.ndarray]
    weights_version: int
    start_states: int


@dataclass(frozen=True)
class Progress:
    """One iteration of a search on the server: the best design so far and its value."""

    iteration: int
    evaluations: int
    best: np.ndarray
    best_value: float


@dataclass(frozen=True)
class Optimized:
    """A search's answer: the best design, its value and spread, what it cost."""

    design: np.ndarray
    value: float
    spread: float
    evaluations: int
    iterations: int
    weights_version: int


@dataclass(frozen=True)
class Record:
    """A row of the run's designs.csv."""

    index: int
    kind: str
    design: np.ndarray
    episodes: int
    best_eval_return: Optional[float]
    last_eval_return: Optional[float]
    predicted_objective: Optional[float]
    design_rollouts: int
    method: str
    prototype: str


@dataclass(frozen=True)
class Landscape:
    """Thesis Fig. 5.9: Eq. 5.6 over the plane of the designs' first two principal components.
    ``objective[j, i]`` is at ``(pc1[i], pc2[j])``, the design ``mean + pc1[i] axes[0] + pc2[j]
    axes[1]`` clipped to the box; ``designs`` are the run's designs projected (index, kind, pc1,
    pc2)."""

    mean: np.ndarray
    axes: np.ndarray
    explained: tuple[float, float]
    pc1: np.ndarray
    pc2: np.ndarray
    objective: np.ndarray
    designs: list[tuple[int, str, float, float]] = field(default_factory=list)
    weights_version: int = 0
