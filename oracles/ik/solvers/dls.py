"""Damped-least-squares task-priority IK on Pinocchio (the ``dls`` solver and oracle).

The paper's own family of engines (Baerlocher & Boulic 1998): each
iteration stacks the tasks by priority and resolves them with damped
pseudo-inverses in each other's null spaces,

    dq  = J1+ e1 + (J2 P1)+ (e2 - J2 dq1) + ...,   P_k = P_{k-1} - (J_k P_{k-1})+ (J_k P_{k-1}),

level 1 being the rows of every hard task (inequalities only where active),
then one level per soft task in priority order. Each task supplies its own
rows (:meth:`~oracles.tasks.HardTask.rows`, :meth:`~oracles.tasks.SoftTask.level`).
Joint limits are enforced by clamping: a joint that a step would push past
its limit is fixed there and the step recomputed without it. Points are
solved one at a time.

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

from oracles.errors import OracleError
from oracles.ik.rounds import NO_CALL, Call
from oracles.ik.solvers.protocol import Room
from oracles.ik.solvers.single import SingleSolver
from oracles.tasks import Numeric, Row

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


RCOND = 1e-8  # singular values below this share of the largest span no direction of a projector (numpy's pinv rcond)


def damped_solve(jac: np.ndarray, err: np.ndarray, damping: float) -> tuple[np.ndarray, np.ndarray]:
    """J^T (J J^T + lambda^2 I)^-1 err of a (m, n) Jacobian, and the rows (r, n) spanning J's row space.

    One SVD J = U S V^T gives both: the damped step V S (S^2 + lambda^2)^-1 U^T err,
    and the exact projector pinv(J) J = V_r V_r^T for the next level's null space.
    """
    u, s, vt = np.linalg.svd(jac, full_matrices=False)
    step = vt.T @ (s / (s**2 + damping**2) * (u.T @ err))
    rank = int((s > RCOND * s[0]).sum()) if s.size else 0
    return step, vt[:rank]


HELD = 1e-5  # [m or rad] project's rows: well within the contacts' checks (0.1 mm, 1 mrad; oracles/tasks/contacts.py)


class DampedLeastSquares(SingleSolver):
    """Task-priority damped least squares (see the module docstring).

    Args:
        room: The oracle's body, strategy and search.
        max_iter: Iterations per solve.
        damping: Damping lambda of the pseudo-inverses.
        max_step: Largest step norm per iteration [rad, m].
        max_reach_step: Largest reach error pursued per iteration [m].
    """

    name = "dls"
    oracle = "dls"
    thorough = False  # it stays in its start's basin

    def __init__(self, room: Room, max_iter: int = 150, damping: float = 0.02, max_step: float = 0.3,
                 max_reach_step: float = 0.05) -> None:
        super().__init__(room)
        for key, value in (("max_iter", max_iter), ("damping", damping), ("max_step", max_step),
                           ("max_reach_step", max_reach_step)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
                raise OracleError(f"{key} must be a number above 0, got {value!r}", oracle=self.oracle, key=key)
        self.max_iter, self.damping, self.max_step = int(max_iter), float(damping), float(max_step)
        self.max_reach_step = float(max_reach_step)
        model, p, strategy = room.body.model, room.problem, room.strategy
        # Velocity columns of the active coordinates, in the order of x.
        cols = list(range(6)) if strategy.floating else []
        cols += [model.joints[j].idx_v for j in p.joint_ids]
        self.cols = np.array(cols, dtype=int)
        self.qidx = np.array([model.joints[j].idx_q for j in p.joint_ids], dtype=int)
        self.qlo = model.lowerPositionLimit[self.qidx]
        self.qhi = model.upperPositionLimit[self.qidx]
        self.jcols = np.arange(6 if strategy.floating else 0, len(cols))  # joint columns within x
        self.soft = strategy.soft
        self.reach_level = self.soft.index(strategy.reach)
        self.unbounded = np.array([model.joints[j].nq == 2 for j in p.joint_ids], dtype=bool)

    def options(self) -> dict[str, Any]:
        return {"max_iter": self.max_iter, "damping": self.damping, "max_step": self.max_step,
                "max_reach_step": self.max_reach_step}

    def _levels(self, q: np.ndarray, goal: np.ndarray, soft: int, call: Call) -> tuple[list[Row], int]:
        """The (jacobian, error) of the hard level and the first soft levels at q, columns restricted to x,
        and how many levels (0 or 1) are hard."""
        model, data = self.room.body.model, self.room.data
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        num = Numeric(
            model, data, q, goal, lambda fid: pin.getFrameJacobian(model, data, fid, LWA)[:, self.cols],
            lambda joint: pin.getJointJacobian(model, data, joint, LWA)[:, self.cols],
            self.cols, self.jcols, self.qidx, self.room.problem.x_ref, self.max_reach_step,
            start=call.start, start_weight=0.0 if call.start is None else 1.0,
            targets={} if call.target is None else self.room.strategy.target_dict(call.target),
        )
        hard = [row for t in self.room.strategy.hard for row in t.rows(num)]
        levels = [Row(np.vstack([r.jacobian for r in hard]), np.concatenate([r.error for r in hard]))] if hard else []
        return levels + [lv for t in self.soft[:soft] if (lv := t.level(num)) is not None], len(levels)

    def _step(self, levels: list[Row], free: np.ndarray) -> np.ndarray:
        """Task-priority step for one point, columns outside free held at zero."""
        n = self.cols.size
        proj = np.diag(free.astype(float))
        dq = np.zeros(n)
        for k, (jac, err) in enumerate(levels):
            step, span = damped_solve(jac @ proj, err - jac @ dq, self.damping)
            dq = dq + step
            if k < len(levels) - 1:
                # The projector uses the exact pseudo-inverse: a damped one would
                # leak lower tasks into the higher ones' space.
                proj = proj - span.T @ span
        return dq

    def _iterate(self, q: np.ndarray, goal: np.ndarray, soft: int, max_iter: int, call: Call,
                 tol: float | None = None) -> np.ndarray:
        """Iterate the stack truncated after the first soft levels until its rows are within ``tol`` [m or rad]
        (default: 5 % of the reach tolerance); returns q."""
        model = self.room.body.model
        tol = 0.05 * self.room.strategy.tolerance if tol is None else tol
        bounded = ~self.unbounded
        for _ in range(max_iter):
            if time.perf_counter() > call.deadline:
                break
            levels, n_hard = self._levels(q, goal, soft, call)
            # The hard level (when any row is active) and the levels down to reach must be closed.
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

    def project(self, q: np.ndarray, start: np.ndarray | None = None, max_iter: int = 12) -> np.ndarray:
        """A posture near q (nq,) that holds the hard tasks with the effector where q puts it: the stack
        down to the reach task, iterated from ``start`` (q by default)."""
        model, data = self.room.body.model, self.room.data
        pin.framesForwardKinematics(model, data, q)
        goal = data.oMf[self.room.problem.effector_id].translation.copy()
        # Rows closed well within the contacts' own checks (0.1 mm, 1 mrad): a frame 0.1 mm off is held, not kept.
        return self._iterate(np.array(q if start is None else start, float), goal, self.reach_level + 1, max_iter,
                             NO_CALL, tol=HELD)

    def towards(self, q: np.ndarray, goal: np.ndarray, max_iter: int) -> np.ndarray:
        """The stack down to the reach task iterated from q (nq,) towards ``goal`` [m]: at most ``max_iter`` steps."""
        return self._iterate(np.array(q, float), np.asarray(goal, float), self.reach_level + 1, int(max_iter), NO_CALL)

    def solve(self, goal: np.ndarray, x0: np.ndarray, lower: bool = True, call: Call = NO_CALL) -> np.ndarray:
        """Lexicographic like casadi-ik: first the tasks down to reach, then the lower ones."""
        p = self.room.problem
        q = self._iterate(p.q_of_x(x0), goal, self.reach_level + 1, self.max_iter, call)
        if (lower and self.room.search.secondary and len(self.soft) > self.reach_level + 1
            and p.check(q, goal, self.room.data, call.target).reachable):
            refined = self._iterate(q.copy(), goal, len(self.soft), self.max_iter // 3, call)
            if p.check(refined, goal, self.room.data, call.target).reachable:
                q = refined  # the lower tasks never cost the verdict
        return q
