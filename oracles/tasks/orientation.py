"""The effector's orientation: an approach axis within a cone, or a full orientation within a tolerance.

Two forms (a hard task: the reach stage minimises the distance to the goal
with the orientation held, so a point is reachable only with it):

* ``{type: orientation, axis: z, direction: -z, cone: 5}``: the effector's
  ``axis`` (its own frame: ``x``, ``-z``, ... or ``[x, y, z]``) points within
  ``cone`` degrees of the world ``direction`` (the tool pointing down). The
  roll about the axis is free, as in capability maps (Zacharias, Borst &
  Hirzinger, "Capturing robot workspace structure: representing robot
  capabilities", IROS 2007).
* ``{type: orientation, rpy: [r, p, y], tolerance: 5}``: the effector
  frame's rotation in the world is within ``tolerance`` degrees (the angle
  of the rotation between them) of ``Rz(y) Ry(p) Rx(r)`` [rad].

Without ``direction`` (or ``rpy``) the task is *free*: the tree is the
position-only one, and only a goal that carries an orientation (a query's
``orientation``, the reachability index's directions) is held to it. A goal's
orientation replaces the configured one.

Both are one inequality row of ``casadi-ik``'s programs on a cosine (of the
axis angle, or of the rotation angle from the trace), whose target and
whether it applies are parameters of the program: one compiled program serves
every goal orientation. The default cone and tolerance, 5 deg, are a
modelling choice (a tool's approach, a palm turned down), not a measured
figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.bodies.urdf import AXES
from oracles.errors import TaskError
from oracles.tasks.base import BUFFER, Constraint, HardTask, Numeric, Reference, Row, Scope, Symbolic, number

LIMIT = 5.0  # [deg] default cone and tolerance (a modelling choice; see the module docstring)
CHECK = 1e-3  # [rad] the verdict's allowance beyond the cone (the solver holds the cosine to 1e-6)
INSIDE = 2e-3  # [rad] dls: how far inside the cone a violated row is pushed
OFF = 3.0  # added to the row when the goal carries no orientation and none is configured: cos >= -1 holds then


def _vector(value: Any, where: str) -> np.ndarray:
    """A unit vector from an axis name (``x``, ``-z``, ...) or three numbers."""
    if isinstance(value, str) and value in AXES:
        return np.array(AXES[value])
    if (isinstance(value, list) and len(value) == 3
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        and np.all(np.isfinite(value)) and np.linalg.norm(value) > 1e-9):
        v = np.asarray(value, float)
        return v / np.linalg.norm(v)  # type: ignore[no-any-return]
    raise TaskError(where, f"expected one of {', '.join(AXES)} or [x, y, z] (not zero), got {value!r}")


def rotation_to(axis: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """The least rotation (3, 3) taking unit ``axis`` onto unit ``direction``."""
    return np.asarray(pin.Quaternion.FromTwoVectors(np.asarray(axis, float),
                                                    np.asarray(direction, float)).toRotationMatrix())


@dataclass
class OrientationTask(HardTask):
    """Hold the effector's approach axis within a cone of a direction, or its rotation near a target."""

    type: ClassVar[str] = "orientation"
    # A goal's orientation: its rotation (9, column-major) and whether it applies (1) or not (0, a free task's
    # goal without one).
    target_key: ClassVar[str | None] = "orientation"
    target_size: ClassVar[int] = 10
    keys: ClassVar[frozenset[str]] = frozenset({"axis", "direction", "cone", "rpy", "tolerance"})
    summary: ClassVar[str] = ("the effector's `axis` (its frame; `x`, `-z` or [x, y, z]) within `cone` deg (default "
                              "5) of the world `direction`, or its rotation within `tolerance` deg of `rpy` [rad]; "
                              "without `direction`/`rpy`, only a goal's orientation (a query's, the reachability "
                              "index's) is held")

    effector: str
    axis: np.ndarray | None  # unit, in the effector's frame (axis form); None: the full form
    target: np.ndarray | None  # (3, 3) the configured goal rotation; None: free
    limit: float  # [rad] the cone or the tolerance
    _id: int = field(default=-1, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> OrientationTask:
        if "axis" in raw:
            for bad in ("rpy", "tolerance"):
                if bad in raw:
                    raise TaskError(f"{where}.{bad}", "an axis form takes axis, direction and cone; give rpy and "
                                                      "tolerance without axis")
            axis = _vector(raw["axis"], f"{where}.axis")
            target = (None if "direction" not in raw
                      else rotation_to(axis, _vector(raw["direction"], f"{where}.direction")))
            cone = number(raw.get("cone", LIMIT), f"{where}.cone", 0.5, 90.0)
            return cls(scope.effector, axis, target, math.radians(cone))
        for bad in ("direction", "cone"):
            if bad in raw:
                raise TaskError(f"{where}.{bad}", "direction and cone need axis (the effector's approach axis)")
        target = None
        if "rpy" in raw:
            rpy = raw["rpy"]
            if not (isinstance(rpy, list) and len(rpy) == 3
                    and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in rpy)):
                raise TaskError(f"{where}.rpy", f"expected [roll, pitch, yaw] [rad], got {rpy!r}")
            target = np.asarray(pin.rpy.rpyToMatrix(*(float(v) for v in rpy)))
        tolerance = number(raw.get("tolerance", LIMIT), f"{where}.tolerance", 0.5, 90.0)
        return cls(scope.effector, None, target, math.radians(tolerance))

    @property
    def free(self) -> bool:
        """Whether only a goal's own orientation is held (none is configured)."""
        return self.target is None

    def aim(self, direction: np.ndarray | None = None, rotation: np.ndarray | None = None) -> np.ndarray:
        """A goal's orientation as the (3, 3) rotation the task holds: from a world direction of the axis
        (axis form) or an effector rotation; raises ValueError for a direction given to the full form."""
        if rotation is not None:
            return np.asarray(rotation, float)
        if direction is None:
            raise ValueError("give a direction or a rotation")
        if self.axis is None:
            raise ValueError("this strategy's orientation task holds a full orientation (rpy); give a quaternion, "
                             "not a direction")
        d = np.asarray(direction, float)
        return rotation_to(self.axis, d / np.linalg.norm(d))

    def default_aim(self) -> np.ndarray:
        """The configured rotation, or the identity for a free task (then not applied)."""
        return np.eye(3) if self.target is None else self.target

    def targets(self, raw: np.ndarray | None, n: int) -> np.ndarray:
        """Goals' orientations, (n, 3) world directions of the axis or (n, 3, 3) effector rotations (None: the
        configured one, or none for a free task), as the programs' parameters: rotation (column-major) and 1 (0:
        none)."""
        if raw is None:
            aims, on = np.tile(self.default_aim(), (n, 1, 1)), float(not self.free)
        elif raw.shape == (n, 3):
            if not np.all(np.isfinite(raw)) or np.any(np.linalg.norm(raw, axis=1) < 1e-9):
                raise ValueError("directions must be finite and not zero")
            aims, on = np.array([self.aim(direction=d) for d in raw]).reshape(n, 3, 3), 1.0
        elif raw.shape == (n, 3, 3):
            if (not np.all(np.isfinite(raw))
                or np.abs(np.einsum("nij,nkj->nik", raw, raw) - np.eye(3)).max(initial=0.0) > 1e-6):
                raise ValueError("rotations must be orthonormal 3 x 3 matrices")
            aims, on = raw, 1.0
        else:
            raise ValueError(f"orientations have shape {raw.shape}, expected ({n}, 3) directions or ({n}, 3, 3) "
                             "rotations")
        return np.concatenate([np.transpose(aims, (0, 2, 1)).reshape(n, 9), np.full((n, 1), on)], axis=1)

    parametric: ClassVar[bool] = True  # the body enters only through the kinematics

    def bind(self, reference: Reference) -> None:
        self._id = reference.body.frame_id(self.effector)

    def describe(self) -> dict[str, Any]:
        out = {**super().describe(), "form": "axis" if self.axis is not None else "full",
               "limit_deg": round(math.degrees(self.limit), 3),
               "free": self.free}
        if self.axis is not None:
            out["axis"] = self.axis.round(6).tolist()
            if self.target is not None:
                out["direction"] = (self.target @ self.axis).round(6).tolist()
        elif self.target is not None:
            out["rpy"] = np.asarray(pin.rpy.matrixToRpy(self.target)).round(6).tolist()
        return out

    def _cosine(self, rot: Any, aim: Any) -> Any:
        """Cosine of the angle the task bounds (numpy or CasADi): the axis's to its direction, or the rotation's."""
        if self.axis is not None:
            a = self.axis.reshape(3, 1)
            return ca.dot(rot @ a, aim @ a) if isinstance(rot, ca.SX) else float((rot @ self.axis) @ (aim @ self.axis))
        if isinstance(rot, ca.SX):
            return (ca.trace(aim.T @ rot) - 1.0) / 2.0
        return float((np.trace(aim.T @ rot) - 1.0) / 2.0)

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        target = sym.targets[self.type]
        rot = sym.kin.frame(self.effector)[0]
        return [Constraint(self._cosine(rot,
                                        ca.reshape(target[:9], 3,
                                                   3)) - math.cos(self.limit) + OFF * (1.0 - target[9]), 0.0, np.inf)]

    def _aim_of(self, num: Numeric) -> np.ndarray | None:
        """The rotation the posture is held to: the goal's, else the configured one (None: nothing applies)."""
        target = num.targets.get(self.type)
        if target is None:
            return self.target
        return np.asarray(target[:9]).reshape(3, 3, order="F") if target[9] > 0.5 else None

    def angle(self, num: Numeric) -> float:
        """The angle [rad] the task bounds at a posture (0 when no orientation applies)."""
        aim = self._aim_of(num)
        if aim is None:
            return 0.0
        return float(np.arccos(np.clip(self._cosine(num.frame(self._id).rotation, aim), -1.0, 1.0)))

    def rows(self, num: Numeric) -> list[Row]:
        aim = self._aim_of(num)
        if aim is None:
            return []
        angle = self.angle(num)
        if angle < self.limit - BUFFER:
            return []
        assert num.jacobian is not None
        rot = num.frame(self._id).rotation
        if self.axis is not None:
            now, want = rot @ self.axis, aim @ self.axis
            turn = np.cross(now, want)
            norm = np.linalg.norm(turn)
            turn = turn / norm if norm > 1e-12 else np.cross(now, [1.0, 0.0, 0.0] if abs(now[0]) < 0.9
                                                             else [0.0, 1.0, 0.0])
        else:
            log = pin.log3(aim @ rot.T)  # world-frame rotation vector from the effector's rotation to the aim
            turn = log / max(np.linalg.norm(log), 1e-12)
        turn = turn / np.linalg.norm(turn)
        return [Row(num.jacobian(self._id)[3:], turn * max(angle - self.limit + INSIDE, 0.0))]

    def holds(self, num: Numeric) -> bool:
        return self.angle(num) <= self.limit + CHECK
