"""Frames kept within bounds: ``{type: within, frames: [left_elbow_flexion, left_fingertip], max: [null, 0.25, null]}``.

Each named frame's origin stays within ``min`` <= p <= ``max`` [m], the world frame's x, y and z; ``null`` (or a key
left out) leaves that side open. The bounds are planes, not obstacles: nothing is kept out of a box, a point is kept
inside one, and no other part of the body is touched.

Why: a driver's idle arm is free so that it hangs when the trunk leans, and the seated balance then uses it as a
counterweight: swung out past the seat's side, up to the door (76-92 % of the belted and lean drivers'
answers, by up to 0.17 m). A person leaves the idle hand in the lap or on the thigh. Held inside the seat's sides,
the posture task's gravity term lays the forearm on the thigh, where the self-collision task stops it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from oracles.errors import TaskError
from oracles.tasks.base import (
    BUFFER,
    INSIDE,
    Constraint,
    HardTask,
    Numeric,
    Reference,
    Row,
    Scope,
    Symbolic,
    frames,
)

AXES = "xyz"
HOLD_TOL = 1e-6  # [m] overshoot the verdict accepts


def _bounds(raw: Any, where: str) -> tuple[float | None, ...]:
    """Three bounds [m] or None, from a list of three numbers or nulls."""
    if raw is None:
        return (None, None, None)
    ok = isinstance(raw, list) and len(raw) == 3 and all(
        v is None or (isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)) for v in raw)
    if not ok:
        raise TaskError(where, f"expected [x, y, z] in metres, each a number or null (open), got {raw!r}")
    return tuple(None if v is None else float(v) for v in raw)


@dataclass(frozen=True)
class Bound:
    """One side of one frame: ``sign * (p[axis] - value) >= 0`` (sign +1 a lower bound, -1 an upper)."""

    frame: str
    axis: int
    value: float
    sign: float


@dataclass
class WithinTask(HardTask):
    """Frames whose origins stay within axis-aligned bounds of the world frame."""

    type: ClassVar[str] = "within"
    keys: ClassVar[frozenset[str]] = frozenset({"frames", "min", "max"})
    summary: ClassVar[str] = ("the origins of `frames` stay within `min` <= p <= `max` [m] (world x, y, z; null: "
                              "open), e.g. a driver's idle arm inside the seat's sides")

    bounds: tuple[Bound, ...] = ()
    _ids: dict[str, int] = field(default_factory=dict, repr=False, compare=False)
    _outside: list[str] = field(default_factory=list, repr=False, compare=False)  # broken at the reference

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> WithinTask:
        if "frames" not in raw:
            raise TaskError(f"{where}.frames", "expected the frames to keep within the bounds (a list of frame names)")
        names = frames(scope, raw["frames"], f"{where}.frames")
        lo, hi = _bounds(raw.get("min"), f"{where}.min"), _bounds(raw.get("max"), f"{where}.max")
        for k in range(3):
            if lo[k] is not None and hi[k] is not None and lo[k] > hi[k]:  # type: ignore[operator]
                raise TaskError(f"{where}.min", f"min {AXES[k]} = {lo[k]} m is above max {AXES[k]} = {hi[k]} m")
        if all(v is None for v in (*lo, *hi)):
            raise TaskError(f"{where}.max", "expected at least one bound in min or max (all are open)")
        still = [n for n in names if not scope.moves(n)]
        if still:
            raise TaskError(f"{where}.frames", f"{', '.join(still)}: no joint of the strategy moves "
                                               "(a bound on it could only hold or fail everywhere)")
        bounds = [Bound(n, k, v, s) for n in names for side, s in ((lo, 1.0), (hi, -1.0))
                  for k, v in enumerate(side) if v is not None]
        return cls(tuple(bounds))

    parametric: ClassVar[bool] = True  # the body enters only through the kinematics; the bounds are the config's

    def bind(self, reference: Reference) -> None:
        self._ids = {b.frame: reference.body.frame_id(b.frame) for b in self.bounds}
        self._outside = []
        for b in self.bounds:
            slack = b.sign * (float(reference.placement(b.frame).translation[b.axis]) - b.value)
            if slack < -HOLD_TOL:
                self._outside.append(f"{b.frame} is {-slack:.3f} m past its {'min' if b.sign > 0 else 'max'} "
                                     f"{AXES[b.axis]} = {b.value} m at the reference posture")

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        return [Constraint(b.sign * (sym.kin.frame(b.frame)[1][b.axis] - b.value), 0.0, np.inf) for b in self.bounds]

    def _slack(self, num: Numeric, b: Bound) -> float:
        return b.sign * (float(num.frame(self._ids[b.frame]).translation[b.axis]) - b.value)

    def rows(self, num: Numeric) -> list[Row]:
        assert num.jacobian is not None
        out = []
        for b in self.bounds:
            slack = self._slack(num, b)
            if slack < BUFFER:
                out.append(Row(b.sign * num.jacobian(self._ids[b.frame])[b.axis:b.axis + 1],
                               np.array([max(0.0, INSIDE - slack)])))
        return out

    def holds(self, num: Numeric) -> bool:
        return all(self._slack(num, b) >= -HOLD_TOL for b in self.bounds)

    def warnings(self) -> list[str]:
        return [f"within: {w} (the search starts from a posture the task refuses)" for w in self._outside]

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "bounds": [
            {"frame": b.frame, "axis": AXES[b.axis], "min" if b.sign > 0 else "max": b.value} for b in self.bounds]}
