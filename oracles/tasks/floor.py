"""The floor: ``{type: floor, exclude: ["*_foot"]}``.

No body point below z = 0 but the soles: every collision capsule that an
active joint moves keeps both end points at least its radius above the
floor, so its lowest point stays on or above it. ``exclude`` names capsules
(glob patterns) that may touch the floor; by default the feet, which stand
on it.

The task is *lazy* (see :class:`~oracles.tasks.base.HardTask`) but for the
effector's own segment: ``casadi-ik``'s programs hold the effector's
capsule (the hand, for a floor goal) as constraint rows, and the other
segments only by cuts, when a posture puts one through the floor. The 30
rows of the human's whole body (two per moving capsule) bind only for goals
near the floor, yet as constraints of every program they cost each fatrop
iteration (replayed D_max 7 whole-body vertices, one process: 4.96 against
4.49 ms per goal, the reach stage 2.69 against 2.21 ms, same verdicts).
The effector's rows stay exact: for a goal at the floor, cuts on the hand,
which turns about the goal, chased a 3 mm overshoot from end to end and
missed reachable goals.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from oracles.bodies.collision import CollisionModel
from oracles.errors import TaskError
from oracles.tasks.base import (
    BUFFER,
    INSIDE,
    Constraint,
    Cut,
    HardTask,
    Numeric,
    Reference,
    Row,
    Scope,
    Symbolic,
    Task,
    moved,
    world_point,
)
from oracles.tasks.contacts import CONTACT_TOL

FEET = ["*_foot"]


@dataclass
class FloorTask(HardTask):
    """Keep every moving segment above the floor z = 0."""

    type: ClassVar[str] = "floor"
    lazy: ClassVar[bool] = True
    keys: ClassVar[frozenset[str]] = frozenset({"exclude"})
    summary: ClassVar[str] = "no body point below the floor z = 0 but the feet (`exclude`: capsules that may touch it)"

    capsules: tuple[int, ...] = ()
    eager: tuple[int, ...] = ()  # the effector's capsules: constraint rows, not cuts
    # no exclude given: the segments that hold the strategy's contacts stand on the floor (see resolve)
    standing: bool = False
    _model: CollisionModel | None = field(default=None, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> FloorTask:
        model = scope.body.collision
        exclude = raw.get("exclude", FEET if any(n.endswith("_foot") for n in model.index) else [])
        if not isinstance(exclude, list) or not all(isinstance(e, str) for e in exclude):
            raise TaskError(f"{where}.exclude", f"expected a list of capsule names or patterns, got {exclude!r}")
        try:
            skip = set(model.names(exclude))
        except Exception as exc:
            raise TaskError(f"{where}.exclude", str(exc)) from exc
        keep = [i for i, p in enumerate(model.placed) if p.name not in skip
                and moved(scope.body.model, p.joint, scope.active)]
        effector = int(scope.body.model.frames[scope.body.frame_id(scope.effector)].parentJoint)
        return cls(tuple(keep), tuple(i for i in keep if model.placed[i].joint == effector), "exclude" not in raw,
                   scope.body.collision)

    def resolve(self, tasks: Sequence[Task], where: str) -> FloorTask:
        """Without ``exclude``, the capsules on the segments holding a contacts or feet task's frames (a robot's
        feet, whatever their names) stand on the floor too."""
        if not self.standing or self._model is None:
            return self
        pm = self._model.model
        feet = {int(pm.frames[pm.getFrameId(f)].parentJoint) for t in tasks for f in t.held_frames}
        keep = tuple(i for i in self.capsules if self._model.placed[i].joint not in feet)
        return replace(self, capsules=keep, eager=tuple(i for i in self.eager if i in keep))

    def bind(self, reference: Reference) -> None:
        self._model = reference.body.collision

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        return self._heights(sym, self.eager)

    def screened(self, sym: Symbolic) -> list[Constraint]:
        """The other moving capsules' end points at least their radius above the floor."""
        return self._heights(sym, [i for i in self.capsules if i not in self.eager])

    parametric: ClassVar[bool] = True

    def numbers(self) -> dict[str, np.ndarray]:
        assert self._model is not None
        return {f"{key}{i}": np.atleast_1d(v) for i in self.capsules
                for key, v in (("a", self._model.placed[i].a), ("b", self._model.placed[i].b),
                               ("radius", self._model.placed[i].radius))}

    def _heights(self, sym: Symbolic, capsules: Sequence[int]) -> list[Constraint]:
        """Each capsule's end points' heights above its radius, at least 0 (the radius in the row, not its bound: a
        row's bounds are the same for every body, :mod:`oracles.ik.parameters`)."""
        assert self._model is not None
        out = []
        for i in capsules:
            p = self._model.placed[i]
            ends = [world_point(sym, p.joint, sym.number(self, f"{key}{i}", e))[2]
                    for key, e in (("a", p.a), ("b", p.b))]
            out.append(Constraint(ca.vertcat(*ends) - sym.number(self, f"radius{i}", p.radius), 0.0, np.inf))
        return out

    def cuts(self, num: Numeric, within: float) -> list[Cut]:
        assert self._model is not None
        out = []
        for i in self.capsules:
            if i in self.eager:
                continue
            p = self._model.placed[i]
            for end in self._model.world(num.data, i):
                if end[2] - p.radius < within:
                    out.append(Cut(num.point_jacobian(p.joint, end)[2], float(end[2]), p.radius))
        return out

    def rows(self, num: Numeric) -> list[Row]:
        assert self._model is not None
        out = []
        for i in self.capsules:
            p = self._model.placed[i]
            for end in self._model.world(num.data, i):
                if end[2] - p.radius < BUFFER:
                    out.append(Row(num.point_jacobian(p.joint, end)[2:3],
                                   np.array([max(0.0, p.radius + INSIDE - end[2])])))
        return out

    def holds(self, num: Numeric) -> bool:
        assert self._model is not None
        return self._model.above_floor(num.q, self.capsules, CONTACT_TOL)
