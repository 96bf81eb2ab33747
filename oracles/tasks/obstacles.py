"""Static boxes in the world: ``{type: obstacles, boxes: [{min: [x, y, z], max: [x, y, z], rpy: [r, p, y]}], margin:
0.01}``.

A table, a wall, a shelf: boxes [m] in the world frame (axis-aligned, or
turned about their centre by ``rpy`` [rad]), and the body's own furniture
(a seated body's seat, :mod:`oracles.bodies.seat`: ``boxes`` may then be left out), that
every collision capsule moved by an active joint keeps ``margin`` [m] away
from (spheres along the capsule's axis kept out of the box grown by their
radius; a lazy task, see :class:`~oracles.tasks.base.HardTask`). A capsule already closer at the reference posture (a
robot's base link on its table) keeps its reference clearance instead. The verdict is
coal's distance between the capsules and the boxes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import coal
import numpy as np
import pinocchio as pin

from oracles.bodies.collision import CollisionModel
from oracles.bodies.environment import Box, parse_box
from oracles.errors import TaskError
from oracles.tasks.base import (
    BUFFER,
    Constraint,
    Cut,
    HardTask,
    Numeric,
    Reference,
    Row,
    Scope,
    Symbolic,
    moved,
    number,
    rows_of_cuts,
)
from oracles.tasks.self_collision import CHECK_TOL, MARGIN


@dataclass(frozen=True)
class Guard:
    """A capsule kept from a box by ``clearance`` [m]; ``floor`` is the least coal distance the verdict accepts."""

    capsule: int
    box: int
    clearance: float
    floor: float


@dataclass
class ObstaclesTask(HardTask):
    """Keep every moving segment out of static boxes."""

    type: ClassVar[str] = "obstacles"
    lazy: ClassVar[bool] = True
    keys: ClassVar[frozenset[str]] = frozenset({"boxes", "margin"})
    summary: ClassVar[str] = ("every moving segment `margin` [m] (default 1 cm) away from static `boxes` (a table, "
                              "a wall, a shelf) and the body's seat")

    boxes: tuple[Box, ...] = ()
    margin: float = MARGIN
    guards: tuple[Guard, ...] = ()
    _model: CollisionModel | None = field(default=None, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> ObstaclesTask:
        boxes_raw = raw.get("boxes", [])
        furniture = scope.body.furniture
        if not isinstance(boxes_raw, list) or not (boxes_raw or furniture):
            raise TaskError(f"{where}.boxes", f"expected a non-empty list of boxes, got {boxes_raw!r}")
        boxes = tuple(parse_box(b, f"{where}.boxes[{k}]") for k, b in enumerate(boxes_raw)) + furniture
        margin = number(raw.get("margin", MARGIN), f"{where}.margin", 0.0, 0.2)
        model = scope.body.collision
        if not model.placed:
            raise TaskError(where, f"{scope.body.source}: the body has no collision geometry")
        task = cls(boxes, margin)
        guards = []
        for i, p in enumerate(model.placed):
            if not moved(scope.body.model, p.joint, scope.active):
                continue
            sag = p.radius - float(np.sqrt(max(p.radius**2 - (0.5 * p.radius) ** 2, 0.0)))
            for k in range(len(boxes)):
                d = task.distance(model, scope.body.q_ref, i, k)
                clearance = margin if d >= margin + sag else min(margin, d - sag)
                guards.append(Guard(i, k, clearance, min(0.0, clearance - sag) - CHECK_TOL))
        task.guards = tuple(guards)
        return task

    def bind(self, reference: Reference) -> None:
        self._model = reference.body.collision

    def distance(self, model: CollisionModel, q: np.ndarray, capsule: int, box: int,
                 data: pin.Data | None = None) -> float:
        """Coal's distance [m] between a capsule at q and a box (``data``: joint placements at q already computed)."""
        if data is None:
            data = model.model.createData()
            pin.forwardKinematics(model.model, data, q)
        obj = model.geometry.geometryObjects[capsule]
        placement = data.oMi[obj.parentJoint] * obj.placement
        b = self.boxes[box]
        request, result = coal.DistanceRequest(), coal.DistanceResult()
        return float(coal.distance(obj.geometry, coal.Transform3s(placement.rotation, placement.translation),
                                   coal.Box(*(2 * b.half)), coal.Transform3s(b.matrix, b.centre), request, result))

    # nothing of the body's in the programs: the task is lazy, its cuts are numbers of each call
    parametric: ClassVar[bool] = True

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        return []  # lazy: see cuts

    def cuts(self, num: Numeric, within: float) -> list[Cut]:
        assert self._model is not None
        out = []
        for g in self.guards:
            p, box = self._model.placed[g.capsule], self.boxes[g.box]
            a, b = self._model.world(num.data, g.capsule)
            for t in np.linspace(0.0, 1.0, len(p.capsule.samples())):
                c = a + t * (b - a)
                gap, n = box.outside(c)
                if gap - p.radius < g.clearance + within:
                    out.append(Cut(n @ num.point_jacobian(p.joint, c), gap - p.radius, g.clearance))
        return out

    def rows(self, num: Numeric) -> list[Row]:
        return rows_of_cuts(self.cuts(num, BUFFER))

    def holds(self, num: Numeric) -> bool:
        assert self._model is not None
        # num.data holds the joint placements at num.q: one forward kinematics for every guard.
        return all(self.distance(self._model, num.q, g.capsule, g.box, num.data) >= g.floor for g in self.guards)
