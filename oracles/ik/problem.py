"""The reach problem of one strategy on one body, shared by the IK oracles.

It fixes the active coordinates ``x`` (the root's position [m] and roll,
pitch, yaw [rad] from its reference orientation when the base floats, then one angle [rad] or length [m] per
active joint), their bounds, the map ``x -> q``, the reach pre-filter, and
the verdict: an independent Pinocchio forward-kinematics check of a posture,
by each task's own check and the joint limits. It binds the strategy's
tasks to the body's reference posture (contacts held where they stand, the
support polygon).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cached_property

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.bodies.body import Body
from oracles.bodies.urdf import ROOT
from oracles.errors import ModelError
from oracles.ik.strategy import Strategy
from oracles.tasks import Numeric, Reference

LIMIT_TOL = 1e-6  # [rad or m] joint limit overshoot the verdict accepts
# how far the ready start moves each joint from the reference towards its range's middle (a modelling choice)
READY = 0.3


class Check:
    """Outcome of the Pinocchio check of one posture.

    The lazy hard tasks (self-collision, the floor: the costly checks) are
    checked when ``hard_ok`` or ``reachable`` is first asked, and
    ``reachable`` looks at the soft tasks (the effector at the goal) first: a
    build's unreachable vertex, given up after one solve, never needs them.
    """

    def __init__(self, residual: float, eager_ok: bool, lazy_ok: Callable[[], bool], soft_ok: bool) -> None:
        self.residual = residual  # [m] effector to goal
        self.eager_ok = eager_ok  # joint limits and the hard tasks that are not lazy hold
        self.soft_ok = soft_ok  # every soft task holds (the effector at the goal among them)
        self._lazy_ok = lazy_ok

    @cached_property
    def hard_ok(self) -> bool:
        """Joint limits and every hard task hold."""
        return self.eager_ok and self._lazy_ok()

    @cached_property
    def reachable(self) -> bool:
        return self.soft_ok and self.hard_ok


def _rpy_quat(r: ca.SX, p: ca.SX, y: ca.SX) -> ca.SX:
    """Quaternion (x, y, z, w) of R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = ca.cos(r / 2), ca.sin(r / 2), ca.cos(p / 2), ca.sin(p / 2), ca.cos(y / 2), ca.sin(y / 2)
    return ca.vertcat(sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                      cr * cp * cy + sr * sp * sy)


def _compose(a: np.ndarray, b: ca.SX) -> ca.SX:
    """Quaternion (x, y, z, w) of the rotation a then b in a's frame (a b), a constant; b itself when a is the
    identity."""
    if np.allclose(a, [0.0, 0.0, 0.0, 1.0]):
        return b
    ax, ay, az, aw = (float(v) for v in a)
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    return ca.vertcat(aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                      aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


class ReachProblem:
    """Coordinates, bounds, polygon and verdict of a strategy on a body."""

    def __init__(self, body: Body, strategy: Strategy) -> None:
        self.body = body
        self.strategy = strategy
        model = body.model
        self.effector_id = body.frame_id(strategy.effector)
        self.x_names, self.joint_ids, lo, hi, limited = _coordinates(body, strategy)
        self.lower, self.upper = np.array(lo), np.array(hi)
        # A floating root's roll, pitch and yaw turn it from its reference orientation (a y-up model stands
        # turned; its x then starts at zero, far from the rpy's gimbal lock at pitch +-pi/2).
        self._root_ref = np.asarray(body.q_ref[3:7], float)
        self._root_ref_rot = pin.Quaternion(self._root_ref).normalized().toRotationMatrix()
        self.limited = np.array(limited, bool)
        self.nx = len(self.x_names)
        # Symbolic x -> q: locked coordinates keep their reference values.
        xs = ca.SX.sym("x", self.nx)
        self.x_sym = xs
        q = self.q_expression(ca.SX(body.q_ref))
        self.q_sym = q
        self._q_of_x = ca.Function("q_of_x", [xs], [q], ["x"], ["q"])
        # x_of_q's index maps (it runs for every start of every solve): one-coordinate joints, and the
        # unbounded revolute ones stored as (cos, sin).
        k0 = 6 if strategy.floating else 0
        single = [(k0 + k, model.joints[j].idx_q) for k, j in enumerate(self.joint_ids) if model.joints[j].nq == 1]
        paired = [(k0 + k, model.joints[j].idx_q) for k, j in enumerate(self.joint_ids) if model.joints[j].nq == 2]
        self._x_single, self._q_single = (np.array([a for a, _ in single], int), np.array([b for _, b in single], int))
        self._x_paired, self._q_paired = (np.array([a for a, _ in paired], int), np.array([b for _, b in paired], int))
        self.x_ref = self.x_of_q(body.q_ref)
        # Where the searches start and spread their random starts: the reference, unless it breaks the strategy's hard
        # tasks (a squat's hips above its knees), when the engine finds a posture that holds them (use_home).
        self.x_home = self.x_ref
        self.home_sought = False
        # A start for refinements: the reference with every joint READY of the
        # way to the middle of its range (the root where it stands).
        self.x_ready = self.x_ref.copy()
        k = 6 if strategy.floating else 0
        self.x_ready[k:] += READY * (0.5 * (self.lower[k:] + self.upper[k:]) - self.x_ref[k:])
        # Tasks record what they hold at the reference posture.
        data = model.createData()
        pin.framesForwardKinematics(model, data, body.q_ref)
        reference = Reference(body, data)
        for task in strategy.tasks:
            task.bind(reference)
        self.anchor, self.max_reach = self._reach_bound(data)
        # The hard tasks' coupled limits at the reference posture: those it rests at are not strain (limits_near).
        self._rest_slacks = [t.limit_slacks(body.q_ref) for t in strategy.hard]

    def use_home(self, q: np.ndarray) -> None:
        """Start the searches from ``q`` (a posture that holds the hard tasks the reference breaks)."""
        self.x_home = self.x_of_q(np.asarray(q, float))

    # -- coordinates -------------------------------------------------------
    def q_expression(self, q_ref: ca.SX) -> ca.SX:
        """The posture q(x) (nq, 1) as an expression of ``x_sym``: the locked coordinates ``q_ref``'s (constants, or a
        body's parameters)."""
        model, xs = self.body.model, self.x_sym
        q = ca.SX(q_ref)
        k = 0
        if self.strategy.floating:
            q[0:3] = xs[0:3]
            q[3:7] = _compose(self._root_ref, _rpy_quat(xs[3], xs[4], xs[5]))
            k = 6
        for j in self.joint_ids:
            jm = model.joints[j]
            if jm.nq == 2:
                q[jm.idx_q] = ca.cos(xs[k])
                q[jm.idx_q + 1] = ca.sin(xs[k])
            else:
                q[jm.idx_q] = xs[k]
            k += 1
        return q

    def arrays(self) -> dict[str, np.ndarray]:
        """The body's numbers the programs take besides its model's (:func:`oracles.ik.parameters`): the reference
        posture and its coordinates, the coordinates' bounds and ranges, the root's reference orientation."""
        return {"q_ref": self.body.q_ref, "x_ref": self.x_ref, "lower": self.lower, "span": self.upper - self.lower,
                "root_ref": self._root_ref}

    def q_of_x(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self._q_of_x(x)).ravel()

    def q_of_x_many(self, x: np.ndarray) -> np.ndarray:
        """Postures (B, nq) of coordinates (B, nx), in one mapped call."""
        if not len(x):
            return np.zeros((0, self.body.model.nq))
        return np.asarray(self._q_of_x(np.asarray(x, float).T)).T.reshape(len(x), -1)

    def x_of_q(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, float)
        x = np.empty(self.nx)
        if self.strategy.floating:
            rot = pin.Quaternion(q[3:7]).normalized().toRotationMatrix()
            x[:3], x[3:6] = q[:3], pin.rpy.matrixToRpy(self._root_ref_rot.T @ rot)
        x[self._x_single] = q[self._q_single]
        x[self._x_paired] = np.arctan2(q[self._q_paired + 1], q[self._q_paired])
        return np.clip(x, self.lower, self.upper)

    def numeric_x(self, q: np.ndarray, data: pin.Data) -> Numeric:
        """Pinocchio's evaluation of q with Jacobians over x (not over velocities), for linearising in x.

        A floating root's velocity is (linear, angular) in its own frame;
        x holds its world position and roll, pitch, yaw, so those columns
        are mapped through the root's rotation and the rpy Jacobian.
        """
        model = self.body.model
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        cols = [model.joints[j].idx_v for j in self.joint_ids]
        if self.strategy.floating:
            rot = pin.Quaternion(np.asarray(q[3:7])).normalized().toRotationMatrix()
            root = np.zeros((6, 6))
            root[:3, :3] = rot.T
            root[3:, 3:] = pin.rpy.computeRpyJacobian(pin.rpy.matrixToRpy(self._root_ref_rot.T @ rot), pin.LOCAL)

        def joint_jacobian(joint: int) -> np.ndarray:
            jac = pin.getJointJacobian(model, data, joint, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            out = jac[:, cols]
            return np.hstack([jac[:, :6] @ root, out]) if self.strategy.floating else out

        return Numeric(model, data, q, np.zeros(3), joint_jacobian=joint_jacobian)

    def random_x(self, rng: np.random.Generator) -> np.ndarray:
        """A random posture near the reference: joints uniform in their ranges, root unmoved."""
        x = rng.uniform(self.lower, self.upper)
        if self.strategy.floating:
            x[:6] = self.x_ref[:6]
        return x

    # -- pre-filter --------------------------------------------------------
    def _reach_bound(self, data: pin.Data) -> tuple[np.ndarray | None, float]:
        """A fixed point and the most the effector can be from it (a triangle-inequality bound).

        With a locked root, the first active joint on the root-to-effector path
        is fixed in space; the effector is at most the sum of the distances
        between consecutive joint origins from it. With a floating root held
        by contacts, the path runs from a contact through the tree.
        """
        model = self.body.model
        frame = model.frames[self.effector_id]

        def path_up(joint: int) -> list[int]:
            out = [joint]
            while out[-1] != 0:
                out.append(int(model.parents[out[-1]]))
            return out

        def length(points: list[np.ndarray]) -> float:
            return float(sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:], strict=False)))

        up = path_up(frame.parentJoint)
        eff = data.oMf[self.effector_id].translation
        origin = [data.oMi[j].translation for j in range(model.njoints)]
        if not self.strategy.floating:
            active = set(self.joint_ids)
            chain = [j for j in reversed(up) if j in active]
            if not chain:
                return eff.copy(), 0.0
            first = chain[0]
            below = list(reversed(up[: up.index(first) + 1]))
            return origin[first].copy(), length([origin[j] for j in below] + [eff])
        if not self.strategy.held_frames:
            return None, np.inf
        best = (None, np.inf)
        for held in self.strategy.held_frames:
            cf = model.frames[self.body.frame_id(held)]
            a, b = path_up(cf.parentJoint), up
            common = next(j for j in a if j in b)
            joints = a[: a.index(common) + 1] + list(reversed(b[: b.index(common)]))
            start = data.oMf[self.body.frame_id(held)].translation
            total = length([start] + [origin[j] for j in joints] + [eff])
            if total < best[1]:
                best = (start.copy(), total)
        return best

    def prefilter(self, goal: np.ndarray) -> float:
        """A lower bound [m] of the distance the effector stays from goal (0 if it may reach)."""
        if self.anchor is None:
            return 0.0
        return max(0.0, float(np.linalg.norm(goal - self.anchor)) - self.max_reach)

    def effector_distance(self, q: np.ndarray, goal: np.ndarray, data: pin.Data) -> float:
        """Distance [m] from the effector at posture q to goal."""
        pin.framesForwardKinematics(self.body.model, data, q)
        return float(np.linalg.norm(data.oMf[self.effector_id].translation - goal))

    def limits_near(self, q: np.ndarray, margin: float) -> list[str]:
        """The limits q comes within ``margin`` [rad or m] of: active joints' range ends (``name (lower)``,
        ``name (upper)``) and the hard tasks' coupled limits; not those the reference posture rests at
        (a straight knee stands at the end of its range)."""
        x = self.x_of_q(q)
        out = []
        for k in np.nonzero(self.limited)[0]:
            for end, gap, rest in (("lower", x[k] - self.lower[k], self.x_ref[k] - self.lower[k]),
                                   ("upper", self.upper[k] - x[k], self.upper[k] - self.x_ref[k])):
                if gap < margin <= rest:
                    out.append(f"{self.x_names[k]} ({end})")
        for t, rest_slacks in zip(self.strategy.hard, self._rest_slacks, strict=True):
            out += [name for name, slack in t.limit_slacks(q).items() if slack < margin <= rest_slacks[name]]
        return out

    # -- the verdict -------------------------------------------------------
    def within_limits(self, q: np.ndarray) -> bool:
        model = self.body.model
        return bool(np.all(q[7:] >= model.lowerPositionLimit[7:] - LIMIT_TOL)
                    and np.all(q[7:] <= model.upperPositionLimit[7:] + LIMIT_TOL))

    def out_of_limits(self, q: np.ndarray) -> list[str]:
        """The posture coordinates of q outside their ranges (beyond the verdict's tolerance), by name."""
        model = self.body.model
        bad = np.nonzero((q[7:] < model.lowerPositionLimit[7:] - LIMIT_TOL)
                         | (q[7:] > model.upperPositionLimit[7:] + LIMIT_TOL))[0]
        return [self.body.q_names[7 + k] for k in bad] if bad.size else []

    def check(self, q: np.ndarray, goal: np.ndarray, data: pin.Data | None = None,
              target: np.ndarray | None = None) -> Check:
        """Independent Pinocchio check of a posture: each task's own check, and the joint limits (target: the
        goal's task targets, a row of ``Strategy.target_rows``, when it carries any)."""
        model = self.body.model
        data = model.createData() if data is None else data
        q, goal = np.array(q, float), np.array(goal, float)  # copies: the deferred checks below read them later
        pin.framesForwardKinematics(model, data, q)
        num = Numeric(model, data, q, goal, targets={} if target is None else self.strategy.target_dict(target))
        residual = self.strategy.reach.residual(num)
        eager_ok = self.within_limits(q) and all(t.holds(num) for t in self.strategy.hard if not t.lazy)
        soft_ok = all(t.holds(num) for t in self.strategy.soft)

        def lazy_ok() -> bool:
            pin.framesForwardKinematics(model, data, q)  # data may hold another posture by now
            return all(t.holds(num) for t in self.strategy.hard if t.lazy)

        return Check(residual, eager_ok, lazy_ok, soft_ok)


def _coordinates(body: Body, strategy: Strategy) -> tuple[list[str], list[int], list[float], list[float], list[bool]]:
    """The problem's coordinates x: their names, the active joints' ids, their bounds, and whether each has a joint
    range (not the root, not an unbounded revolute)."""
    model = body.model
    lo: list[float] = []
    hi: list[float] = []
    limited: list[bool] = []  # whether a coordinate has a joint range (not the root, not an unbounded revolute)
    x_names: list[str] = []
    joint_ids: list[int] = []
    for name in strategy.joints:
        if name == ROOT:
            x_names += ["root_x", "root_y", "root_z", "root_roll", "root_pitch", "root_yaw"]
            p0 = body.q_ref[:3]
            lo += [*(p0 - 1.5), -np.pi / 2, -np.pi / 2, -np.pi]
            hi += [*(p0 + 1.5), np.pi / 2, np.pi / 2, np.pi]
            limited += [False] * 6
            continue
        j = body.joint_id(name)
        jm = model.joints[j]
        if jm.nv != 1:
            raise ModelError(f"joint {name!r} has {jm.nv} degrees of freedom; only the root and one-axis joints "
                             "can be active", source=body.source)
        joint_ids.append(j)
        x_names.append(name)
        limited.append(jm.nq == 1)
        if jm.nq == 2:  # unbounded revolute, stored as (cos, sin)
            lo.append(-2 * np.pi)
            hi.append(2 * np.pi)
        else:
            lo.append(float(model.lowerPositionLimit[jm.idx_q]))
            hi.append(float(model.upperPositionLimit[jm.idx_q]))
    return x_names, joint_ids, lo, hi, limited
