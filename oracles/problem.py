"""The reach problem of one strategy on one body, shared by the IK oracles.

It fixes the active coordinates ``x`` (the root's position [m] and roll,
pitch, yaw [rad] when the base floats, then one angle [rad] or length [m] per
active joint), their bounds, the map ``x -> q``, the support polygon, and the
verdict: an independent Pinocchio forward-kinematics check of a posture.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import pinocchio as pin
from scipy.spatial import ConvexHull

from oracles.body import ROOT, Body
from oracles.strategy import Strategy
from reach.errors import ModelError

# Verdict tolerances of the hard tasks.
CONTACT_TOL = 1e-4  # [m] contact position drift
ANGLE_TOL = 1e-3  # [rad] contact orientation drift
LIMIT_TOL = 1e-6  # [rad or m] joint limit overshoot
BALANCE_TOL = 1e-5  # [m] CoM beyond the shrunk polygon


@dataclass(frozen=True)
class Check:
    """Outcome of the Pinocchio check of one posture."""

    residual: float  # [m] effector to goal
    hard_ok: bool  # contacts, floor, balance and limits hold
    reachable: bool


def _rpy_quat(r: ca.SX, p: ca.SX, y: ca.SX) -> ca.SX:
    """Quaternion (x, y, z, w) of R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = ca.cos(r / 2), ca.sin(r / 2), ca.cos(p / 2), ca.sin(p / 2), ca.cos(y / 2), ca.sin(y / 2)
    return ca.vertcat(sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


class ReachProblem:
    """Coordinates, bounds, polygon and verdict of a strategy on a body."""

    def __init__(self, body: Body, strategy: Strategy) -> None:
        self.body = body
        self.strategy = strategy
        model = body.model
        self.effector_id = body.frame_id(strategy.effector)
        lo: list[float] = []
        hi: list[float] = []
        self.x_names: list[str] = []
        self.joint_ids: list[int] = []
        for name in strategy.joints:
            if name == ROOT:
                self.x_names += ["root_x", "root_y", "root_z", "root_roll", "root_pitch", "root_yaw"]
                p0 = body.q_ref[:3]
                lo += [*(p0 - 1.5), -np.pi / 2, -np.pi / 2, -np.pi]
                hi += [*(p0 + 1.5), np.pi / 2, np.pi / 2, np.pi]
                continue
            j = body.joint_id(name)
            jm = model.joints[j]
            if jm.nv != 1:
                raise ModelError(f"{body.source}: joint {name!r} has {jm.nv} degrees of freedom; only the root and one-axis joints can be active")
            self.joint_ids.append(j)
            self.x_names.append(name)
            if jm.nq == 2:  # unbounded revolute, stored as (cos, sin)
                lo.append(-2 * np.pi)
                hi.append(2 * np.pi)
            else:
                lo.append(float(model.lowerPositionLimit[jm.idx_q]))
                hi.append(float(model.upperPositionLimit[jm.idx_q]))
        self.lower, self.upper = np.array(lo), np.array(hi)
        self.nx = len(self.x_names)
        # Symbolic x -> q: locked coordinates keep their reference values.
        xs = ca.SX.sym("x", self.nx)
        q = ca.SX(body.q_ref)
        k = 0
        if strategy.floating:
            q[0:3] = xs[0:3]
            q[3:7] = _rpy_quat(xs[3], xs[4], xs[5])
            k = 6
        for j in self.joint_ids:
            jm = model.joints[j]
            if jm.nq == 2:
                q[jm.idx_q] = ca.cos(xs[k])
                q[jm.idx_q + 1] = ca.sin(xs[k])
            else:
                q[jm.idx_q] = xs[k]
            k += 1
        self.x_sym, self.q_sym = xs, q
        self._q_of_x = ca.Function("q_of_x", [xs], [q], ["x"], ["q"])
        self.x_ref = self.x_of_q(body.q_ref)
        # Reference placements of contacts, and the support polygon.
        data = model.createData()
        pin.framesForwardKinematics(model, data, body.q_ref)
        self.contact_ref = [data.oMf[body.frame_id(c.frame)].copy() for c in strategy.contacts]
        self.polygon: np.ndarray | None = None
        if strategy.margin is not None:
            pts = np.array([data.oMf[body.frame_id(f)].translation[:2] for f in strategy.support])
            try:
                hull = ConvexHull(pts)
            except Exception as exc:  # scipy's QhullError for degenerate supports
                raise ModelError(f"support frames {list(strategy.support)} do not span a polygon ({exc})") from exc
            # Rows (a_x, a_y, c): a . p + c + margin <= 0 inside the shrunk polygon.
            self.polygon = hull.equations.copy()
            self.polygon[:, 2] += strategy.margin
        self.anchor, self.max_reach = self._reach_bound(data)

    # -- coordinates -------------------------------------------------------
    def q_of_x(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self._q_of_x(x)).ravel()

    def x_of_q(self, q: np.ndarray) -> np.ndarray:
        x = []
        if self.strategy.floating:
            rot = pin.Quaternion(np.asarray(q[3:7])).normalized().toRotationMatrix()
            x += [*q[:3], *pin.rpy.matrixToRpy(rot)]
        for j in self.joint_ids:
            jm = self.body.model.joints[j]
            x.append(np.arctan2(q[jm.idx_q + 1], q[jm.idx_q]) if jm.nq == 2 else q[jm.idx_q])
        return np.clip(np.array(x, dtype=float), self.lower, self.upper)

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
        if not self.strategy.contacts:
            return None, np.inf
        best = (None, np.inf)
        for c in self.strategy.contacts:
            cf = model.frames[self.body.frame_id(c.frame)]
            a, b = path_up(cf.parentJoint), up
            common = next(j for j in a if j in b)
            joints = a[: a.index(common) + 1] + list(reversed(b[: b.index(common)]))
            start = data.oMf[self.body.frame_id(c.frame)].translation
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

    # -- the verdict -------------------------------------------------------
    def check(self, q: np.ndarray, goal: np.ndarray, data: pin.Data | None = None) -> Check:
        """Independent Pinocchio check of a posture: residual and hard tasks."""
        model = self.body.model
        data = model.createData() if data is None else data
        residual = self.effector_distance(q, goal, data)  # leaves data's frames at q for the hard tasks
        ok = bool(np.all(q[7:] >= model.lowerPositionLimit[7:] - LIMIT_TOL) and np.all(q[7:] <= model.upperPositionLimit[7:] + LIMIT_TOL))
        for c, ref in zip(self.strategy.contacts, self.contact_ref, strict=True):
            cur = data.oMf[self.body.frame_id(c.frame)]
            ok &= bool(np.linalg.norm(cur.translation - ref.translation) <= CONTACT_TOL)
            if c.mode == "fixed":
                ok &= bool(np.linalg.norm(pin.log3(ref.rotation.T @ cur.rotation)) <= ANGLE_TOL)
            else:
                axis = np.asarray(c.axis)
                ok &= bool(np.linalg.norm(cur.rotation @ axis - ref.rotation @ axis) <= ANGLE_TOL)
        for f in self.strategy.above_floor:
            ok &= bool(data.oMf[self.body.frame_id(f)].translation[2] >= -CONTACT_TOL)
        if self.polygon is not None:
            com = pin.centerOfMass(model, data, q, False)
            ok &= bool(np.all(self.polygon[:, :2] @ com[:2] + self.polygon[:, 2] <= BALANCE_TOL))
        return Check(residual, ok, ok and residual <= self.strategy.tolerance)
