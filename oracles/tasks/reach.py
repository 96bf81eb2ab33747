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
# [m^2] Weight of the range-normalised displacement from a query's current
# posture in the reach stage: a move of a whole joint range costs as much as
# missing the goal by 1 cm, so the stage settles within about 0.02 mm of a
# goal it can reach (the pull balances twice the residual) and moves no joint
# it need not move.
PROXIMAL = 1e-4


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
        return cls(scope.effector, number(raw.get("tolerance", TOLERANCE), f"{where}.tolerance", 1e-6, 1.0),
                   cls.priority_of(raw, where))

    parametric: ClassVar[bool] = True  # the body enters only through the kinematics

    def bind(self, reference: Reference) -> None:
        self._id = reference.body.frame_id(self.effector)

    def objective(self, sym: Symbolic) -> ca.SX:
        f = self.measure(sym)
        if sym.start is not None and sym.start_weight is not None:
            # With the character's current posture (a query's `from`), move it
            # the least that reaches: from a posture a centimetre off, the
            # interior-point steps of a reach-only stage wandered into another
            # basin (knees, trunk twist) that the posture stage below, a local
            # search, then kept: 1-cm neighbours low in front jumped by more
            # than 10 deg in 8 of 289 pairs (demo atlas), none with this term.
            f += PROXIMAL * sym.start_weight * ca.sumsqr((sym.x - sym.start) / sym.span)
        return f

    def measure(self, sym: Symbolic) -> ca.SX:
        # The squared distance alone: the proximal term leaves the goal a
        # fraction of a millimetre off and must not loosen the later stages' hold.
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
