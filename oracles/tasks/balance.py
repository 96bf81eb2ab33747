"""Balance: ``{type: balance, margin: 0.02, support: [...], pelvis: false}``.

The centre of mass's ground projection stays inside the support polygon
shrunk by ``margin`` [m]. The polygon is the convex hull of the reference
ground positions of ``support`` frames, by default those the strategy's
feet or contacts tasks name. With ``pelvis: true`` the root joint's origin
(the generated human's mid-hip) stays over the polygon too: a person standing
on both feet keeps the pelvis over them (a modelling choice, not a measured
bound: without it the lowest straight-knee reach shifted the pelvis 21 cm
aside, past the feet, with the spine side-bent and twisted to their limits).
``pelvis: d`` (a number [m]) keeps it over the polygon and also within ``d``
of its reference position aside (world y: the generated human's left and
right), so that it may go back and forth (hips pushed back in a stoop) but
not sideways: the shipped human configs give 0.05, a bound for
goals straight ahead (a modelling choice, not a measured one).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
import pinocchio as pin
from scipy.spatial import ConvexHull

from oracles.errors import ModelError, TaskError
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
    Task,
    frames,
    number,
    world_point,
)

BALANCE_TOL = 1e-5  # [m] CoM beyond the shrunk polygon that the verdict accepts
ROOT_JOINT = 1  # Pinocchio's index of every body's floating root joint (oracles.bodies.body)


@dataclass
class BalanceTask(HardTask):
    """Keep the centre of mass over the shrunk support polygon."""

    type: ClassVar[str] = "balance"
    keys: ClassVar[frozenset[str]] = frozenset({"margin", "support", "pelvis"})
    summary: ClassVar[str] = ("the centre of mass's ground projection inside the support polygon of the feet, shrunk "
                              "by `margin` [m]; with `pelvis: true` the pelvis (the root's origin) over it too, and "
                              "with `pelvis: D` [m] also within D aside (world y) of where it stands")

    margin: float = 0.02
    polygon_frames: tuple[str, ...] = ()
    pelvis: bool = False
    aside: float | None = None  # [m] the pelvis's largest shift aside (world y) from its reference, when given
    #: Rows (a_x, a_y, c): a . p + c <= 0 inside the shrunk polygon.
    polygon: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), init=False, repr=False, compare=False)
    #: The unshrunk polygon's rows, for the pelvis.
    hull: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> BalanceTask:
        margin = number(raw.get("margin", 0.02), f"{where}.margin", 0.0, 0.5)
        given = frames(scope, raw["support"], f"{where}.support") if "support" in raw else ()
        pelvis = raw.get("pelvis", False)
        aside = None
        if not isinstance(pelvis, bool):
            aside = number(pelvis, f"{where}.pelvis", 0.0, 1.0)  # a distance [m]: true, and within it aside
            pelvis = True
        return cls(margin, given, pelvis, aside)

    def resolve(self, tasks: Sequence[Task], where: str) -> BalanceTask:
        support = self.polygon_frames or tuple(dict.fromkeys(f for t in tasks for f in t.support))
        if len(set(support)) < 3:
            raise TaskError(where, "balance needs a support polygon of 3 frames or more, got "
                                   f"{list(dict.fromkeys(support))}: give the feet task soles (each foot's corner "
                                   "frames; "
                                  "add them with the body's frames), a contacts task's support, or balance.support")
        return replace(self, polygon_frames=support)

    def bind(self, reference: Reference) -> None:
        pts = np.array([reference.placement(f).translation[:2] for f in self.polygon_frames])
        try:
            hull = ConvexHull(pts)
        except Exception as exc:  # scipy's QhullError for degenerate supports
            raise ModelError(f"support frames {list(self.polygon_frames)} do not span a polygon ({exc})") from exc
        self.polygon = hull.equations.copy()
        self.polygon[:, 2] += self.margin
        self.hull = hull.equations.copy()
        if self.aside is not None:
            y = float(reference.data.oMi[ROOT_JOINT].translation[1])  # the pelvis's y at the reference
            self.hull = np.vstack([self.hull, [[0.0, 1.0, -(y + self.aside)], [0.0, -1.0, y - self.aside]]])

    parametric: ClassVar[bool] = True

    def numbers(self) -> dict[str, np.ndarray]:
        return {"polygon": self.polygon, "hull": self.hull}

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        com = sym.kin.center_of_mass()
        polygon = sym.number(self, "polygon", self.polygon)
        out = [Constraint(polygon[:, :2] @ com[:2] + polygon[:, 2], -np.inf, 0.0)]
        if self.pelvis:
            root = world_point(sym, ROOT_JOINT, np.zeros(3))
            hull = sym.number(self, "hull", self.hull)
            out.append(Constraint(hull[:, :2] @ root[:2] + hull[:, 2], -np.inf, 0.0))
        return out

    def rows(self, num: Numeric) -> list[Row]:
        jcom = pin.jacobianCenterOfMass(num.model, num.data, num.q, False)[:2, num.columns]
        com = num.data.com[0][:2]
        viol = self.polygon[:, :2] @ com + self.polygon[:, 2]
        out = [Row(self.polygon[row, None, :2] @ jcom, np.array([min(0.0, -viol[row] - INSIDE)]))
               for row in np.nonzero(viol > -BUFFER)[0]]
        if self.pelvis and num.joint_jacobian is not None:
            jroot = num.joint_jacobian(ROOT_JOINT)[:2]
            over = self.hull[:, :2] @ num.data.oMi[ROOT_JOINT].translation[:2] + self.hull[:, 2]
            out += [Row(self.hull[row, None, :2] @ jroot, np.array([min(0.0, -over[row] - INSIDE)]))
                    for row in np.nonzero(over > -BUFFER)[0]]
        return out

    def holds(self, num: Numeric) -> bool:
        com = pin.centerOfMass(num.model, num.data, num.q, False)
        if np.any(self.polygon[:, :2] @ com[:2] + self.polygon[:, 2] > BALANCE_TOL):
            return False
        root = num.data.oMi[ROOT_JOINT].translation[:2]
        return not self.pelvis or bool(np.all(self.hull[:, :2] @ root + self.hull[:, 2] <= BALANCE_TOL))
