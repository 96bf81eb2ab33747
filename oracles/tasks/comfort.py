"""Stay near the reference posture: ``{type: comfort, weight: 1.0, priority: 3}``.

The objective is the mean squared displacement of the active coordinates
from the reference posture, each normalised by its range, times ``weight``;
a zero weight disables the task.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from oracles.tasks.base import Numeric, Row, Scope, SoftTask, Symbolic, number

DLS_GAIN = 0.1  # dls: share of the displacement closed per iteration


@dataclass
class ComfortTask(SoftTask):
    """Minimise the range-normalised displacement from the reference posture."""

    type: ClassVar[str] = "comfort"
    keys: ClassVar[frozenset[str]] = frozenset({"weight"})
    summary: ClassVar[str] = "stay near the reference posture (range-normalised displacement, times `weight`)"
    default_priority: ClassVar[int] = 3
    slack: ClassVar[float] = 1e-6  # [objective units]

    weight: float = 1.0
    priority: float = 3.0

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> ComfortTask:
        return cls(number(raw.get("weight", 1.0), f"{where}.weight", 0.0, 1e6), cls.priority_of(raw, where))

    @property
    def inert(self) -> bool:
        return self.weight <= 0

    parametric: ClassVar[bool] = True  # the body enters only through the reference coordinates

    def objective(self, sym: Symbolic) -> ca.SX:
        nx = sym.x.numel()
        return self.weight * ca.sumsqr((sym.x - sym.x_ref) / sym.span) / max(nx, 1)

    def level(self, num: Numeric) -> Row:
        assert (num.columns is not None and num.joint_columns is not None and num.joint_q is not None
                and num.x_ref is not None)
        select = np.zeros((num.joint_columns.size, num.columns.size))
        select[np.arange(num.joint_columns.size), num.joint_columns] = 1.0
        return Row(DLS_GAIN * select, DLS_GAIN * (num.x_ref[num.joint_columns] - num.q[num.joint_q]))
