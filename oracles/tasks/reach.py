"""The effector at the goal: ``{type: reach, tolerance: 0.005, priority: 1}``.

The verdict's task: a posture reaches the goal when Pinocchio puts the
effector within ``tolerance`` [m] of it (and every hard task holds).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from oracles.tasks.base import Numeric, Reference, Row, Scope, SoftTask, Symbolic, number

TOLERANCE = 0.005  # [m] default reach tolerance of the verdict


@dataclass
class ReachTask(SoftTask):
    """Minimise the effector's distance to the goal; within ``tolerance`` it is reached."""

    type: ClassVar[str] = "reach"
    keys: ClassVar[frozenset[str]] = frozenset({"tolerance"})
    summary: ClassVar[str] = "the effector at the goal; its `tolerance` [m] (default 5 mm) decides the verdict"
    default_priority: ClassVar[int] = 1
    slack: ClassVar[float] = 1e-6  # [m per axis] a later stage may move the effector

    effector: str
    tolerance: float = TOLERANCE
    priority: float = 1.0
    _id: int = field(default=-1, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> ReachTask:
        return cls(scope.effector, number(raw.get("tolerance", TOLERANCE), f"{where}.tolerance", 1e-6, 1.0), cls.priority_of(raw, where))

    def bind(self, reference: Reference) -> None:
        self._id = reference.body.frame_id(self.effector)

    def objective(self, sym: Symbolic) -> ca.SX:
        return ca.sumsqr(self.held(sym))

    def held(self, sym: Symbolic) -> ca.SX:
        # Held per axis (|e_i| <= bound): a bound on the square would have a
        # zero gradient at the optimum, which interior-point solvers handle badly.
        return sym.kin.frame(self.effector)[1] - sym.goal

    def held_bounds(self, optimum: float) -> tuple[np.ndarray, np.ndarray]:
        # Lower tasks may trade reach error up to half the tolerance (per axis
        # tolerance / (2 sqrt 3), so the distance stays within tolerance / 2):
        # a hair's-breadth hold makes the lower programs hard to solve, and
        # millimetres of reach are worth a natural posture.
        b = max(np.sqrt(max(optimum, 0.0)) + self.slack, self.tolerance / (2.0 * np.sqrt(3.0)))
        return np.full(3, -b), np.full(3, b)

    def attained(self, optimum: float) -> bool:
        """Unreached, lower tasks cannot change the verdict: the engine stops."""
        return optimum <= self.tolerance**2

    def level(self, num: Numeric) -> Row:
        assert num.jacobian is not None
        err = num.goal - num.frame(self._id).translation
        dist = np.linalg.norm(err)
        # Clamp the target distance, so that a far goal does not drag the posture off the hard tasks.
        return Row(num.jacobian(self._id)[:3], err * min(1.0, num.max_reach_step / dist) if dist > 0 else err)

    def residual(self, num: Numeric) -> float:
        """Distance [m] from the effector to the goal."""
        return float(np.linalg.norm(num.frame(self._id).translation - num.goal))

    def holds(self, num: Numeric) -> bool:
        return self.residual(num) <= self.tolerance
