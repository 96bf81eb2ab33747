"""Look at the goal: ``{type: gaze, frame: eyes, priority: 2}``.

The frame's x axis points at the goal. Its objective is 1 - cos of the
angle between them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from oracles.tasks.base import Numeric, Reference, Row, Scope, SoftTask, Symbolic, frame


@dataclass
class GazeTask(SoftTask):
    """Point a frame's x axis (the eyes') at the goal."""

    type: ClassVar[str] = "gaze"
    keys: ClassVar[frozenset[str]] = frozenset({"frame"})
    summary: ClassVar[str] = "the x axis of `frame` (default the `eyes`) at the goal"
    default_priority: ClassVar[int] = 2
    slack: ClassVar[float] = 1e-4  # [1 - cos of the gaze error]: about 0.8 deg from a perfect aim

    frame: str
    priority: float = 2.0
    _id: int = field(default=-1, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> GazeTask:
        return cls(frame(scope, raw.get("frame", "eyes"), f"{where}.frame"), cls.priority_of(raw, where))

    def bind(self, reference: Reference) -> None:
        self._id = reference.body.frame_id(self.frame)

    def objective(self, sym: Symbolic) -> ca.SX:
        rot, pos = sym.kin.frame(self.frame)
        to_goal = sym.goal - pos
        return 1.0 - ca.dot(rot[:, 0], to_goal) / (ca.norm_2(to_goal) + 1e-9)

    def level(self, num: Numeric) -> Row:
        assert num.jacobian is not None
        eye = num.frame(self._id)
        d, u = eye.rotation[:, 0], num.goal - eye.translation
        return Row(num.jacobian(self._id)[3:], np.cross(d, u / (np.linalg.norm(u) + 1e-9)))
