"""A locked belt: ``{type: tether, anchor: [x, y, z], frames: [sternum, left_shoulder], slack: 0.02}``.

A seat belt's retractor locks in a crash or a hard brake, and some drivers
and operators keep it locked: the webbing's length from its anchor (a
shoulder belt's D-ring on the pillar above the outboard shoulder) no longer
pays out. Each named frame on the chest then stays within its reference
distance from the anchor, plus ``slack`` [m] (the give of the webbing and
the clothes; 2 cm by default, a modelling choice). The chest may still turn
and slide under the belt, nearer the anchor. The verdict measures the
distances by Pinocchio's forward kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
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
    number,
)

TETHER_TOL = 1e-4  # [m] beyond the webbing's length that the verdict accepts


@dataclass
class TetherTask(HardTask):
    """Frames kept within their reference distance (plus slack) of an anchor."""

    type: ClassVar[str] = "tether"
    keys: ClassVar[frozenset[str]] = frozenset({"anchor", "frames", "slack"})
    summary: ClassVar[str] = ("a locked belt: `frames` stay within their reference distance of `anchor` [m] plus "
                              "`slack` [m] (default 2 cm)")

    anchor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    held: tuple[str, ...] = ()
    slack: float = 0.02
    _length: dict[str, float] = field(default_factory=dict, init=False, repr=False, compare=False)
    _ids: dict[str, int] = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> TetherTask:
        anchor = raw.get("anchor")
        if (not isinstance(anchor, list) or len(anchor) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in anchor)):
            raise TaskError(f"{where}.anchor", "expected [x, y, z] in metres (the belt's anchor, world frame), got "
                                               f"{anchor!r}")
        if "frames" not in raw:
            raise TaskError(f"{where}.frames", "expected the frames the belt holds (e.g. [sternum, left_shoulder])")
        held = tuple(f for f in frames(scope, raw["frames"], f"{where}.frames") if scope.moves(f))
        point = tuple(float(v) for v in anchor)
        return cls(point, held, number(raw.get("slack", 0.02), f"{where}.slack", 0.0, 0.5))  # type: ignore[arg-type]

    def bind(self, reference: Reference) -> None:
        a = np.asarray(self.anchor)
        self._length = {f: float(np.linalg.norm(reference.placement(f).translation - a)) + self.slack
                        for f in self.held}
        self._ids = {f: reference.body.frame_id(f) for f in self.held}

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        a = ca.SX(np.asarray(self.anchor).reshape(3, 1))
        out = []
        for f in self.held:
            d = sym.kin.frame(f)[1] - a
            out.append(Constraint(ca.dot(d, d), -np.inf, self._length[f] ** 2))
        return out

    def rows(self, num: Numeric) -> list[Row]:
        assert num.jacobian is not None
        out = []
        for f in self.held:
            d = num.frame(self._ids[f]).translation - np.asarray(self.anchor)
            n = float(np.linalg.norm(d))
            past = n - self._length[f]
            if past > -BUFFER:
                out.append(Row((d / n)[None, :] @ num.jacobian(self._ids[f])[:3], np.array([min(0.0, -past - INSIDE)])))
        return out

    def holds(self, num: Numeric) -> bool:
        return all(float(np.linalg.norm(num.frame(self._ids[f]).translation - np.asarray(self.anchor)))
                   <= self._length[f] + TETHER_TOL
                   for f in self.held)
