"""The interior-point solver (``fatrop``, ``ipopt``): the reach problem's lexicographic stages.

:class:`InteriorPoint` builds, from the problem's formulation
(:class:`~oracles.ik.solvers.formulation.Formulation`: the symbols and the
parameter vector), the hard tasks' rows and the soft tasks' objectives, and
the lexicographic stages: stage 1 minimises the squared reach error under the hard tasks (contacts, heels,
balance polygon) as constraints and joint limits as bounds; each following
soft task (gaze, then posture, by priority) is minimised with every earlier
objective constrained to stay at its optimum. The lazy tasks (collisions)
enter as cuts (:class:`Cuts`). The programs are built on the first solve
that needs them, compiled with ``jit`` and shared by variants of equal
options (:class:`Programs`).
"""

from __future__ import annotations

import copy
import shutil
import warnings
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.errors import OracleError
from oracles.ik.jit import COMPILER, compiled_nlpsols
from oracles.ik.rounds import NO_CALL, Call
from oracles.ik.solvers.formulation import Formulation
from oracles.ik.solvers.protocol import Room, Solver
from oracles.ik.solvers.single import SingleSolver
from oracles.protocol import Purpose
from oracles.tasks import HardTask, Numeric, SoftTask

# fatrop's initial barrier parameter for a settled reach stage (see Search.settle):
# its start is a neighbour's posture a few centimetres off, which a smaller
# barrier leaves less (docs/decisions/0007: 17-24 % fewer iterations, same verdicts).
SETTLE_MU = 1e-6
# Lazy tasks' cuts (see oracles.tasks.base.HardTask): how many one program
# holds, how many rounds of cutting a stage may take, how near its bound a row
# is cut [m], and how far inside its bound a cut puts it [m] (the rows are
# curved; a cut exactly on the bound lands just short of it).
CUT_SLOTS = 16
CUT_ROUNDS = 4
CUT_WITHIN = 0.02
CUT_INSIDE = 0.002
UNUSED = -1.0  # an unused cut slot's lower bound: 0 >= -1
REFINE_SECONDARY_ITER = 40  # iteration cap of the lower stages when refining an answer
SOLVERS = ("fatrop", "ipopt")


class Cuts:
    """The cut slots of one solve: rows ``matrix @ x >= lower``; once full, a new cut replaces the oldest."""

    def __init__(self, slots: int, nx: int) -> None:
        self.matrix = np.zeros((slots, nx))
        self.lower = np.full(slots, UNUSED)
        self.count = 0

    def add(self, row: np.ndarray, lower: float) -> None:
        if not len(self.lower):
            return
        k = self.count % len(self.lower)
        self.matrix[k], self.lower[k] = row, lower
        self.count += 1


@dataclass
class Programs:
    """The compiled programs of one set of engine options, built on the first solve that needs them."""

    stages: list[ca.Function] = field(default_factory=list)
    cut_stages: list[ca.Function] = field(default_factory=list)  # the same with cut rows, built on the first cut
    # the settled reach stage (see Search.settle), by cut slots
    settling: dict[int, ca.Function] = field(default_factory=dict)
    bounds: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # row bounds by number of cut slots
    objectives: list[ca.Function] = field(default_factory=list)  # each stage's measure, at (x, params)


class InteriorPoint(SingleSolver):
    """The reach problem's lexicographic stages solved by fatrop or IPOPT, one goal from one start (see the module
    docstring). Nothing is built at construction: the programs (and their jit compilation) are built on the first
    solve, so loading a config or building an oracle in a process that never solves costs no compilation; twins
    of equal options share them.

    Args:
        room: The oracle's body, strategy and search.
        solver: ``fatrop`` or ``ipopt``, the interior-point solvers shipped with CasADi. IPOPT is the referee of
            ``reach audit``.
        max_iter: Iteration cap of the reach stage.
        secondary_iter: Iteration cap of each lower stage (gaze, posture). A lower stage stopped at its cap keeps its
            last iterate when it honours every constraint (else the stage above's posture).
        jit: Compile the problem's functions to machine code with the system's C compiler (``gcc``): ``auto``
            compiles when ``gcc`` is on the PATH and falls back to CasADi's interpreter if it fails, ``true``
            requires it, ``false`` (the default) never does. The libraries are kept on disk and shared by every
            process (:mod:`oracles.ik.jit`).
        body_parameters: The body's numbers (its offsets, masses, reference posture, support polygon, capsules) as
            parameters of the programs, not constants: every body of one shape (a population's members) then
            shares one program a strategy, compiled once (:mod:`oracles.ik.parameters`; :meth:`share`). Default
            false: a lone body's programs keep its numbers as constants (smaller expressions).
    """

    def __init__(self, room: Room, solver: str = "fatrop", max_iter: int = 60, secondary_iter: int = 15,
                 jit: bool | str = False, body_parameters: bool = False) -> None:
        super().__init__(room)
        if solver not in SOLVERS:
            raise OracleError(f"solver must be one of {sorted(SOLVERS)}, got {solver!r}", oracle=self.oracle,
                              key="solver")
        if not isinstance(body_parameters, bool):
            raise OracleError(f"body_parameters must be true or false, got {body_parameters!r}", oracle=self.oracle,
                              key="body_parameters")
        if jit not in (True, False, "auto"):
            raise OracleError(f"jit must be true, false or 'auto', got {jit!r}", oracle=self.oracle, key="jit")
        self.name = solver
        self.max_iter, self.secondary_iter = int(max_iter), int(secondary_iter)
        self.formulation = Formulation(room, body_parameters)
        self._set_jit(jit)
        self._cache: dict[tuple[Any, ...], Programs] = {}  # shared with twins (a shallow copy keeps the dict)

    def options(self) -> dict[str, Any]:
        lifted = {"body_parameters": True} if self.formulation.body_parameters else {}
        return {"max_iter": self.max_iter, "solver": self.name, "jit": self.jit_asked,
                "secondary_iter": self.secondary_iter, **lifted}

    def twin(self, room: Room, *, purpose: Purpose | None = None, compiled: bool = True,
             starts: int | None = None) -> InteriorPoint:
        # A refinement never compiles (seconds, more than a server's few solves gain) and lets the lower stages
        # converge (its budget bounds the time); the referee solves with IPOPT, the reference solver.
        out = copy.copy(self)
        out.room, out.formulation = room, self.formulation.twin(room)
        if not compiled:
            out.jit, out._cache = False, {}
        if purpose == "refine":
            out._set_jit(False)
            out.secondary_iter = REFINE_SECONDARY_ITER
        elif purpose == "referee":
            out.name = "ipopt"
        return out

    def _set_jit(self, jit: bool | str) -> None:
        has_compiler = shutil.which(COMPILER) is not None
        if jit is True and not has_compiler:
            raise OracleError(f"jit needs the C compiler {COMPILER} on the PATH; install it or set jit: false",
                              oracle=self.oracle, key="jit")
        self.jit_asked = jit
        self.jit = jit is True or (jit == "auto" and has_compiler)

    @property
    def order(self) -> list[SoftTask]:
        """The soft tasks solved, by priority: down to reach, and the lower ones with ``secondary``."""
        soft, reach = self.room.strategy.soft, self.room.strategy.reach
        return list(soft if self.room.search.secondary else soft[: soft.index(reach) + 1])

    @property
    def lazy(self) -> list[HardTask]:
        """The lazy hard tasks (collisions): cut, not held as rows."""
        return [t for t in self.room.strategy.hard if t.lazy]

    @property
    def programs(self) -> Programs:
        """The programs of this solver's options (those a twin with the same options shares)."""
        search = self.room.search
        key = (self.name, self.jit_asked, self.max_iter, self.secondary_iter, len(self.order), search.settle > 0,
               search.max_seconds if self.name == "ipopt" else None)
        found = self._cache.get(key)
        if found is None:
            found = self._cache[key] = Programs()
        return found

    def prepare(self, cut: bool = False) -> None:
        """The stages now (and with ``cut``, their twins with cut rows) rather than on the first solve."""
        programs = self.programs
        if not programs.stages:
            programs.stages = self._build(programs)
        if cut and self.lazy and not programs.cut_stages:
            programs.cut_stages = self._build(programs, CUT_SLOTS)

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float:
        """The lowest stage's objective at a posture (the posture task's, in the shipped strategies)."""
        self.prepare()
        if len(self.order) < 2:
            return 0.0
        x = self.room.problem.x_of_q(posture)
        return float(self.programs.objectives[-1](x, self.formulation.params(goal, x, call)))

    def solve(self, goal: np.ndarray, x0: np.ndarray, lower: bool = True, call: Call = NO_CALL) -> np.ndarray:
        self.prepare()
        p, order, reach = self.room.problem, self.order, self.room.strategy.reach
        x = np.clip(x0, p.lower, p.upper)
        # settling: the start moved the least (see Search.settle)
        params = self.formulation.params(goal, x, call, pull=not lower)
        optimum: list[float] = []
        cuts = Cuts(CUT_SLOTS, p.nx)  # kept from stage to stage: they describe the same neighbourhood
        for k, task in enumerate(order):
            stage = self._cut_stage(k, x, params, optimum, cuts, settled=not lower)
            if stage is None:
                break  # keep the last posture; the check decides
            x, value = stage
            optimum.append(value)
            if not task.attained(value) or (not lower and task is reach):
                break  # e.g. unreachable: lower tasks cannot change the verdict
        return p.q_of_x(x)

    def share(self, other: Solver) -> bool:
        """Take ``other``'s programs (those built and those it builds later) for this body, when one program serves
        both (:meth:`Formulation.program_key`); returns whether it did. A population's members answer with the first
        member's programs, built once."""
        if not isinstance(other, InteriorPoint):
            return False
        if not self.formulation.shares_programs(self.options(), other.formulation, other.options()):
            return False
        self._cache = other._cache
        return True

    def _build(self, programs: Programs, slots: int = 0) -> list[ca.Function]:
        """The lexicographic stages: each soft task minimised with the earlier ones held, and ``slots`` cut rows."""
        p, order, strategy = self.room.problem, self.order, self.room.strategy
        sym, params = self.formulation.symbols()
        x = sym.x
        rows = [c for t in strategy.hard for c in t.constraints(sym)]
        # The lazy tasks' cuts: linear rows whose coefficients are parameters,
        # so they add nothing to the second derivatives. An unused slot is
        # 0 >= -1: fatrop mishandles rows free on both sides (it ran past its
        # iteration cap).
        cut = ca.SX.sym("cut", slots, p.nx)
        g = ca.vertcat(*[c.expr for c in rows], cut @ x) if rows or slots else ca.SX.zeros(0, 1)
        lbg = np.array([c.lower for c in rows for _ in range(c.expr.numel())] + [UNUSED] * slots, float)
        ubg = np.array([c.upper for c in rows for _ in range(c.expr.numel())] + [np.inf] * slots, float)
        programs.bounds[slots] = (lbg, ubg)
        specs, settle = [], None
        for k, task in enumerate(order):
            earlier = [t.held(sym) for t in order[:k]]
            nlp = {"x": x, "p": ca.vertcat(params, ca.vec(cut)), "f": task.objective(sym), "g": ca.vertcat(g, *earlier)}
            iters = self.max_iter if k == 0 else self.secondary_iter
            specs.append((f"stage_{task.type}{'_cut' if slots else ''}", nlp, self._options(self.name, iters)))
            if k == 0 and self.room.search.settle > 0 and self.name == "fatrop":
                opts = {**self._options(self.name, iters), "fatrop.mu_init": SETTLE_MU}
                settle = len(specs)
                specs.append((f"stage_{task.type}_settle{'_cut' if slots else ''}", nlp, opts))
        built = self._nlpsols(specs)  # compiled together: the compiler runs on several at once
        stages = [f for j, f in enumerate(built) if j != settle]
        if settle is not None:
            programs.settling[slots] = built[settle]
        programs.objectives = [ca.Function(t.type, [x, params], [t.measure(sym)]) for t in order]
        return stages

    def _nlpsols(self, specs: list[tuple[str, dict[str, Any], dict[str, Any]]]) -> list[ca.Function]:
        """Each ``(name, nlp, opts)`` as a program of this solver, compiled when asked (falling back to CasADi's
        interpreter when the compiler fails under ``jit: auto``)."""
        if self.jit:
            try:
                return compiled_nlpsols(self.name, specs)
            except RuntimeError as exc:
                reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
                if self.jit_asked is True:
                    raise OracleError(f"jit compilation with {COMPILER} failed ({reason}); set jit: false",
                                      oracle=self.oracle, key="jit") from exc
                warnings.warn(f"casadi-ik: jit compilation failed, using CasADi's interpreter ({reason})", stacklevel=2)
                self.jit = False
        return [ca.nlpsol(name, self.name, nlp, opts) for name, nlp, opts in specs]

    def _options(self, solver: str, max_iter: int) -> dict[str, Any]:
        if solver == "fatrop":
            # No structure detection: the problem is one stage, not an
            # optimal-control horizon. A small initial barrier parameter suits
            # warm starts, which most build solves are (docs/decisions/0007).
            return {"print_time": 0, "structure_detection": "none", "fatrop.print_level": 0, "fatrop.tol": 1e-6,
                    "fatrop.mu_init": 1e-4, "fatrop.max_iter": max_iter}
        seconds = self.room.search.max_seconds
        budget = {"ipopt.max_wall_time": seconds} if seconds else {}
        return {**budget, "print_time": 0, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": max_iter,
                "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4}

    def _stage(self, k: int, x: np.ndarray, params: np.ndarray, optimum: list[float], cuts: Cuts | None,
               settled: bool = False) -> np.ndarray | None:
        """Stage k's solution from x (settled: the reach stage of a settled start), or None when the solver
        fails or (below the first stage) breaks a constraint."""
        p, programs = self.room.problem, self.programs
        slots = CUT_SLOTS if cuts is not None else 0
        if cuts is not None and not programs.cut_stages:
            # on the first collision: many problems never need them
            programs.cut_stages = self._build(programs, CUT_SLOTS)
        lbg, ubg = programs.bounds[slots]
        lo, hi = [lbg], [ubg]
        if cuts is not None:
            lo[0] = lbg.copy()
            lo[0][len(lbg) - slots :] = cuts.lower
        for t, opt in zip(self.order[:k], optimum, strict=False):
            a, b = t.held_bounds(opt)
            lo.append(a)
            hi.append(b)
        low, high = np.concatenate(lo), np.concatenate(hi)
        program = (programs.stages if cuts is None else programs.cut_stages)[k]
        if settled and k == 0:
            program = programs.settling.get(slots, program)
        try:
            if cuts is None:
                sol = program(x0=x, p=params, lbx=p.lower, ubx=p.upper, lbg=low, ubg=high)
            else:
                sol = program(x0=x, p=np.concatenate([params, cuts.matrix.ravel(order="F")]), lbx=p.lower,
                              ubx=p.upper, lbg=low, ubg=high)
        except RuntimeError:
            return None  # a numerical failure of the solver
        if k > 0:
            # A lower stage is kept only if it honours every constraint,
            # whatever the solver's status (it may stop at its iteration cap).
            gval = np.asarray(sol["g"]).ravel()
            if np.any(gval < low - 1e-7) or np.any(gval > high + 1e-7):
                return None
        return np.clip(np.asarray(sol["x"]).ravel(), p.lower, p.upper)

    def _cut_stage(
        self, k: int, x: np.ndarray, params: np.ndarray, optimum: list[float], cuts: Cuts, settled: bool = False,
    ) -> tuple[np.ndarray, float] | None:
        """Stage k with the lazy tasks: while its posture breaks one, cut the near rows there and solve again.

        Returns the posture and the stage's objective there, or None when the stage gives no posture.
        """
        room, task, lazy = self.room, self.order[k], self.lazy
        model, reach = room.body.model, room.strategy.reach
        for rounds in range(CUT_ROUNDS + 1):
            x_new = self._stage(k, x, params, optimum, cuts if cuts.count else None, settled)
            if x_new is None:
                return None
            value = float(self.programs.objectives[k](x_new, params))
            if not lazy or (task is reach and not task.attained(value)):
                return x_new, value  # a reach stage that misses the goal is not worth cutting: its verdict is no
            q = room.problem.q_of_x(x_new)
            pin.framesForwardKinematics(model, room.data, q)
            if all(t.holds(Numeric(model, room.data, q, np.zeros(3))) for t in lazy):
                return x_new, value
            if rounds == CUT_ROUNDS:
                break
            room.stats["cut_rounds"] += 1
            num = room.problem.numeric_x(q, room.data)
            for t in lazy:
                for c in t.cuts(num, CUT_WITHIN):
                    cuts.add(c.jacobian, c.need + CUT_INSIDE - c.gap + float(c.jacobian @ x_new))
        # Still broken: the reach stage's posture goes to the verdict (which
        # refuses it); a lower stage's is dropped for the stage above's.
        assert x_new is not None
        return (x_new, value) if task is reach else None



def fatrop(room: Room, max_iter: int = 60, secondary_iter: int = 15, jit: bool | str = False,
           body_parameters: bool = False) -> InteriorPoint:
    """The interior-point solver with fatrop (``solver: fatrop``)."""
    return InteriorPoint(room, "fatrop", max_iter, secondary_iter, jit, body_parameters)


def ipopt(room: Room, max_iter: int = 60, secondary_iter: int = 15, jit: bool | str = False,
          body_parameters: bool = False) -> InteriorPoint:
    """The interior-point solver with IPOPT (``solver: ipopt``), the referee's."""
    return InteriorPoint(room, "ipopt", max_iter, secondary_iter, jit, body_parameters)
