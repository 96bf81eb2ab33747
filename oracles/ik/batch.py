"""A batched damped Gauss-Newton engine: every goal x start of one call advances together.

``casadi-ik``'s opt-in engine (``solver: batch``; fatrop stays the default,
see the README's limitations). The tasks keep their one definition: the
CasADi expressions they already give the interior-point programs (hard rows
with their bounds, the reach task's residual, the lower tasks' objectives)
are compiled into one function of (x, parameters), mapped over a chunk of
postures (CasADi ``Function.map``), and evaluated for the whole batch at
once. Each iteration then takes, for every start at once, the step of

    min  |J_e dx + e|^2 + lambda^2 |dx|^2      s.t.  C dx = r

through its KKT system, solved by the Woodbury identity on the reach's three
rows and a Schur complement on the constraints (:meth:`BatchProgram.step`):

* **hard tasks as constraints (an active set).** ``C`` holds every equality
  row, every inequality row within ``BUFFER`` of its bound (pushed
  ``INSIDE`` it), as ``dls`` activates them, and the rows a first solve
  would carry past their bounds (solved again). An active set, not a
  barrier: most rows (balance, couplings, the hang cone) are inactive most
  of the time, and a start that breaks one is pulled back to it in one
  linearised step, which a barrier cannot do from outside its domain. Not a
  projection: the constraints and the reach share one solve, so a step
  never trades a hard row for reach; the constraints' part of the step is
  taken first and the reach's within each start's trust radius;
* **joint limits** by clamping: a coordinate a step would push past its
  range is fixed at its bound and the step is solved again without it;
* **the reach task** as the objective, its error clamped to
  ``MAX_REACH_STEP`` per iteration (a far goal does not drag a posture off
  its constraints), Levenberg-Marquardt damped;
* **the lower tasks** (gaze, posture, comfort) as the secondary objective:
  once a start reaches, the reach rows join the constraints and the lower
  tasks' weighted sum (weights ``LOWER_WEIGHT`` ** rank, an approximation of
  their lexicographic order; each task weighed only beyond the level it
  leaves free, as the gaze's cone) is minimised by damped Newton steps on its
  whole Hessian (eigenvalues made positive), the inequality rows active only
  where they bind.

Lazy hard tasks (self-collision, the floor) give no rows here: a posture
found is checked by the verdict (coal, Pinocchio) as always, and one that
breaks them, or that ends near the goal but not within the tolerance, is
polished by the interior-point programs (fatrop) from there, which cut the
lazy rows (see :mod:`oracles.ik.solvers.interior`).
"""
from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np
from threadpoolctl import ThreadpoolController

from oracles.ik.budget import Meter, lower_cost, reach_cost
from oracles.ik.jit import compiled_functions
from oracles.tasks import Constraint, SoftTask, Symbolic
from oracles.tasks.reach import PROXIMAL

# postures per call of the mapped function (padded): large enough to amortise a call, small enough to pad little
CHUNK = 64
SMALL = 8  # ... and of its small map, for the rest of a batch (a refinement's K starts)
BUFFER = 0.005  # [m or rad] an inequality row within this of its bound is active (as dls: oracles/tasks/base.py)
INSIDE = 1e-4  # [m or rad] how far inside its bound an active row is pushed
DAMPING = 1e-2  # Levenberg-Marquardt damping lambda of the reach steps [m per rad] (dls's is 0.02)
LOWER_DAMPING = 1e-2  # damping of the lower tasks' Newton steps, a share of their Hessian's mean diagonal
REGULAR = 1e-10  # KKT regularisation of the constraint block: contradictory or zero rows stay solvable
MAX_STEP = 0.4  # [rad or m] largest step norm of one iteration (a start's trust radius at most)
MIN_RADIUS = 1e-3  # [rad or m] a start whose trust radius has shrunk below this has stalled
MAX_REACH_STEP = 0.25  # [m] largest reach error pursued in one iteration
# the smoothing of a lower task's hinge at its free level (in its objective's units; the gaze's: 1 - cos, about 2.6 deg)
FREE_SMOOTH = 1e-3
LOWER_WEIGHT = 0.1  # weight of each lower task relative to the one above it
FIXED = 1e8  # the diagonal that holds a clamped coordinate still
GROUP = 8  # lazy rows per compiled Jacobian (a group is evaluated only where one of its rows is near)
# [m] a lazy row (a collision pair, a capsule over the floor) this near its bound gives the step a row (a step moves a
# hand a few cm)
SCREEN = 0.05
HARD_TOL = 1e-6  # [m or rad] a hard row this far past its bound still holds (the interior-point programs' tolerance)
FAR = 1e3  # [m] what a lazy row is, in a joined call's posture, where its own call has it near no posture: inactive


@dataclass(frozen=True)
class Rows:
    """Bounds of the hard rows: ``lower <= g(x) <= upper`` per row, and which rows are equalities."""

    lower: np.ndarray
    upper: np.ndarray

    @property
    def equality(self) -> np.ndarray:
        return np.asarray(self.lower == self.upper)


@dataclass
class State:
    """The batch's evaluation at its postures: hard rows g (B, m) with their bounds (m,) and Jacobians
    (B, m, n), the reach residual e (B, 3) and its Jacobian (B, 3, n), how far each posture breaks a lazy
    row (B,), and (when asked) the lower tasks' value (B,), gradient (B, n) and Hessian (B, n, n).

    The rows are the eager hard tasks' and the lazy rows near their bound in some posture of the batch
    (:meth:`BatchProgram.evaluate`), so their number changes from one evaluation to the next.
    """

    g: np.ndarray
    jg: np.ndarray
    e: np.ndarray
    je: np.ndarray
    rows: Rows
    lazy_violation: np.ndarray
    f: np.ndarray | None = None
    grad: np.ndarray | None = None
    hess: np.ndarray | None = None

    def take(self, index: np.ndarray) -> State:
        """The state of some postures of the batch (the lower tasks' terms left out)."""
        return State(self.g[index], self.jg[index], self.e[index], self.je[index], self.rows,
                     self.lazy_violation[index])

    def take_lower(self, index: np.ndarray) -> State:
        """The state of some postures of the batch, the lower tasks' terms with them."""
        out = self.take(index)
        assert self.f is not None and self.grad is not None and self.hess is not None
        out.f, out.grad, out.hess = self.f[index], self.grad[index], self.hess[index]
        return out


class BatchProgram:
    """The tasks' expressions compiled for batches, and the batched iteration on them.

    Args:
        sym: The symbols of the strategy's programs (see :class:`oracles.tasks.Symbolic`).
        params: Their parameter vector (goal, start, start weight, the tasks' targets).
        hard: The hard tasks' constraint rows (the lazy ones give none).
        reach: The reach task's residual expression (3,).
        lower: The soft tasks below reach, in priority order.
        lower_bound, upper_bound: The coordinates' bounds (n,).
        span: The coordinates' ranges (n,), for the proximal term's scale.
        jit: Compile the functions with the C compiler (``oracles.ik.jit``), else CasADi's interpreter.
        name: A prefix for the compiled functions' names.
    """

    def __init__(self, sym: Symbolic, params: ca.SX, hard: Sequence[Constraint], reach: ca.SX,
                 lower: Sequence[SoftTask],
                 lower_bound: np.ndarray, upper_bound: np.ndarray, span: np.ndarray, jit: bool, name: str,
                 screened: Sequence[Constraint] = ()) -> None:
        x = sym.x
        self.n = int(x.numel())
        self.np = int(params.numel())
        g = ca.vertcat(*[c.expr for c in hard]) if hard else ca.SX.zeros(0, 1)
        self.rows = _rows(hard)
        self.m = int(g.numel())
        # The lazy tasks' rows (self-collision, the floor): all evaluated, their Jacobians only where near.
        self.lazy_rows = _rows(screened)
        functions = _lazy_functions(x, params, screened, name)  # then the reach's and the lower tasks'
        self.lazy_m = int(functions[0].size1_out(0)) if functions else 0
        jg = ca.jacobian(g, x) if self.m else ca.SX.zeros(0, self.n)
        je = ca.jacobian(reach, x)
        f = ca.SX(0.0)
        for k, task in enumerate(lower):
            # Only the excess over what the task leaves free counts (the gaze's cone), as in fatrop's stages, which
            # hold it below that level: weighed whole, the gaze was pulled to the cone's centre at the posture's cost
            # (on the whole body, postures 10-80 % worse liked than fatrop's: docs/decisions/0003; the count of 8 in
            # 25 was not found again).
            term = task.objective(sym)
            if task.free > 0:
                excess = term - task.free
                term = 0.5 * (excess + ca.sqrt(excess**2 + FREE_SMOOTH**2))
            f += LOWER_WEIGHT**k * term
        hess, grad = ca.hessian(f, x)
        self.lower_bound, self.upper_bound, self.span = lower_bound, upper_bound, span
        self.groups: np.ndarray | None = None  # each row's call when several run joined (see :meth:`joined`)
        self.has_lower = bool(lower)
        outs = [g, jg, reach, je]
        functions.append(ca.Function(f"{name}_reach", [x, params], [ca.densify(o) for o in outs]))
        if lower:
            functions.append(ca.Function(f"{name}_lower", [x, params], [ca.densify(o) for o in [*outs, f, grad, hess]]))
        # compiled together: the compiler runs on several at once
        self._wrap(dict(zip([fn.name() for fn in functions], compiled_functions(functions) if jit else functions,
                            strict=True)), name)
        # Every matrix the step factors is small (n and m below 100): OpenBLAS's threads only wait on each other, and
        # beside a second worker process on two cores they spun: eigh of 512 36 x 36 Hessians took 1.1 s, 70 ms on
        # one thread (measured here).
        self.threads = ThreadpoolController()

    def _wrap(self, built: dict[str, ca.Function], name: str) -> None:
        """The program's functions (by name, compiled or not), each mapped over batches of postures."""
        if self.lazy_m:
            self._lazy = _Mapped(built[f"{name}_lazy"], [(self.lazy_m, 1)], self.n, self.np)
            self._lazy_groups = [(k, _Mapped(built[f"{name}_lazy_jac{k}"], [(min(GROUP, self.lazy_m - k), self.n)],
                                             self.n, self.np))
                                 for k in range(0, self.lazy_m, GROUP)]
        self._reach = _Mapped(built[f"{name}_reach"], [(self.m, 1), (self.m, self.n), (3, 1), (3, self.n)], self.n,
                              self.np)
        self._full = _Mapped(built[f"{name}_lower"],
                             [(self.m, 1), (self.m, self.n), (3, 1), (3, self.n), (1, 1), (self.n, 1),
                              (self.n, self.n)],
                             self.n, self.np) if self.has_lower else None

    def with_bounds(self, lower_bound: np.ndarray, upper_bound: np.ndarray) -> BatchProgram:
        """This program with other coordinate bounds (another body's, its functions taking that body's numbers as
        parameters: :mod:`oracles.ik.parameters`): (n,), or (B, n) a row of the batch each (the members of a
        population solved together, :mod:`oracles.ik.joined`)."""
        twin = copy.copy(self)
        twin.lower_bound, twin.upper_bound, twin.span = lower_bound, upper_bound, upper_bound - lower_bound
        return twin

    def joined(self, groups: np.ndarray) -> BatchProgram:
        """This program for a batch of several calls' rows joined (:mod:`oracles.ik.joined`), ``groups`` (B,) each
        row's call: what a step reads of the batch's other rows (the lazy rows near some posture, the padding of the
        active rows) it reads of its own call's alone, so each call's rows step as they would alone."""
        twin = copy.copy(self)
        twin.groups = np.asarray(groups, int)
        return twin

    def at(self, rows: np.ndarray) -> BatchProgram:
        """This program for some rows of its batch: itself, or with those rows' bounds and calls when each row has
        its own."""
        if np.ndim(self.lower_bound) == 1 and self.groups is None:
            return self
        twin = self.with_bounds(self.lower_bound[rows], self.upper_bound[rows]) if np.ndim(self.lower_bound) == 2 \
            else copy.copy(self)
        twin.groups = None if self.groups is None else self.groups[rows]
        return twin

    def _by_call(self, flags: np.ndarray) -> np.ndarray:
        """flags (B, k): for each row of a joined batch, whether the flag is set in some row of its call."""
        assert self.groups is not None
        calls = np.zeros((int(self.groups.max()) + 1, flags.shape[1]), bool)
        np.logical_or.at(calls, self.groups, flags)
        return calls[self.groups]

    # -- evaluation -----------------------------------------------------------
    def evaluate(self, x: np.ndarray, p: np.ndarray, lower: bool = False, guard: np.ndarray | None = None) -> State:
        """The batch's :class:`State` at postures x (B, n) with parameters p (B, np); the lazy rows near their bound
        become rows of the postures in ``guard`` (B,) (all when None), and count in every posture's violation."""
        fn = self._full if lower and self._full is not None else self._reach
        out = fn(x, p)
        g, jg, rows = out[0][..., 0], out[1], self.rows
        lazy_violation = np.zeros(len(x))
        if self.lazy_m:
            values = self._lazy(x, p)[0][..., 0]
            lazy_violation = np.maximum(self.lazy_rows.lower - values, 0.0).max(axis=1)
            near = values < self.lazy_rows.lower + SCREEN
            if guard is not None:
                near &= guard[:, None]
            cols = np.nonzero(near.any(axis=0))[0]
            if cols.size and self.groups is not None:
                # A lazy row is a row of the postures of the calls it is near in, as when each call runs alone.
                seen = self._by_call(near[:, cols])
                values = values.copy()
                values[:, cols] = np.where(seen, values[:, cols], FAR)
            if cols.size:
                jac = np.zeros((len(x), cols.size, self.n))
                for k, group in self._lazy_groups:
                    mine = np.nonzero((cols >= k) & (cols < k + GROUP))[0]  # this group's near rows, as columns of jac
                    some = np.nonzero(near[:, cols[mine]].any(axis=1))[0] if mine.size else mine
                    if some.size:
                        jac[some[:, None], mine] = group(x[some], p[some])[0][:, cols[mine] - k]
                if self.groups is not None:
                    jac *= seen[..., None]
                g, jg = np.concatenate([g, values[:, cols]], axis=1), np.concatenate([jg, jac], axis=1)
                rows = Rows(np.concatenate([rows.lower, self.lazy_rows.lower[cols]]),
                            np.concatenate([rows.upper, self.lazy_rows.upper[cols]]))
        state = State(g, jg, out[2][..., 0], out[3], rows, lazy_violation)
        if lower and self._full is not None:
            state.f, state.grad, state.hess = out[4][:, 0, 0], out[5][..., 0], out[6]
        return state

    # -- the step -------------------------------------------------------------
    @staticmethod
    def active(state: State, ahead: np.ndarray | None = None, buffer: float = BUFFER) -> tuple[np.ndarray, np.ndarray]:
        """Which hard rows are active (B, m) and what change each active row needs (B, m): those within ``BUFFER``
        of a bound, and those that ``ahead`` (the rows' values after a first step, linearised) would cross."""
        g, lo, hi = state.g, state.rows.lower, state.rows.upper
        eq = state.rows.equality
        low = g < lo + buffer
        high = g > hi - buffer
        if ahead is not None:
            low |= ahead < lo
            high |= ahead > hi
        target = np.where(eq, lo,
                          np.where(low & ~high, lo + INSIDE, np.where(high & ~low, hi - INSIDE, 0.5 * (lo + hi))))
        act = eq | low | high
        return act, np.where(act, target - g, 0.0)

    def violation(self, state: State, lazy: bool = True) -> np.ndarray:
        """The largest amount (B,) by which a hard row (with ``lazy``, a lazy one too) lies outside its bounds."""
        g = state.g[:, : self.m]
        eager = np.maximum(np.maximum(self.rows.lower - g, g - self.rows.upper), 0.0).max(axis=1, initial=0.0)
        return np.maximum(eager, state.lazy_violation) if lazy else eager

    def step(self, diag: np.ndarray, jac: np.ndarray | None, gradient: np.ndarray, state: State, fixed: np.ndarray,
             radius: np.ndarray, extra: tuple[np.ndarray, np.ndarray] | None = None, ahead: np.ndarray | None = None,
             buffer: float = BUFFER) -> np.ndarray:
        """The KKT step (B, n) of min 1/2 dx' H dx + gradient' dx subject to the active hard rows (and ``extra``
        rows C dx = r, the reach held below it), H = diag(diag) + jac' jac (or ``diag`` itself when it is a whole
        (B, n, n) Hessian), coordinates in ``fixed`` (B, n) held still.

        H is a diagonal plus a low-rank term (the reach's 3 rows), so its inverse is applied by the
        Woodbury identity and the constraints by their Schur complement S = C H^-1 C': a few small batched
        products and one (m, m) solve per posture instead of an (n + m) one.
        """
        c, r, active = self._gathered(state, ahead, buffer, extra)
        h_inv = _h_inverse(diag, jac, fixed)
        dx_g = -h_inv(gradient[..., None])[..., 0]  # the objective's part of the step
        dx_r = np.zeros_like(dx_g)  # the constraints' part (the KKT step is linear in the gradient and the rows' need)
        m = c.shape[1]
        if m:
            hc = h_inv(np.transpose(c, (0, 2, 1)))  # (B, n, m)
            schur = c @ hc
            # A row whose gradient vanishes here (a coupling at its apex) has a zero Schur row: the floor keeps its
            # multiplier finite, and its zero gradient makes it move nothing.
            scale = np.maximum(np.abs(np.einsum("bii->b", schur)) / np.maximum(self._padded(active, m), 1), 1e-12)
            schur += (REGULAR * scale)[:, None, None] * np.eye(m)
            nu = np.linalg.solve(schur, np.stack([(c @ dx_g[..., None])[..., 0], r], axis=2))
            dx_g = dx_g - (hc @ nu[..., :1])[..., 0]
            dx_r = (hc @ nu[..., 1:])[..., 0]
        dx_g, dx_r = dx_g * ~fixed, dx_r * ~fixed
        # The step is bounded by each start's trust radius (B,), the constraints' part first: a far goal's pull never
        # cuts short the return to the hard rows (scaling the whole step did, and kept 9 in 10 whole-body starts off
        # their feet).
        n_r = np.linalg.norm(dx_r, axis=1, keepdims=True)
        n_g = np.linalg.norm(dx_g, axis=1, keepdims=True)
        with np.errstate(over="ignore"):  # a huge ratio is clipped to 1 anyway
            room = np.clip((radius[:, None] - n_r) / np.maximum(n_g, 1e-300), 0.0, 1.0)
        dx = dx_r * np.minimum(1.0, MAX_STEP / np.maximum(n_r, 1e-300)) + room * dx_g
        return np.where(np.isfinite(dx).all(axis=1, keepdims=True), dx, 0.0)  # a singular solve moves nothing

    def _padded(self, active: np.ndarray, m: int) -> np.ndarray | int:
        """The step's row count m as each row's call alone pads it: its posture with the most active rows (``active``,
        (B,)), the batch's most being ``m`` less the rows every posture has."""
        if self.groups is None:
            return m
        most = np.zeros(int(self.groups.max()) + 1, int)
        np.maximum.at(most, self.groups, active)
        return most[self.groups] + (m - int(active.max(initial=0)))

    def _gathered(self, state: State, ahead: np.ndarray | None, buffer: float,
                  extra: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The step's rows C (B, k, n) and their need r (B, k): each posture's active hard rows first, as many as the
        posture with the most (a padding row is a zero row, which the Schur complement's floor keeps harmless: about
        half the rows are active in any posture of the batch), then ``extra``'s; and each posture's active rows (B,)."""
        act, need = self.active(state, ahead, buffer)
        k = int(act.sum(axis=1).max(initial=0))
        order = np.argsort(~act, axis=1, kind="stable")[:, :k]
        on = np.take_along_axis(act, order, axis=1)
        cs = [np.take_along_axis(state.jg, order[..., None], axis=1) * on[..., None]]
        rs = [np.take_along_axis(need, order, axis=1)]
        if extra is not None:
            cs.append(extra[0])
            rs.append(extra[1])
        return np.concatenate(cs, axis=1), np.concatenate(rs, axis=1), act.sum(axis=1)

    def clamped_step(self, x: np.ndarray, diag: np.ndarray, jac: np.ndarray | None, gradient: np.ndarray, state: State,
                     radius: np.ndarray, extra: tuple[np.ndarray, np.ndarray] | None = None,
                     buffer: float = BUFFER) -> np.ndarray:
        """:meth:`step`, solved again where it would push coordinates past their bounds (held there) or carry
        inactive hard rows past theirs (made active): an active set of one look ahead."""
        fixed = np.zeros(x.shape, bool)
        dx = self.step(diag, jac, gradient, state, fixed, radius, extra, buffer=buffer)
        over = ((x + dx < self.lower_bound) | (x + dx > self.upper_bound)) & ~fixed
        ahead = state.g + (state.jg @ dx[..., None])[..., 0]
        crossing = ((ahead < state.rows.lower) | (ahead > state.rows.upper)) & ~self.active(state, buffer=buffer)[0]
        again = np.nonzero(over.any(axis=1) | crossing.any(axis=1))[0]
        if again.size:
            sub = state.take(again)
            ex = None if extra is None else (extra[0][again], extra[1][again])
            dx[again] = self.at(again).step(diag[again], None if jac is None else jac[again], gradient[again], sub,
                                            over[again], radius[again], ex, ahead[again], buffer)
        return np.clip(x + dx, self.lower_bound, self.upper_bound)

    def reach_step(self, x: np.ndarray, state: State, start: np.ndarray | None, start_weight: np.ndarray,
                   radius: np.ndarray) -> np.ndarray:
        """One Gauss-Newton iteration of every posture towards its goal (reach as objective, hard rows held)."""
        e, je = state.e, state.je
        dist = np.linalg.norm(e, axis=1, keepdims=True)
        e_c = e * np.minimum(1.0, MAX_REACH_STEP / np.maximum(dist, 1e-12))
        diag = np.full(x.shape, DAMPING**2)
        gradient = (np.transpose(je, (0, 2, 1)) @ e_c[..., None])[..., 0]
        if start is not None:
            # The reach task's proximal term (oracles/tasks/reach.py): move the least from the current posture.
            w = PROXIMAL * start_weight[:, None] / self.span**2
            diag = diag + w
            gradient = gradient + w * (x - start)
        return self.clamped_step(x, diag, je, gradient, state, radius)

    def lower_step(self, x: np.ndarray, state: State, radius: np.ndarray) -> np.ndarray:
        """One damped Newton iteration of the lower tasks within each posture's trust radius (B,), the reach rows held
        at the goal with the hard ones.

        Only the hard rows at or past their bounds, or that the step would carry past them, are active (no
        ``BUFFER``): a row near its bound that the lower tasks pull away from is let go (held within the buffer, the
        balance and coupling rows kept the whole-body postures 10-20 degrees from fatrop's, their preference 30 %
        worse)."""
        assert state.hess is not None and state.grad is not None
        # Newton on the whole Hessian, its eigenvalues made positive (the energy and gaze terms couple the joints: on
        # the diagonal alone the steps overshot and stalled, 8 of 25 whole-body postures 10 % worse liked than
        # fatrop's).
        w, v = np.linalg.eigh(0.5 * (state.hess + np.transpose(state.hess, (0, 2, 1))))
        w = np.abs(w)
        w = w + LOWER_DAMPING * w.mean(axis=1, keepdims=True) + 1e-6
        hessian = (v * w[:, None, :]) @ np.transpose(v, (0, 2, 1))
        return self.clamped_step(x, hessian, None, state.grad, state, radius, (state.je, -state.e), buffer=0.0)


def _lazy_functions(x: ca.SX, params: ca.SX, screened: Sequence[Constraint], name: str) -> list[ca.Function]:
    """The lazy rows' function and their Jacobian's by groups of ``GROUP`` rows (none without lazy rows)."""
    lazy = ca.vertcat(*[c.expr for c in screened]) if screened else ca.SX.zeros(0, 1)
    m = int(lazy.numel())
    if not m:
        return []
    # Frozen symbols (the nearest points' parameters) are held while differentiating, then replaced.
    held = [pair for c in screened for pair in c.frozen]
    symbols, values = [v for v, _ in held], [e for _, e in held]
    jac = ca.jacobian(lazy, x)
    if held:
        lazy, jac = ca.substitute([lazy, jac], [ca.vertcat(*symbols)], [ca.vertcat(*values)])
    # The Jacobian by groups of rows, each evaluated only for the postures with one of its rows near: all 147 rows of
    # the whole body cost 69 us a posture, about ten times the reach's (measured here).
    return [ca.Function(f"{name}_lazy", [x, params], [ca.densify(lazy)]),
            *(ca.Function(f"{name}_lazy_jac{k}", [x, params], [ca.densify(jac[k : min(k + GROUP, m), :])])
              for k in range(0, m, GROUP))]


def _h_inverse(diag: np.ndarray, jac: np.ndarray | None, fixed: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """v (B, n, k) -> H^-1 v, for H = diag(diag) + jac' jac (or ``diag`` itself, a whole (B, n, n) Hessian), a fixed
    coordinate's row and column the identity's times ``FIXED``."""
    if diag.ndim == 3:
        dense = np.where(fixed[:, :, None] | fixed[:, None, :], 0.0, diag)
        idx = np.arange(diag.shape[1])
        dense[:, idx, idx] = np.where(fixed, FIXED, dense[:, idx, idx])
        return lambda v: np.linalg.solve(dense, v)
    d_inv = 1.0 / np.where(fixed, FIXED, diag)
    if jac is None:
        return lambda v: d_inv[..., None] * v
    # M^-1 in closed form (the reach's 3 rows): M = I + J D^-1 J' is symmetric with eigenvalues >= 1, and a
    # batched LAPACK solve of 3 x 3 systems cost more in its calls than in its arithmetic.
    middle = np.eye(jac.shape[1]) + (jac * d_inv[:, None, :]) @ np.transpose(jac, (0, 2, 1))
    middle_inv = _inverse3(middle) if jac.shape[1] == 3 else np.linalg.inv(middle)
    jac_t = np.transpose(jac, (0, 2, 1))

    def h_inv(v: np.ndarray) -> np.ndarray:
        # H^-1 v: D^-1 v - D^-1 J' M^-1 J D^-1 v, M = I + J D^-1 J' (the Woodbury identity).
        dv = d_inv[..., None] * v
        return dv - d_inv[..., None] * (jac_t @ (middle_inv @ (jac @ dv)))

    return h_inv


def _inverse3(m: np.ndarray) -> np.ndarray:
    """The inverses of a batch of 3 x 3 matrices (B, 3, 3), by their adjugates."""
    a, b, c = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
    d, e, f = m[:, 1, 0], m[:, 1, 1], m[:, 1, 2]
    g, h, i = m[:, 2, 0], m[:, 2, 1], m[:, 2, 2]
    adj = np.stack([np.stack([e * i - f * h, c * h - b * i, b * f - c * e], axis=1),
                    np.stack([f * g - d * i, a * i - c * g, c * d - a * f], axis=1),
                    np.stack([d * h - e * g, b * g - a * h, a * e - b * d], axis=1)], axis=1)
    det = a * adj[:, 0, 0] + b * adj[:, 1, 0] + c * adj[:, 2, 0]
    return adj / det[:, None, None]


def _rows(constraints: Sequence[Constraint]) -> Rows:
    return Rows(np.array([c.lower for c in constraints for _ in range(c.expr.numel())], float),
                np.array([c.upper for c in constraints for _ in range(c.expr.numel())], float))


class _Mapped:
    """A function of (x, p) over a batch of postures, compiled or interpreted, called through CasADi's buffers (no
    conversion of its outputs: numpy arrays are written in place).

    The function is mapped (CasADi's serial map, a loop in C++) over ``CHUNK`` postures and over ``SMALL``: a
    refinement's one goal has K = 8 starts, and padded to 64 it paid for eight times the postures it asked for (a
    motion's end posture spent its whole 0.25 s budget evaluating)."""

    def __init__(self, f: ca.Function, shapes: list[tuple[int, int]], n: int, np_: int) -> None:
        self.shapes = shapes
        self.maps = {size: _Buffers(f.map(f"{f.name()}_map{size}", "serial", size, [], []), size, shapes, n, np_)
                     for size in (SMALL, CHUNK)}

    def __call__(self, x: np.ndarray, p: np.ndarray) -> list[np.ndarray]:
        """Each output (B, rows, cols) at postures x (B, n) and parameters p (B, np)."""
        b = len(x)
        result = [np.empty((b, rows, cols)) for rows, cols in self.shapes]
        k = 0
        while k < b:
            # The large map while it would be at least half used, then the small one.
            mapped = self.maps[CHUNK if b - k > CHUNK // 2 else SMALL]
            c = min(mapped.size, b - k)
            mapped.x[:c], mapped.p[:c] = x[k : k + c], p[k : k + c]
            if c < mapped.size:  # pad with the first posture: every column of the map is evaluated
                mapped.x[c:], mapped.p[c:] = x[k], p[k]
            mapped.trigger()
            for r, o in zip(result, mapped.out, strict=True):
                r[k : k + c] = np.transpose(o[:c], (0, 2, 1))
            k += c
        return result


class _Buffers:
    """One mapped function with the numpy arrays CasADi reads its arguments from and writes its results to."""

    def __init__(self, mapped: ca.Function, size: int, shapes: list[tuple[int, int]], n: int, np_: int) -> None:
        self.size = size
        self.x = np.zeros((self.size, n))
        self.p = np.zeros((self.size, np_))
        self.out = [np.zeros((self.size, cols, rows)) for rows, cols in shapes]  # each block column-major
        self.buffer, self.trigger = mapped.buffer()
        # CasADi takes the arrays' own memory (the buffer protocol); its stubs type the size argument it does not need.
        self.buffer.set_arg(0, memoryview(self.x))  # type: ignore[call-arg, arg-type]
        self.buffer.set_arg(1, memoryview(self.p))  # type: ignore[call-arg, arg-type]
        for k, o in enumerate(self.out):
            self.buffer.set_res(k, memoryview(o))  # type: ignore[call-arg, arg-type]


# -- the iteration over many starts ---------------------------------------------

MAX_ITER = 40  # reach iterations
# reaching starts of one goal whose lower tasks are refined, the first in start order (the neighbour's posture in a
# build first)
LOWER_STARTS = 2
# lower-task iterations of a reaching start, each followed by a step back to the goal: 12 took 16.2 ms a warm whole-body
# goal against 12.8 ms, for a mean preference of 4.92 against 5.08 (fatrop 5.88)
LOWER_ITER = 6
# ... of a refinement (its budget bounds them): from a stored posture a cell away, 6 left the whole body's lower tasks
# at twice the preference fatrop's stages reach (tests/test_select.py's handover)
REFINE_LOWER_ITER = 24
RESTORE_ITER = 4  # Gauss-Newton steps back to the goal and the hard rows after them, at most
DECIDES = 1e-3  # [m or rad] a decisive start decides its goal only with its hard rows held this well
STALL = 0.02  # a start whose distance to the goal shrinks by less than this share in an iteration has stalled
# iterations the other starts of a goal get once one has reached, to find a better-liked posture (a choice, not tuned)
EXTRA = 2
CONVERGED = 0.1  # share of the tolerance within which a start has reached and stops iterating


class Ends(NamedTuple):
    """Where a batch's starts ended: postures x (B, n), reach distances, hard-row violations and the lower tasks'
    values (B,) (inf where not computed), which goals a decisive start gave up (indexed by goal), each start's
    reach rounds (B,), and which starts reached their goal through a lazy row (a collision) at some iteration (B,)."""

    x: np.ndarray
    dist: np.ndarray
    viol: np.ndarray
    liked: np.ndarray
    given_up: np.ndarray
    rounds: np.ndarray
    blocked: np.ndarray


class Starts(NamedTuple):
    """One batch of starts to iterate: the arguments of :func:`run_starts` (a call the waves ask for, run alone or
    joined with other oracles' of the same program, :mod:`oracles.ik.joined`)."""

    program: BatchProgram
    x0: np.ndarray
    params: np.ndarray
    goal_of: np.ndarray
    tolerance: float
    lower: bool
    start: np.ndarray | None
    meter: Meter
    stats: dict[str, int]
    decisive: np.ndarray | None = None
    give_up: float = np.inf
    lower_iter: int = LOWER_ITER

    def run(self) -> Ends:
        return run_starts(*self)


def run_starts(program: BatchProgram, x0: np.ndarray, params: np.ndarray, goal_of: np.ndarray, tolerance: float,
               lower: bool, start: np.ndarray | None, meter: Meter, stats: dict[str, int],
               decisive: np.ndarray | None = None, give_up: float = np.inf, lower_iter: int = LOWER_ITER) -> Ends:
    """Iterate every start (B, n) with its parameters (B, np) together (see :class:`Ends`), with ``lower_iter``
    iterations of the lower tasks from a reaching posture.

    ``decisive`` (B,) marks the starts whose failure decides their goal (a build's warm start from a neighbour
    near the goal, see :class:`oracles.ik.search.Search`): when one stalls farther than ``give_up`` [m] from its goal,
    its rows held, the goal's other starts stop there (they ran beside it until then). ``meter`` holds each goal's
    (``goal_of``'s) work budget: a goal stops where it cannot pay its starts' next round."""
    with program.threads.limit(limits=1, user_api="blas"):
        return _run_starts(program, x0, params, goal_of, tolerance, lower, start, meter, stats, decisive, give_up,
                           lower_iter)


def _run_starts(program: BatchProgram, x0: np.ndarray, params: np.ndarray, goal_of: np.ndarray, tolerance: float,
                lower: bool, start: np.ndarray | None, meter: Meter, stats: dict[str, int],
                decisive: np.ndarray | None, give_up: float, lower_iter: int) -> Ends:
    x, dist, viol, given_up, rounds, blocked = _reach_rounds(program, x0, params, goal_of, tolerance, start, meter,
                                                             stats, decisive, give_up)
    f = np.full(len(x), np.inf)
    if lower and program.has_lower:
        _lower_rounds(program, x, dist, viol, f, params, np.asarray(goal_of, int), tolerance, start, meter, stats,
                      lower_iter)
    return Ends(x, dist, viol, f, given_up, rounds, blocked)


def _reach_rounds(program: BatchProgram, x0: np.ndarray, params: np.ndarray, goal_of: np.ndarray, tolerance: float,
                  start: np.ndarray | None, meter: Meter, stats: dict[str, int], decisive: np.ndarray | None,
                  give_up: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The reach stage of every start (see :func:`run_starts`): their ends x, reach distances, hard-row violations,
    the goals a decisive start gave up, each start's rounds, and which starts were guarded (reached through a lazy
    row)."""
    x = x0.copy()
    b = len(x)
    dist = np.full(b, np.inf)
    viol = np.full(b, np.inf)
    live = np.arange(b)
    start_weight = params[:, 3 + program.n] if start is not None else np.zeros(b)
    starts = None if start is None else params[:, 3 : 3 + program.n]
    owner = np.asarray(goal_of, int)
    reached_at = np.full(int(owner.max()) + 1 if b else 0, -1)  # the iteration at which each goal's first start reached
    given_up = np.zeros(len(reached_at), bool)
    radius = np.full(b, MAX_STEP)  # each start's trust radius: halved when a step loses ground, grown when it gains
    # A start moves free of the lazy rows (collisions, the floor) until it reaches its goal through one; from then on
    # they are rows of its steps, which take it out with the goal held. Guarded from the first step, the arm of a
    # reach across the body stopped against the trunk (12 of 99 goals fatrop reaches missed, against 4 unguarded).
    guarded = np.zeros(b, bool)
    merit_before = np.full(b, np.inf)
    rounds = np.zeros(b, int)
    price = reach_cost(program.n)
    for it in range(MAX_ITER + 1):
        live = live[meter.pay(owner[live], price)] if live.size else live
        if not live.size:
            break
        state = program.at(live).evaluate(x[live], params[live], guard=guarded[live])
        stats["iterations"] = stats.get("iterations", 0) + int(live.size)
        rounds[live] += 1
        d, v = np.linalg.norm(state.e, axis=1), program.violation(state)
        dist[live], viol[live] = d, v
        done = (d <= CONVERGED * tolerance) & (v <= HARD_TOL)
        first = owner[live[done]]
        reached_at[first[reached_at[first] < 0]] = it
        # A start stops when it has reached; when it stalls away from the goal; or EXTRA iterations after another
        # start of its goal reached.
        newly, stalled = _progress(program, state, live, d, v, it, tolerance, guarded, radius, merit_before)
        late = (reached_at[owner[live]] >= 0) & (it - reached_at[owner[live]] >= EXTRA)
        if decisive is not None:
            lost = owner[live[stalled & decisive[live] & (d > give_up) & (v <= DECIDES)]]
            given_up[lost] = True
            late |= given_up[owner[live]]
        keep = ~(done | stalled | late)
        if not keep.any():
            break
        sub = np.nonzero(keep & ~newly)[0]
        moving = live[sub]
        x[moving] = program.at(moving).reach_step(x[moving], state.take(sub),
                                                  None if starts is None else starts[moving], start_weight[moving],
                                                  radius[moving])
        live = live[keep]
    return x, dist, viol, given_up, rounds, guarded


def _progress(program: BatchProgram, state: State, live: np.ndarray, d: np.ndarray, v: np.ndarray, it: int,
              tolerance: float, guarded: np.ndarray, radius: np.ndarray,
              merit_before: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The live starts' progress in iteration ``it``, from their reach distances d and hard-row violations v: their
    trust radii (halved when a step lost ground, grown when it gained), their guards, their merits (``guarded``,
    ``radius`` and ``merit_before`` (B,) in place); and which were newly guarded and which stalled away from the goal
    (their distance plus their rows' violation shrank by less than STALL of itself, or their radius collapsed)."""
    before = merit_before[live]
    # [m, with rad as m] progress counts the return to the hard rows as well as towards the goal (the lazy ones once
    # guarded)
    merit = d + np.where(guarded[live], v, program.violation(state, lazy=False))
    newly = ~guarded[live] & (d <= tolerance) & (state.lazy_violation > HARD_TOL)
    worse = merit > before
    radius[live] = np.where(worse, 0.5 * radius[live], np.minimum(MAX_STEP, 1.5 * radius[live]))
    # A newly guarded start waits an iteration for its lazy rows, with its full trust radius (its progress is not
    # judged on it).
    guarded[live[newly]] = True
    radius[live[newly]] = MAX_STEP
    merit[newly] = np.inf
    merit_before[live] = merit
    gained = np.full(len(merit), np.inf)  # (a start's first merit, and a newly guarded start's, are inf)
    known = np.isfinite(before)
    gained[known] = before[known] - merit[known]
    stalled = (d > tolerance) & (gained < STALL * merit) & ~worse & (it > 2)
    return newly, stalled | (radius[live] < MIN_RADIUS)


def _lower_rounds(program: BatchProgram, x: np.ndarray, dist: np.ndarray, viol: np.ndarray, f: np.ndarray,
                  params: np.ndarray, owner: np.ndarray, tolerance: float, start: np.ndarray | None, meter: Meter,
                  stats: dict[str, int], lower_iter: int) -> None:
    """The lower tasks' rounds from the reaching starts' postures: x, dist and viol updated where a start's lower steps
    keep the goal and the hard rows, and f (B,) the lower tasks' value of every reaching start (in place)."""
    start_weight = params[:, 3 + program.n] if start is not None else np.zeros(len(x))
    starts = None if start is None else params[:, 3 : 3 + program.n]
    reached = np.nonzero((dist <= tolerance) & (viol <= HARD_TOL))[0]
    # The lower tasks refine at most LOWER_STARTS reaching starts per goal, the first in the order of the starts
    # (the hint, the reference, the ready posture, then the random ones): the rest keep their reach posture.
    # (reached is in start order, and a goal's starts are contiguous: a start's rank is its distance from its goal's
    # first.)
    reached = reached[np.arange(len(reached)) - np.searchsorted(owner[reached], owner[reached]) < LOWER_STARTS]
    if not reached.size:
        return  # (no start reached: nothing to like)
    y, p_low, s_low = x[reached].copy(), params[reached], None if starts is None else starts[reached]
    low = program.at(reached)
    w_low, r_low = start_weight[reached], np.full(len(reached), MAX_STEP)
    state = low.evaluate(y, p_low, lower=True)
    assert state.f is not None
    best = state.f.copy()
    low_cost = lower_cost(program.n)
    for _ in range(lower_iter):
        going = np.nonzero(r_low >= MIN_RADIUS)[0]
        r_low[going[~meter.pay(owner[reached[going]], low_cost)]] = 0.0  # a goal that cannot pay stops
        if not np.any(r_low >= MIN_RADIUS):
            break

        # Each lower step is linearised: a Gauss-Newton step back to the goal and the hard rows follows it (without,
        # the lower steps drifted 2-27 mm off the goal and 1-4 mm past hard rows, and were all thrown away). A step
        # is kept where the lower tasks like it better, back within reach of the goal; else its radius halves (a
        # diagonal Newton step on coupled terms overshot, and the idle arm swung out).
        # (Each start's steps depend on itself alone: the same goal gets the same posture in any batch.)
        on = np.nonzero(r_low >= MIN_RADIUS)[0]
        stats["iterations"] = stats.get("iterations", 0) + 2 * int(on.size)
        here = low.at(on)
        trial = here.lower_step(y[on], state.take_lower(on), r_low[on])
        trial = here.reach_step(trial, here.evaluate(trial, p_low[on]), None if s_low is None else s_low[on],
                                w_low[on], np.full(len(on), MAX_STEP))
        after = here.evaluate(trial, p_low[on], lower=True)
        assert after.f is not None
        better = (after.f < best[on]) & (np.linalg.norm(after.e,
                                                        axis=1) <= tolerance) & (program.violation(after) <= 1e-4)
        y[on[better]], best[on[better]] = trial[better], after.f[better]
        r_low[on] = np.where(better, np.minimum(MAX_STEP, 1.5 * r_low[on]), 0.5 * r_low[on])
        if better.any():  # state is y's evaluation throughout
            state = low.evaluate(y, p_low, lower=True)
    state = _restore(low, y, state, p_low, s_low, w_low, tolerance, meter)
    d, v = np.linalg.norm(state.e, axis=1), program.violation(state)
    # The lower tasks never cost the verdict: a start whose lower steps leave the goal or a hard row keeps its reach
    # posture.
    ok = (d <= 0.5 * tolerance) & (v <= HARD_TOL)
    assert state.f is not None
    x[reached[ok]], dist[reached[ok]], viol[reached[ok]] = y[ok], d[ok], v[ok]
    f[reached[ok]] = state.f[ok]
    # Every other reaching start is scored where it stands, so that "liked" compares them all.
    rest = np.nonzero((dist <= tolerance) & (viol <= HARD_TOL) & ~np.isfinite(f))[0]
    if rest.size:
        back = program.at(rest).evaluate(x[rest], params[rest], lower=True)
        assert back.f is not None
        f[rest] = back.f


def _restore(program: BatchProgram, y: np.ndarray, state: State, params: np.ndarray, starts: np.ndarray | None,
             start_weight: np.ndarray, tolerance: float, meter: Meter) -> State:
    """A few reach steps that bring the lower-refined postures y (in place) that drifted back onto the goal and the
    hard rows; y's evaluation."""
    for _ in range(RESTORE_ITER):
        if meter.late():
            break  # (a lower-refined posture left off the goal keeps its reach posture; these few steps back to the
            # goal are not priced: the clock's guard alone)
        d, v = np.linalg.norm(state.e, axis=1), program.violation(state)
        off = np.nonzero((d > 0.5 * tolerance) | (v > HARD_TOL))[0]
        if not off.size:
            break
        y[off] = program.at(off).reach_step(y[off], state.take(off), None if starts is None else starts[off],
                                            start_weight[off], np.full(len(off), MAX_STEP))
        state = program.evaluate(y, params, lower=True)
    return state
