"""The axis-aligned box a map covers: B0 of the paper, in metres, 2-D or 3-D."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reach.errors import TreeError


@dataclass(frozen=True)
class Box:
    """An axis-aligned box [lo, hi] in metres, 2-D or 3-D."""

    lo: np.ndarray
    hi: np.ndarray

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, dtype=float).reshape(-1)
        hi = np.asarray(self.hi, dtype=float).reshape(-1)
        if lo.shape != hi.shape or lo.shape[0] not in (2, 3):
            raise TreeError(f"box min and max must both have 2 or 3 coordinates, got {lo.shape} and {hi.shape}",
                            what="box")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise TreeError("box coordinates must be finite", what="box")
        if np.any(hi <= lo):
            raise TreeError(f"box is empty: max {hi.tolist()} must exceed min {lo.tolist()} on every axis", what="box")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @property
    def dim(self) -> int:
        return int(self.lo.shape[0])

    @property
    def size(self) -> np.ndarray:
        return self.hi - self.lo  # type: ignore[no-any-return]

    @property
    def volume(self) -> float:
        return float(np.prod(self.size))

    def to_dict(self) -> dict[str, list[float]]:
        return {"min": self.lo.tolist(), "max": self.hi.tolist()}

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Box) and np.array_equal(self.lo, other.lo) and np.array_equal(self.hi, other.hi)

    def __hash__(self) -> int:
        return hash((tuple(self.lo), tuple(self.hi)))
