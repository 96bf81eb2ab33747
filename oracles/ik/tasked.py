"""A body under a strategy: what its tasks say of postures and of the volume, without a search.

The oracle protocol's capabilities that need the strategy but no solve
(:mod:`oracles.protocol`): the reach ball, the free turn, the floor, the
furniture and the keep-out capsules, the independent check of postures, the
hard tasks a posture breaks, the limits it comes near, and what the spec
will likely get wrong. :class:`oracles.ik.oracle.IKOracle` adds the search.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pinocchio as pin

from oracles.bodies.body import Body
from oracles.bodies.posed import PosedBody
from oracles.bodies.urdf import ROOT
from oracles.ik import balancing
from oracles.ik.problem import ReachProblem
from oracles.ik.search import Search
from oracles.ik.solvers.dls import DampedLeastSquares
from oracles.ik.stepping import LEG_ITER, chain, planted, swing_frames
from oracles.ik.strategy import Strategy
from oracles.protocol import Ball, check_points
from oracles.tasks import BalanceTask, ContactsTask, FloorTask, Numeric, ObstaclesTask, OrientationTask, StepTask

# tasks that hold something fixed in the world, which a turn would move
WORLD_FIXED = frozenset({"obstacles", "tether"})


class TaskedBody(PosedBody):
    """A body, a strategy on it and its reach problem (see the module docstring).

    Args:
        body: The body.
        strategy: The strategy parsed on it.
        spec: The body's spec as given (``reference: auto`` is reported by :meth:`describe`).
        strategy_params: The strategy's spec (body, effector, joints, tasks).
    """

    search: Search  # the oracle's (oracles.ik.oracle.IKOracle), which its solvers read here
    stats: dict[str, int]

    def __init__(self, body: Body, strategy: Strategy, spec: dict[str, Any], strategy_params: dict[str, Any]) -> None:
        super().__init__(body, strategy.effector, _anchor(body, strategy))
        self.strategy = strategy
        self.problem = ReachProblem(body, strategy)
        self.posture_names = tuple(body.q_names)
        self._body_spec = spec
        self.strategy_params = strategy_params
        # the damped least squares that hold a posture's hard tasks (made on first use)
        self._projector: DampedLeastSquares | None = None

    def use_reference(self, q: np.ndarray) -> None:
        """Make ``q`` the reference posture (every search's start, the contacts' places)."""
        self.body = dataclasses.replace(self.body, q_ref=np.asarray(q, float).copy())
        self.problem = ReachProblem(self.body, self.strategy)

    def reach_bound(self) -> Ball | None:
        """A fixed point and the most the effector can be from it [m], or None when unbounded."""
        p = self.problem
        if p.anchor is None or not np.isfinite(p.max_reach):
            return None
        return Ball(p.anchor.copy(), float(p.max_reach))

    def free_turn(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The first active joint's axis when the volume turns freely about it (see
        :class:`oracles.protocol.Turning`)."""
        if self.body.furniture or any(t.type in WORLD_FIXED for t in self.strategy.tasks):
            return None
        turn = base_turn(self.body, self.strategy, self.problem)
        if turn is not None and self.strategy.task("floor") is not None and abs(turn[1][2]) < 1 - 1e-9:
            return None  # a floor turns with a vertical axis only
        return turn

    def quarter_turn(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The first active joint's axis when it is vertical and a quarter turn about it maps the volume onto itself
        (see :class:`oracles.protocol.QuarterTurning`): every box the world holds fixed is a square about it."""
        if any(t.type in WORLD_FIXED and not isinstance(t, ObstaclesTask) for t in self.strategy.tasks):
            return None  # a belt's anchor
        turn = base_turn(self.body, self.strategy, self.problem)
        if turn is None or abs(turn[1][2]) < 1 - 1e-9:
            return None
        point = turn[0]
        task = self.strategy.task("obstacles")
        boxes = [*self.body.furniture, *(task.boxes if isinstance(task, ObstaclesTask) else ())]
        for box in boxes:
            square = abs(box.half[0] - box.half[1]) <= 1e-9 and np.allclose(box.matrix[:, 2], [0, 0, 1], atol=1e-12)
            if not (square and np.allclose(box.centre[:2], point[:2], atol=1e-9)):
                return None
        return turn

    def turned(self, postures: np.ndarray, quarters: np.ndarray) -> np.ndarray:
        """Postures (N, nq) with the first active joint turned by quarters (N,) x 90 deg anticlockwise about +z (see
        :meth:`quarter_turn`), within its range."""
        model = self.body.model
        jm = model.joints[min(self.problem.joint_ids)]
        lo, hi = model.lowerPositionLimit[jm.idx_q], model.upperPositionLimit[jm.idx_q]
        out = np.array(postures, float, copy=True)
        turn = base_turn(self.body, self.strategy, self.problem)
        assert turn is not None, "turned() needs a quarter turn"
        angle = np.asarray(quarters, float) * (np.pi / 2) * np.sign(turn[1][2])
        k = jm.idx_q
        if jm.nq == 2:  # an unbounded revolute joint, stored as (cos, sin)
            theta = np.arctan2(out[:, k + 1], out[:, k]) + angle
            out[:, k], out[:, k + 1] = np.cos(theta), np.sin(theta)
            return out
        q = out[:, k] + angle
        # its range spans a full turn or more: a turn of 2 pi brings any angle within it
        q = np.where(q > hi, q - 2 * np.pi, q)
        out[:, k] = np.where(q < lo, q + 2 * np.pi, q)
        return out

    def lowest(self) -> float | None:
        """0 when a floor task holds the effector's own capsule above z = 0 (the effector lies inside it), else None."""
        floor = self.strategy.task("floor")
        return 0.0 if isinstance(floor, FloorTask) and floor.eager else None

    def furniture(self) -> tuple[list[str], np.ndarray]:
        """The body's seat and the obstacles task's boxes (see :class:`oracles.protocol.Furnished`)."""
        task = self.strategy.task("obstacles")
        boxes = list(dict.fromkeys([*self.body.furniture, *(task.boxes if isinstance(task, ObstaclesTask) else ())]))
        return [b.name or f"box{i}" for i, b in enumerate(boxes)], np.array([b.as_row() for b in boxes]).reshape(-1, 10)

    def keep_out(self) -> np.ndarray:
        """Capsules (K, 7) that hold no reachable point: the static segments the effector may not enter."""
        out = [c for t in self.strategy.hard for c in t.keep_out()]
        return np.array(out, float).reshape(-1, 7)

    def verify(self, points: np.ndarray, postures: np.ndarray) -> np.ndarray:
        """The verdict's own check (Pinocchio forward kinematics, every hard task) of postures found elsewhere."""
        pts = check_points(points, 3)
        return np.array([self.problem.check(np.asarray(q, float), g, self._data).reachable
                         for g, q in zip(pts, postures, strict=True)], bool)

    def faults(self, postures: np.ndarray) -> list[list[str]]:
        """The joints outside their ranges and the hard tasks a posture breaks, by each task's own check."""
        model, data, p = self.body.model, self._data, self.problem
        out = []
        for q in np.atleast_2d(np.asarray(postures, float)):
            pin.framesForwardKinematics(model, data, q)
            num = Numeric(model, data, q, data.oMf[p.effector_id].translation.copy())
            out.append(p.out_of_limits(q) + [t.type for t in self.strategy.hard if not t.holds(num)])
        return out

    def limits_near(self, posture: np.ndarray, margin: float) -> list[str]:
        """The joint limits a posture comes within margin [rad or m] of (see :meth:`ReachProblem.limits_near`)."""
        return self.problem.limits_near(np.asarray(posture, float), float(margin))

    def orientation_kinds(self) -> tuple[str, ...]:
        """``direction`` and ``rotation`` for an axis-form orientation task, ``rotation`` for a full one, else none."""
        task = self.strategy.task("orientation")
        if not isinstance(task, OrientationTask):
            return ()
        return ("direction", "rotation") if task.axis is not None else ("rotation",)

    def landing(self, posture: np.ndarray) -> dict[str, Any] | None:
        """Where the strategy's stepping foot lands at a posture (see :class:`oracles.protocol.Stepping`), or None."""
        task = self.strategy.task("step")
        if not isinstance(task, StepTask):
            return None
        model, data = self.body.model, self._data
        pin.framesForwardKinematics(model, data, np.asarray(posture, float))
        fid = self.body.frame_id(task.foot)
        # the foot's axis that pointed ahead (world x) where it stood, where the posture turns it
        ahead = data.oMf[fid].rotation @ (task.stood.rotation.T @ np.array([1.0, 0.0, 0.0]))
        return {"foot": task.foot, "position": [round(float(v), 6) for v in data.oMf[fid].translation],
                "yaw": round(math.atan2(float(ahead[1]), float(ahead[0])), 6)}

    def interpolate(self, q0: np.ndarray, q1: np.ndarray, s: np.ndarray, exact: bool = True) -> np.ndarray:
        """As :meth:`PosedBody.interpolate`; every other foot held fixed (a hard task's ``fixed`` contact, the step's
        foot) that stands at one place at both ends is kept there too, by its leg's own inverse kinematics at each
        posture: interpolated, the second foot slid (up to 1 cm while a step's body reached over it) and every frame
        of a standing reach broke the feet, to be held by a solve. A strategy with a balance task (and no step) has each
        posture whose centre of mass (or pelvis) leaves its bounds moved back by the root, its feet held again
        (:mod:`oracles.ik.balancing`). ``exact=False``: as it slid (the feet's legs move neither the effector nor the
        root)."""
        a, b = np.asarray(q0, float), np.asarray(q1, float)
        s = np.atleast_1d(np.asarray(s, float))
        out = super().interpolate(a, b, s)
        if not exact:
            return out
        out = self._held(a, b, out)
        balance = self.strategy.task("balance")
        if not isinstance(balance, BalanceTask) or self.anchor is None or self.strategy.task("step") is not None:
            return out
        # the centre of mass (and pelvis) kept within the balance's bounds (oracles.ik.balancing)
        return balancing.balanced(self.body.model, self._data, a, b, s, out, balance.polygon,
                                  balance.hull if balance.pelvis else None, self._held_moved)

    def _held(self, a: np.ndarray, b: np.ndarray, postures: np.ndarray, anchor: bool = False,
              iterations: int = LEG_ITER) -> np.ndarray:
        """Postures between a and b with every planted foot held by its leg, the anchor's too with ``anchor`` (a root
        moved aside moved it)."""
        feet = planted_frames(self.body, self.strategy, self.problem, self.anchor)
        for foot in [self.anchor, *feet] if anchor and self.anchor is not None else feet:
            postures = planted(self.body.model, self.body.frame_id(foot), a, b, postures, iterations)
        return postures

    def _held_moved(self, a: np.ndarray, b: np.ndarray, postures: np.ndarray) -> np.ndarray:
        """:meth:`_held` of postures whose root the balance moved aside (oracles.ik.balancing), the anchor's leg too."""
        return self._held(a, b, postures, anchor=True, iterations=balancing.HOLD_ITER)

    def swing(self, q0: np.ndarray, q1: np.ndarray, count: int) -> np.ndarray | None:
        """A step's frames from q0 to the foot set down where q1 puts it (see :mod:`oracles.ik.stepping`)."""
        return swing_frames(self, np.asarray(q0, float), np.asarray(q1, float), int(count))

    def _dls(self) -> DampedLeastSquares:
        """The damped least squares on this body and strategy, made on first use: no compilation."""
        if self._projector is None:
            self._projector = DampedLeastSquares(self)
        return self._projector

    def _project(self, posture: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """Damped least squares on the hard tasks' rows alone, from guess, pulled towards posture (may still break
        them)."""
        return np.asarray(self._dls().project(posture, guess))

    def describe(self) -> dict[str, Any]:
        """The strategy as parsed: effector, active joints and tasks (``reach model CONFIG``); with ``reference: auto``,
        the reference posture found for it (joint -> rad or m)."""
        out: dict[str, Any] = {"effector": self.strategy.effector, "joints": list(self.strategy.joints),
                               "tasks": [t.describe() for t in self.strategy.tasks]}
        if self._body_spec.get("reference") == "auto":
            model, q = self.body.model, self.body.q_ref
            out["reference"] = {}
            for name in self.strategy.joints:  # one value per joint: a continuous joint's angle
                if name != ROOT:
                    jm = model.joints[model.getJointId(name)]
                    value = math.atan2(q[jm.idx_q + 1], q[jm.idx_q]) if jm.nq == 2 else q[jm.idx_q]
                    out["reference"][name] = round(float(value), 6)
        return out

    def diagnose(self) -> list[str]:
        """What in the spec will likely give a wrong or empty volume (see :class:`oracles.protocol.Diagnosed`)."""
        out = list(self.body.notes)
        for task in self.strategy.hard:
            out += task.warnings()
        q = self.body.q_ref
        broken = self.faults(q[None])[0]
        # A start that breaks a hard task is common (one foot's balance from two feet) and the search leaves
        # it; only when the nearest posture holding the hard tasks cannot be found is the volume at risk.
        # A posture class the strategy enters (a squat's, from standing) is left by the searches' other starts.
        if broken and not set(broken) <= self.strategy.entered and self.faults(self._project(q, q)[None])[0]:
            out.append(f"the reference posture breaks the hard tasks {broken} and no posture near it holds them: "
                       "every search starts "
                       "there, so the volume may come out empty; give body.reference (a posture that holds them) or "
                       "change the tasks")
        return out


def planted_frames(body: Body, strategy: Strategy, p: ReachProblem, anchor: str | None) -> list[str]:
    """The frames :meth:`TaskedBody.interpolate` keeps by their legs' inverse kinematics: the fixed contacts but the
    anchor (which the root's placement keeps), and the step's foot."""
    fixed = [c.frame for t in strategy.hard if isinstance(t, ContactsTask) for c in t.contacts
             if c.mode == "fixed" and c.frame != anchor]
    task = strategy.task("step")
    model = body.model
    # only a limb of its own: a hand held on a rail shares the trunk with the effector, which it would move
    reaching = set(chain(model, p.effector_id))
    return [f for f in dict.fromkeys(fixed + ([task.foot] if isinstance(task, StepTask) else []))
            if not reaching & set(chain(model, body.frame_id(f)))]


def base_turn(body: Body, strategy: Strategy, p: ReachProblem) -> tuple[np.ndarray, np.ndarray] | None:
    """The point and axis of the first active joint when it turns a full turn and every other active joint lies
    after it, the root fixed; else None."""
    model = body.model
    if strategy.floating or not p.joint_ids:
        return None
    first = min(p.joint_ids)
    for j in p.joint_ids:
        while j > first:
            j = int(model.parents[j])
        if j != first:
            return None  # an active joint on another branch
    jm = model.joints[first]
    full = str(model.names[first]) in body.continuous or (
        jm.nq == 1 and model.upperPositionLimit[jm.idx_q] - model.lowerPositionLimit[jm.idx_q] >= 2 * np.pi - 1e-6)
    if not full:
        return None
    data = model.createData()
    pin.computeJointJacobians(model, data, body.q_ref)
    column = pin.getJointJacobian(model, data, first, pin.LOCAL_WORLD_ALIGNED)[:, jm.idx_v]
    if np.linalg.norm(column[3:]) < 0.5 or np.linalg.norm(column[:3]) > 1e-9:
        return None  # not a revolute joint
    return data.oMi[first].translation.copy(), column[3:] / np.linalg.norm(column[3:])


def _anchor(body: Body, strategy: Strategy) -> str | None:
    """The frame a standing body moves from: the first ``fixed`` contact of a hard task, else the first ``hinge``
    (a foot pivoting about its ball: its two placements differ by a turn about the ball's axis, which the
    interpolation follows, so the ball stays where it is), when the root floats."""
    if not strategy.floating:
        return None
    contacts = [c for t in strategy.hard if isinstance(t, ContactsTask) for c in t.contacts]
    for mode in ("fixed", "hinge"):
        contact = next((c for c in contacts if c.mode == mode), None)
        if contact is not None:
            return contact.frame
    return None
