"""Damped-least-squares task-priority IK on Pinocchio (registry name ``dls``).

The paper's own family of engines (Baerlocher & Boulic 1998): each
iteration stacks the tasks by priority and resolves them with damped
pseudo-inverses in each other's null spaces,

    dq  = J1+ e1 + (J2 P1)+ (e2 - J2 dq1) + ...,   P_k = P_{k-1} - (J_k P_{k-1})+ (J_k P_{k-1}),

level 1 being the hard tasks (contacts held, heels above the floor and the
centre of mass inside the shrunk support polygon, as an active set of
violated rows), then reach, gaze and comfort in their priority order. Joint
limits are enforced by clamping: a joint that a step would push past its
limit is fixed there and the step recomputed without it.

As in ``casadi-ik`` the soft tasks are lexicographic: the stack down to the
reach task is iterated first; the lower tasks (gaze, comfort) are added
afterwards, and their result is kept only if the verdict still holds.
Verdicts follow the same Pinocchio check as ``casadi-ik``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pinocchio as pin

from oracles.ik import IKOracle

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
BUFFER = 0.005  # [m] distance from an inequality's bound at which its row becomes active
INSIDE = 1e-4  # [m] how far inside its bound a violated row is pushed


def damped_pinv(jac: np.ndarray, damping: float) -> np.ndarray:
    """Batched J^T (J J^T + lambda^2 I)^-1 for jac of shape (N, m, n)."""
    m = jac.shape[1]
    jjt = jac @ jac.transpose(0, 2, 1) + (damping**2) * np.eye(m)[None]
    return jac.transpose(0, 2, 1) @ np.linalg.inv(jjt)  # type: ignore[no-any-return]


class DLSIK(IKOracle):
    """Batched task-priority damped least squares (see the module docstring).

    Args:
        max_iter: Iterations per solve.
        damping: Damping lambda of the pseudo-inverses.
        max_step: Largest step norm per iteration [rad, m].
        max_reach_step: Largest reach error pursued per iteration [m].
        (others as :class:`~oracles.ik.IKOracle`)
    """

    def __init__(self, *args: Any, max_iter: int = 150, damping: float = 0.02, max_step: float = 0.3, max_reach_step: float = 0.05, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.max_iter, self.damping, self.max_step = int(max_iter), float(damping), float(max_step)
        self.max_reach_step = float(max_reach_step)
        model = self.body.model
        p = self.problem
        # Velocity columns of the active coordinates, in the order of x.
        cols = list(range(6)) if self.strategy.floating else []
        cols += [model.joints[j].idx_v for j in p.joint_ids]
        self.cols = np.array(cols, dtype=int)
        self.qidx = np.array([model.joints[j].idx_q for j in p.joint_ids], dtype=int)
        self.qlo = model.lowerPositionLimit[self.qidx]
        self.qhi = model.upperPositionLimit[self.qidx]
        self.jcols = np.arange(6 if self.strategy.floating else 0, len(cols))  # joint columns within x
        self.fid = {n: self.body.frame_id(n) for n in {self.strategy.effector, *(c.frame for c in self.strategy.contacts), *self.strategy.above_floor, *([self.strategy.gaze] if self.strategy.gaze else [])}}
        self.has_hard = bool(self.strategy.contacts or self.strategy.above_floor or p.polygon is not None)
        self.reach_level = self.strategy.order.index("reach")
        self.unbounded = np.array([model.joints[j].nq == 2 for j in p.joint_ids], dtype=bool)

    def _kinematics(self, q: np.ndarray, goal: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """The (jacobian, error) of each priority level at q, columns restricted to x."""
        model, data, s, p = self.body.model, self._data, self.strategy, self.problem
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)

        def jac(name: str) -> np.ndarray:
            return pin.getFrameJacobian(model, data, self.fid[name], LWA)[:, self.cols]

        hard_j, hard_e = [], []
        for c, ref in zip(s.contacts, p.contact_ref, strict=True):
            cur, j = data.oMf[self.fid[c.frame]], jac(c.frame)
            hard_j.append(j[:3])
            hard_e.append(ref.translation - cur.translation)
            if c.mode == "fixed":
                hard_j.append(j[3:])
                hard_e.append(pin.log3(ref.rotation @ cur.rotation.T))
            else:
                w, w_ref = cur.rotation @ np.asarray(c.axis), ref.rotation @ np.asarray(c.axis)
                b1 = np.cross(w, [0.0, 0.0, 1.0] if abs(w[2]) < 0.9 else [1.0, 0.0, 0.0])
                b1 /= np.linalg.norm(b1)
                basis = np.stack([b1, np.cross(w, b1)])
                hard_j.append(basis @ j[3:])
                hard_e.append(basis @ np.cross(w, w_ref))
        # Inequalities as an active set with a buffer: a row near its bound
        # holds still (error 0); a row past it is pushed back inside.
        for f in s.above_floor:
            z = data.oMf[self.fid[f]].translation[2]
            if z < BUFFER:
                hard_j.append(jac(f)[2:3])
                hard_e.append(np.array([max(0.0, INSIDE - z)]))
        if p.polygon is not None:
            jcom = pin.jacobianCenterOfMass(model, data, q, False)[:2, self.cols]
            com = data.com[0][:2]
            viol = p.polygon[:, :2] @ com + p.polygon[:, 2]
            for row in np.nonzero(viol > -BUFFER)[0]:
                hard_j.append(p.polygon[row, None, :2] @ jcom)
                hard_e.append(np.array([min(0.0, -viol[row] - INSIDE)]))
        levels: list[tuple[np.ndarray, np.ndarray]] = []
        if hard_j:
            levels.append((np.vstack(hard_j), np.concatenate(hard_e)))
        for task in s.order:
            if task == "reach":
                err = goal - data.oMf[self.fid[s.effector]].translation
                dist = np.linalg.norm(err)
                # Clamp the target distance, so that a far goal does not drag the posture off the hard tasks.
                levels.append((jac(s.effector)[:3], err * min(1.0, self.max_reach_step / dist) if dist > 0 else err))
            elif task == "gaze" and s.gaze is not None:
                eye = data.oMf[self.fid[s.gaze]]
                d, u = eye.rotation[:, 0], goal - eye.translation
                levels.append((jac(s.gaze)[3:], np.cross(d, u / (np.linalg.norm(u) + 1e-9))))
            elif task == "comfort" and s.comfort > 0:
                eye_x = np.zeros((self.jcols.size, self.cols.size))
                eye_x[np.arange(self.jcols.size), self.jcols] = 1.0
                levels.append((0.1 * eye_x, 0.1 * (p.x_ref[self.jcols] - q[self.qidx])))
        return levels

    def _step(self, levels: list[tuple[np.ndarray, np.ndarray]], free: np.ndarray) -> np.ndarray:
        """Task-priority step for one point, columns outside free held at zero."""
        n = self.cols.size
        proj = np.diag(free.astype(float))
        dq = np.zeros(n)
        for jac, err in levels:
            jp = (jac @ proj)[None]
            dq = dq + damped_pinv(jp, self.damping)[0] @ (err - jac @ dq)
            # The projector uses the exact pseudo-inverse: a damped one would
            # leak lower tasks into the higher ones' space.
            proj = proj - np.linalg.pinv(jp[0], rcond=1e-8) @ jp[0]
        return dq

    def _iterate(self, q: np.ndarray, goal: np.ndarray, soft: int, max_iter: int) -> np.ndarray:
        """Iterate the stack truncated after the first soft levels; returns q."""
        model, _p = self.body.model, self.problem
        tol = 0.05 * self.strategy.tolerance
        n_hard = int(self.has_hard)
        bounded = ~self.unbounded
        for _ in range(max_iter):
            if time.perf_counter() > self._deadline:
                break
            levels = self._kinematics(q, goal)[: n_hard + soft]
            err = max((float(np.abs(e).max()) if e.size else 0.0) for _, e in levels[: n_hard + self.reach_level + 1])
            free = np.ones(self.cols.size, bool)
            for _ in range(self.cols.size):  # clamping loop: fix joints a step would push past their limits
                dq = self._step(levels, free)
                norm = np.linalg.norm(dq)
                if norm > self.max_step:
                    dq *= self.max_step / norm
                target = q[self.qidx] + dq[self.jcols]
                over = ((target < self.qlo) | (target > self.qhi)) & bounded & free[self.jcols]
                if not over.any():
                    break
                free[self.jcols[over]] = False
            if err < tol and (soft == self.reach_level + 1 or np.linalg.norm(dq) < 1e-6):
                break  # hard tasks and reach hold (and lower tasks have settled)
            v = np.zeros(model.nv)
            v[self.cols] = dq
            q = pin.integrate(model, q, v)
            q[self.qidx[bounded]] = np.clip(q[self.qidx[bounded]], self.qlo[bounded], self.qhi[bounded])
        return q

    def solve(self, goal: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """Lexicographic like casadi-ik: first the tasks down to reach, then the lower ones."""
        q = self._iterate(self.problem.q_of_x(x0), goal, self.reach_level + 1, self.max_iter)
        if self.secondary and len(self.strategy.order) > self.reach_level + 1 and self.problem.check(q, goal, self._data).reachable:
            refined = self._iterate(q.copy(), goal, len(self.strategy.order), self.max_iter // 3)
            if self.problem.check(refined, goal, self._data).reachable:
                q = refined  # the lower tasks never cost the verdict
        return q
