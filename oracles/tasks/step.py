"""A step: ``{type: step, foot: right_foot, stance: left_foot, forward: [0, L], aside: [-0.1, 0.1], turn: 30}``.

One foot leaves its place and is set down flat on the floor within a step
region; the other (the ``stance`` foot, held where it stands by the
strategy's ``feet`` task) stays. The stepping foot's place is part of the
search: its frame keeps its standing height and stays flat (its vertical
axis vertical), lands ``forward`` [m] ahead of where it stood (world x, the
body's facing) and ``aside`` [m] across (world y), turned at most ``turn``
[deg] about the vertical. Balance is over the new support: the centre of
mass's ground projection inside the polygon of both feet, shrunk by
``margin`` [m].

The verdict checks that polygon exactly: the convex hull of both feet's
heel and toe corners where the posture puts them (scipy). The search holds
a smaller one, inside it whatever the step: the quadrilateral of the two
feet's centrelines, each from heel to toe with its ends moved in by
``margin`` (every point of it lies ``margin`` or more inside its foot, so
their hull lies inside the feet's hull shrunk by ``margin``), so that its
rows stay smooth while the polygon's corners move (the hull of moving
points changes its edges).

Defaults. ``forward``: from 0 to 0.41 times the stature, the low end of
the walking step length by stature that pedometers are set with (41-45 %
of stature; biologyinsights.com, "What is my step length by height", a
secondary source: no gait study read here) and reached from standing in a
single step. ``aside`` +-0.10 m and ``turn`` 30 deg: modelling choices,
not measured (no source on how far a reaching step turns the foot was
read here). A strategy with a step carries no ``balance`` task (the step
holds its own), and its ``feet`` task holds the stance foot alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np
import pinocchio as pin
from scipy.spatial import ConvexHull

from oracles.errors import TaskError
from oracles.tasks.balance import BALANCE_TOL
from oracles.tasks.base import BUFFER, INSIDE, Constraint, HardTask, Numeric, Reference, Row, Scope, Symbolic, Task
from oracles.tasks.base import frame as one_frame
from oracles.tasks.contacts import ANGLE_TOL, CONTACT_TOL
from oracles.tasks.feet import DOWN_SUPPORT, _side_frames

STEP_OF_STATURE = 0.41  # the step region's forward reach, a share of stature (see the module docstring)
ASIDE = 0.10  # [m] how far across the stepping foot may land (a modelling choice)
TURN = 30.0  # [deg] how far the stepping foot may turn about the vertical (a modelling choice)
REGION_TOL = 1e-6  # [m or cos] a region bound this far past still holds (the programs' tolerance)


def _pair(value: Any, where: str) -> tuple[float, float]:
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value) or value[0] > value[1]):
        raise TaskError(where, f"expected [low, high] in metres, low <= high, got {value!r}")
    return float(value[0]), float(value[1])


@dataclass
class StepTask(HardTask):
    """One foot set down flat within a step region, balance over the new support (see the module docstring)."""

    type: ClassVar[str] = "step"
    keys: ClassVar[frozenset[str]] = frozenset({"foot", "stance", "forward", "aside", "turn", "margin"})
    summary: ClassVar[str] = ("one foot (`foot`) set down flat on the floor within a step region (`forward`, `aside` "
                              "[m] from where it stood, turned at most `turn` deg), the `stance` foot kept; the centre "
                              "of mass over both feet's new polygon shrunk by `margin` [m]")

    foot: str = "right_foot"
    stance: str = "left_foot"
    forward: tuple[float, float] = (0.0, 0.7)
    aside: tuple[float, float] = (-ASIDE, ASIDE)
    turn: float = math.radians(TURN)
    margin: float = 0.02
    corners: tuple[str, ...] = ()  # the stepping foot's heel_inner, heel_outer, toe_inner, toe_outer
    stance_corners: tuple[str, ...] = ()
    _ref: pin.SE3 = field(default_factory=pin.SE3.Identity, init=False, repr=False, compare=False)
    _stance_line: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)), init=False, repr=False, compare=False)
    _length: float = field(default=1.0, init=False, repr=False, compare=False)
    _ccw: bool = field(default=True, init=False, repr=False, compare=False)
    _ids: dict[str, int] = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> StepTask:
        if raw.get("foot") == "either":
            raise TaskError(f"{where}.foot", "one stepping foot a strategy: for either foot give two strategies at one "
                                             "priority, each with its foot (configs/human.yaml's right_step and "
                                             "right_cross_step; the selector takes the first that reaches)")
        foot = one_frame(scope, raw.get("foot", "right_foot"), f"{where}.foot")
        stance = one_frame(scope, raw.get("stance", "left_foot" if foot != "left_foot" else "right_foot"),
                           f"{where}.stance")
        if foot == stance:
            raise TaskError(f"{where}.stance", f"expected the other foot than the stepping one, got {stance!r}")
        corners = _side_frames(scope, foot, DOWN_SUPPORT)
        stance_corners = _side_frames(scope, stance, DOWN_SUPPORT)
        if len(corners) != 4 or len(stance_corners) != 4:
            raise TaskError(where, f"a step needs each foot's heel and toe corners ({foot}: {corners}, {stance}: "
                                   f"{stance_corners}); the generated human has them")
        anthro = scope.body.anthropometry
        # a URDF body has no stature: its step region is the config's (0.7 m ahead by default)
        default_forward = [0.0, round(STEP_OF_STATURE * anthro.stature, 3)] if anthro is not None else [0.0, 0.7]
        forward = _pair(raw.get("forward", default_forward), f"{where}.forward")
        aside = _pair(raw.get("aside", [-ASIDE, ASIDE]), f"{where}.aside")
        turn = raw.get("turn", TURN)
        if not isinstance(turn, (int, float)) or isinstance(turn, bool) or not 0.0 <= turn < 90.0:
            raise TaskError(f"{where}.turn", f"expected degrees from 0 to under 90, got {turn!r}")
        margin = raw.get("margin", 0.02)
        if not isinstance(margin, (int, float)) or isinstance(margin, bool) or not 0.0 <= margin < 0.05:
            raise TaskError(f"{where}.margin", f"expected metres from 0 to under 0.05, got {margin!r}")
        return cls(foot, stance, forward, aside, math.radians(float(turn)), float(margin), tuple(corners),
                   tuple(stance_corners))

    def resolve(self, tasks: Sequence[Task], where: str) -> StepTask:
        if any(t.type == "balance" for t in tasks):
            raise TaskError(where, "a step holds its own balance over the new support: remove the strategy's balance "
                                   "task")
        if any(self.foot in t.held_frames for t in tasks if t is not self):
            raise TaskError(where, f"another task holds the stepping foot {self.foot!r} where it stands: give the "
                                   f"feet task frames: [{self.stance}]")
        return self

    def bind(self, reference: Reference) -> None:
        self._ref = reference.placement(self.foot)
        self._ids = {f: reference.body.frame_id(f) for f in (self.foot, *self.corners, *self.stance_corners)}
        pts = {f: reference.placement(f).translation[:2] for f in (*self.corners, *self.stance_corners)}
        step_heel, step_toe, width = _line([pts[f] for f in self.corners])
        self._length = float(np.linalg.norm(step_toe - step_heel))
        heel, toe, stance_width = _line([pts[f] for f in self.stance_corners])
        if 0.5 * min(width, stance_width) < self.margin:
            raise TaskError("step.margin", f"the feet are {min(width, stance_width):.3f} m wide: a margin of "
                                           f"{self.margin} m leaves no polygon")
        # Each foot's centreline, its ends moved in by the margin: every point of it lies the margin or more inside its
        # foot (half the foot's width from its sides), so the quadrilateral of the two lies inside both feet's hull
        # shrunk by the margin, which the verdict checks. A smaller inset put its corners outside that polygon on
        # narrow feet, where searches then ended unreached (docs/results.md).
        d = (toe - heel) / np.linalg.norm(toe - heel)
        self._stance_line = np.array([heel + self.margin * d, toe - self.margin * d])
        # the quadrilateral's corners in counterclockwise order: the stance foot to the stepping foot's left or right
        side = step_toe - step_heel
        other = self._stance_line[0] - step_heel
        self._ccw = bool(side[0] * other[1] - side[1] * other[0] > 0)

    @property
    def stood(self) -> pin.SE3:
        """Where the stepping foot stood: its frame's placement at the reference posture."""
        return self._ref

    # -- the search's rows -------------------------------------------------
    def constraints(self, sym: Symbolic) -> list[Constraint]:
        rot, pos = sym.kin.frame(self.foot)
        ref = self._ref
        # the foot's local axes that point up and ahead (world z and x) where it stood
        up = rot @ ca.SX(ref.rotation.T @ np.array([0.0, 0.0, 1.0]))
        ahead = rot @ ca.SX(ref.rotation.T @ np.array([1.0, 0.0, 0.0]))
        out = [Constraint(ca.vertcat(pos[2] - ref.translation[2], up[0], up[1]), 0.0, 0.0),
               Constraint(pos[0] - ref.translation[0], self.forward[0], self.forward[1]),
               Constraint(pos[1] - ref.translation[1], self.aside[0], self.aside[1]),
               Constraint(ahead[0], math.cos(self.turn), np.inf)]
        corners = [sym.kin.frame(f)[1][:2] for f in self.corners]
        heel, toe = 0.5 * (corners[0] + corners[1]), 0.5 * (corners[2] + corners[3])
        d = (toe - heel) / self._length
        a, b = (ca.SX(p.reshape(2, 1)) for p in self._stance_line)
        step_heel, step_toe = heel + self.margin * d, toe - self.margin * d
        quad = [step_heel, step_toe, b, a] if self._ccw else [step_toe, step_heel, a, b]
        com = sym.kin.center_of_mass()[:2]
        for k in range(4):
            v, w = quad[k], quad[(k + 1) % 4]
            e = w - v
            out.append(Constraint(e[0] * (com[1] - v[1]) - e[1] * (com[0] - v[0]), 0.0, np.inf))
        return out

    # -- damped least squares' rows ---------------------------------------
    def rows(self, num: Numeric) -> list[Row]:
        assert num.jacobian is not None
        ref, fid = self._ref, self._ids[self.foot]
        cur, jac = num.frame(fid), num.jacobian(fid)
        up_local = ref.rotation.T @ np.array([0.0, 0.0, 1.0])
        up = cur.rotation @ up_local
        # the vertical axis's tilt: d(up) = omega x up, so its x and y rows are (-skew(up) @ J_w)[:2]
        tilt = (-pin.skew(up) @ jac[3:])[:2]
        out = [Row(jac[2:3], np.array([ref.translation[2] - cur.translation[2]])), Row(tilt, -up[:2])]
        for axis, (lo, hi) in ((0, self.forward), (1, self.aside)):
            off = cur.translation[axis] - ref.translation[axis]
            if off < lo + BUFFER:
                out.append(Row(jac[axis : axis + 1], np.array([max(0.0, lo + INSIDE - off)])))
            elif off > hi - BUFFER:
                out.append(Row(jac[axis : axis + 1], np.array([min(0.0, hi - INSIDE - off)])))
        return out + self._balance_rows(num)

    def _balance_rows(self, num: Numeric) -> list[Row]:
        """The quadrilateral's edges near or past the centre of mass, linearised: e x (c - v) >= 0 for each edge
        v -> w, the stepping foot's corners and the centre of mass moving with x (see :meth:`constraints`)."""
        assert num.jacobian is not None
        pos = [num.frame(self._ids[f]).translation[:2] for f in self.corners]
        jac = [num.jacobian(self._ids[f])[:2] for f in self.corners]
        heel, toe = 0.5 * (pos[0] + pos[1]), 0.5 * (pos[2] + pos[3])
        j_heel, j_toe = 0.5 * (jac[0] + jac[1]), 0.5 * (jac[2] + jac[3])
        k = self.margin / self._length
        step = [(heel + k * (toe - heel), j_heel + k * (j_toe - j_heel)),
                (toe - k * (toe - heel), j_toe - k * (j_toe - j_heel))]
        zero = np.zeros_like(j_heel)
        stance = [(self._stance_line[0], zero), (self._stance_line[1], zero)]
        quad = [step[0], step[1], stance[1], stance[0]] if self._ccw else [step[1], step[0], stance[0], stance[1]]
        com = pin.centerOfMass(num.model, num.data, num.q, False)[:2]
        j_com = pin.jacobianCenterOfMass(num.model, num.data, num.q, False)[:2, num.columns]
        out = []
        for (v, jv), (w, jw) in zip(quad, [*quad[1:], quad[0]], strict=True):
            e, je, r, jr = w - v, jw - jv, com - v, j_com - jv
            f = e[0] * r[1] - e[1] * r[0]
            if f < BUFFER:
                j_f = je[0] * r[1] + e[0] * jr[1] - je[1] * r[0] - e[1] * jr[0]
                out.append(Row(-j_f[None], np.array([min(0.0, f - INSIDE)])))
        return out

    # -- the verdict -------------------------------------------------------
    def holds(self, num: Numeric) -> bool:
        ref, cur = self._ref, num.frame(self._ids[self.foot])
        if abs(cur.translation[2] - ref.translation[2]) > CONTACT_TOL:
            return False
        up = cur.rotation @ (ref.rotation.T @ np.array([0.0, 0.0, 1.0]))
        if np.linalg.norm(up[:2]) > ANGLE_TOL:
            return False
        off = cur.translation - ref.translation
        if not (self.forward[0] - REGION_TOL <= off[0] <= self.forward[1] + REGION_TOL
                and self.aside[0] - REGION_TOL <= off[1] <= self.aside[1] + REGION_TOL):
            return False
        ahead = cur.rotation @ (ref.rotation.T @ np.array([1.0, 0.0, 0.0]))
        if ahead[0] < math.cos(self.turn) - REGION_TOL:
            return False
        corners = np.array([num.frame(self._ids[f]).translation[:2] for f in (*self.corners, *self.stance_corners)])
        hull = ConvexHull(corners).equations
        com = pin.centerOfMass(num.model, num.data, num.q, False)[:2]
        return bool(np.all(hull[:, :2] @ com + hull[:, 2] + self.margin <= BALANCE_TOL))

    def describe(self) -> dict[str, Any]:
        return {"type": self.type, "foot": self.foot, "stance": self.stance, "forward": list(self.forward),
                "aside": list(self.aside), "turn": round(math.degrees(self.turn), 6), "margin": self.margin}


def _line(corners: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, float]:
    """A foot's centreline from its corners (heel_inner, heel_outer, toe_inner, toe_outer): the heel's and toe's
    midpoints, and its width [m]."""
    heel, toe = 0.5 * (corners[0] + corners[1]), 0.5 * (corners[2] + corners[3])
    width = min(float(np.linalg.norm(corners[0] - corners[1])), float(np.linalg.norm(corners[2] - corners[3])))
    return heel, toe, width
