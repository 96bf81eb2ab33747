"""A locked belt: ``{type: tether, anchor: [x, y, z], frames: [sternum, left_shoulder], slack: 0.02}``.

A seat belt's retractor locks in a crash or a hard brake, and some drivers
and operators keep it locked: the webbing's length from its anchor (a
shoulder belt's D-ring on the pillar above the outboard shoulder) no longer
pays out. Each named frame on the chest then stays within its reference
distance from the anchor, plus ``slack`` [m] (the give of the webbing and
the clothes; 2 cm by default, a modelling choice). The chest may still turn
and slide under the belt, nearer the anchor. The verdict measures the
distances by Pinocchio's forward kinematics.

With ``buckle: [x, y, z]`` the belt is a shoulder belt's line: the webbing
runs from the anchor over the ``frames`` in the order given (the outboard
shoulder, then the sternum) to the buckle at the inboard hip, and its whole
length stays within its reference length plus ``slack``: the chest may move
along the belt or away from it towards the seat, not forward out of it (a
radius about the D-ring alone let the chest slide forward and down, and the
belted driver leaned 20 deg away from the reaching hand). The
string between two fixed points is the model; the webbing's friction on the
chest and the torso's compliance under it are not modelled.
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
    keys: ClassVar[frozenset[str]] = frozenset({"anchor", "frames", "slack", "buckle"})
    summary: ClassVar[str] = ("a locked belt: `frames` stay within their reference distance of `anchor` [m] plus "
                              "`slack` [m] (default 2 cm); with `buckle` [m], the webbing's length from the anchor "
                              "over the frames in order to the buckle")

    anchor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    held: tuple[str, ...] = ()
    slack: float = 0.02
    buckle: tuple[float, float, float] | None = None
    _length: dict[str, float] = field(default_factory=dict, init=False, repr=False, compare=False)
    _ids: dict[str, int] = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> TetherTask:
        point = _point(raw.get("anchor"), f"{where}.anchor", "the belt's anchor")
        buckle = None if raw.get("buckle") is None else _point(raw["buckle"], f"{where}.buckle", "the belt's buckle")
        if "frames" not in raw:
            raise TaskError(f"{where}.frames", "expected the frames the belt holds (e.g. [sternum, left_shoulder])")
        held = tuple(f for f in frames(scope, raw["frames"], f"{where}.frames") if scope.moves(f))
        if buckle is not None and len(held) != len(frames(scope, raw["frames"], f"{where}.frames")):
            raise TaskError(f"{where}.frames", "a belt with a buckle holds frames the strategy moves, every one (the "
                                               "webbing's path crosses them in order)")
        return cls(point, held, number(raw.get("slack", 0.02), f"{where}.slack", 0.0, 0.5), buckle)

    def path(self, points: list[Any]) -> Any:
        """The webbing's length from the anchor over the points to the buckle (numpy or CasADi)."""
        assert self.buckle is not None
        ends = [np.asarray(self.anchor), *points, np.asarray(self.buckle)]
        norm = ca.norm_2 if isinstance(points[0], (ca.SX, ca.MX)) else np.linalg.norm
        return sum(norm(ends[k + 1] - ends[k]) for k in range(len(ends) - 1))

    def bind(self, reference: Reference) -> None:
        self._ids = {f: reference.body.frame_id(f) for f in self.held}
        if self.buckle is not None:
            self._length = {"path": float(self.path([reference.placement(f).translation for f in self.held]))
                            + self.slack}
            return
        a = np.asarray(self.anchor)
        self._length = {f: float(np.linalg.norm(reference.placement(f).translation - a)) + self.slack
                        for f in self.held}

    parametric: ClassVar[bool] = True

    def numbers(self) -> dict[str, np.ndarray]:
        return {f"length.{k}": np.array([v]) for k, v in self._length.items()}

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        # the belt's length (the body's, at its reference) inside the row, its bound 0 for every body
        if self.buckle is not None:
            length = sym.number(self, "length.path", self._length["path"])
            return [Constraint(self.path([sym.kin.frame(f)[1] for f in self.held]) - length, -np.inf, 0.0)]
        a = ca.SX(np.asarray(self.anchor).reshape(3, 1))
        out = []
        for f in self.held:
            d = sym.kin.frame(f)[1] - a
            length = sym.number(self, f"length.{f}", self._length[f])
            out.append(Constraint(ca.dot(d, d) - length**2, -np.inf, 0.0))
        return out

    def rows(self, num: Numeric) -> list[Row]:
        assert num.jacobian is not None
        if self.buckle is not None:
            pts = [np.asarray(num.frame(self._ids[f]).translation) for f in self.held]
            past = float(self.path(pts)) - self._length["path"]
            if past <= -BUFFER:
                return []
            ends = [np.asarray(self.anchor), *pts, np.asarray(self.buckle)]
            grad = sum(_unit(ends[k + 1] - ends[k])[None, :] @ num.jacobian(self._ids[f])[:3]
                       - _unit(ends[k + 2] - ends[k + 1])[None, :] @ num.jacobian(self._ids[f])[:3]
                       for k, f in enumerate(self.held))
            return [Row(grad, np.array([min(0.0, -past - INSIDE)]))]
        out = []
        for f in self.held:
            d = num.frame(self._ids[f]).translation - np.asarray(self.anchor)
            n = float(np.linalg.norm(d))
            past = n - self._length[f]
            if past > -BUFFER:
                out.append(Row((d / n)[None, :] @ num.jacobian(self._ids[f])[:3], np.array([min(0.0, -past - INSIDE)])))
        return out

    def holds(self, num: Numeric) -> bool:
        if self.buckle is not None:
            return float(self.path([np.asarray(num.frame(self._ids[f]).translation) for f in self.held])) <= (
                self._length["path"] + TETHER_TOL)
        return all(float(np.linalg.norm(num.frame(self._ids[f]).translation - np.asarray(self.anchor)))
                   <= self._length[f] + TETHER_TOL
                   for f in self.held)


def _point(value: Any, key: str, what: str) -> tuple[float, float, float]:
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)):
        raise TaskError(key, f"expected [x, y, z] in metres ({what}, world frame), got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)
