"""The interior-point programs of the reach problem: its formulation in CasADi, and fatrop's or IPOPT's solves.

:class:`ProgramOracle` formulates :class:`CasadiIK`'s problem
(:class:`~oracles.ik.engine.CasadiIK`): the symbols and the parameter
vector (goal, start, start weight, the tasks' targets and, lifted, the
body's numbers: :mod:`oracles.ik.parameters`), the hard tasks' rows and the
soft tasks' objectives, and builds the lexicographic stages: stage 1
minimises the squared reach error under the hard tasks (contacts, heels,
balance polygon) as constraints and joint limits as bounds; each following
soft task (gaze, then posture, by priority) is minimised with every earlier
objective constrained to stay at its optimum. The lazy tasks (collisions)
enter as cuts (:class:`Cuts`). The programs are built on the first solve
that needs them, compiled with ``jit`` and shared by variants of equal
options (:class:`Programs`).
"""

from __future__ import annotations

import shutil
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.bodies.kinematics import SymbolicKinematics, model_arrays
from oracles.errors import OracleError
from oracles.ik.jit import COMPILER, compiled_nlpsol
from oracles.ik.oracle import Call, IKOracle
from oracles.ik.parameters import BodyParameters
from oracles.tasks import HardTask, Numeric, Symbolic

# fatrop's initial barrier parameter for a settled reach stage (see Search.settle):
# its start is a neighbour's posture a few centimetres off, which a smaller
# barrier leaves less (docs/history.md: 17-24 % fewer iterations, same verdicts).
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


class ProgramOracle(IKOracle):
    """An IK oracle whose problem is formulated as CasADi programs (see the module docstring); the engine options
    (``max_iter``, ``secondary_iter``, ``solver``, ``jit``, ``body_parameters``) are set by
    :class:`~oracles.ik.engine.CasadiIK`."""

    max_iter: int
    secondary_iter: int
    solver: str
    body_parameters: bool
    jit: bool
    lazy: list[HardTask]  # the lazy hard tasks (collisions): cut, not held as rows
    _cache: dict[tuple[Any, ...], Programs]
    _batch_cache: dict[tuple[Any, ...], Any]

    def _set_jit(self, jit: bool | str) -> None:
        has_compiler = shutil.which(COMPILER) is not None
        if jit is True and not has_compiler:
            raise OracleError(f"jit needs the C compiler {COMPILER} on the PATH; install it or set jit: false",
                              oracle=self.name, key="jit")
        self.jit_asked = jit
        self.jit = jit is True or (jit == "auto" and has_compiler)

    @property
    def nlp_solver(self) -> str:
        """The interior-point solver of the programs: the engine's own, or fatrop where ``batch`` polishes."""
        return "fatrop" if self.solver == "batch" else self.solver

    def _set_order(self) -> None:
        """The soft tasks solved, by priority: down to reach, and the lower ones with ``secondary``."""
        soft = self.strategy.soft
        self.order = list(soft if self.search.secondary else soft[: soft.index(self.strategy.reach) + 1])

    @property
    def programs(self) -> Programs:
        """The programs of this oracle's engine options (those a variant with the same options shares)."""
        key = (self.nlp_solver, self.jit_asked, self.max_iter, self.secondary_iter, len(self.order),
               self.search.settle > 0, self.search.max_seconds if self.nlp_solver == "ipopt" else None)
        found = self._cache.get(key)
        if found is None:
            found = self._cache[key] = Programs()
        return found

    def _build(self, programs: Programs, slots: int = 0) -> list[ca.Function]:
        """The lexicographic stages: each soft task minimised with the earlier ones held, and ``slots`` cut rows."""
        p, order = self.problem, self.order
        sym, params = self._symbols()
        x = sym.x
        rows = [c for t in self.strategy.hard for c in t.constraints(sym)]
        # The lazy tasks' cuts: linear rows whose coefficients are parameters,
        # so they add nothing to the second derivatives. An unused slot is
        # 0 >= -1: fatrop mishandles rows free on both sides (it ran past its
        # iteration cap).
        cut = ca.SX.sym("cut", slots, p.nx)
        g = ca.vertcat(*[c.expr for c in rows], cut @ x) if rows or slots else ca.SX.zeros(0, 1)
        lbg = np.array([c.lower for c in rows for _ in range(c.expr.numel())] + [UNUSED] * slots, float)
        ubg = np.array([c.upper for c in rows for _ in range(c.expr.numel())] + [np.inf] * slots, float)
        programs.bounds[slots] = (lbg, ubg)
        stages = []
        for k, task in enumerate(order):
            earlier = [t.held(sym) for t in order[:k]]
            nlp = {"x": x, "p": ca.vertcat(params, ca.vec(cut)), "f": task.objective(sym), "g": ca.vertcat(g, *earlier)}
            iters = self.max_iter if k == 0 else self.secondary_iter
            solver = self.nlp_solver
            stages.append(self._nlpsol(f"stage_{task.type}{'_cut' if slots else ''}", solver, nlp,
                                       self._options(solver, iters)))
            if k == 0 and self.search.settle > 0 and solver == "fatrop":
                opts = {**self._options(solver, iters), "fatrop.mu_init": SETTLE_MU}
                programs.settling[slots] = self._nlpsol(f"stage_{task.type}_settle{'_cut' if slots else ''}", solver,
                                                        nlp, opts)
        programs.objectives = [ca.Function(t.type, [x, params], [t.measure(sym)]) for t in order]
        return stages

    def _symbols(self) -> tuple[Symbolic, ca.SX]:
        """The programs' symbols and their parameter vector: goal (3), start (nx), start weight, the tasks' targets,
        and, lifted, the body's numbers (:mod:`oracles.ik.parameters`)."""
        p = self.problem
        goal, start, weight = ca.SX.sym("goal", 3), ca.SX.sym("start", p.nx), ca.SX.sym("start_weight", 1)
        target = ca.SX.sym("target", self.strategy.target_size)
        if not self.lifted:
            sym = Symbolic(SymbolicKinematics(self.body.model, p.q_sym), p.x_sym, goal, p.x_ref, p.upper - p.lower,
                           tuple(p.x_names), p.lower, start, weight, self.strategy.target_dict(target))
            return sym, ca.vertcat(goal, start, weight, target)
        numbers = self.numbers
        kin = SymbolicKinematics(self.body.model, p.q_expression(numbers.sx("q_ref")), numbers)
        sym = Symbolic(kin, p.x_sym, goal, numbers.vector("x_ref"), numbers.vector("span"), tuple(p.x_names),
                       numbers.vector("lower"), start, weight, self.strategy.target_dict(target), numbers,
                       {id(t): f"task{k}." for k, t in enumerate(self.strategy.tasks)})
        return sym, ca.vertcat(goal, start, weight, target, numbers.symbols)

    @property
    def lifted(self) -> bool:
        """Whether the programs take the body's numbers as parameters: ``body_parameters``, and every task of the
        strategy can (:attr:`Task.parametric`)."""
        return self.body_parameters and all(t.parametric for t in self.strategy.tasks)

    @cached_property
    def numbers(self) -> BodyParameters:
        """The body's numbers as the programs take them (lifted when :attr:`lifted`; only lifted programs read them)."""
        arrays = {**model_arrays(self.body.model), **self.problem.arrays()}
        tasks = {f"task{k}.{name}": v for k, t in enumerate(self.strategy.tasks) for name, v in t.numbers().items()}
        # The tasks' numbers lifted whole: their zeros are a body's (a capsule a sphere at one member, a segment at
        # the next: 3 of 20 ANSUR II members had another program).
        return BodyParameters({**arrays, **tasks}, self.lifted, fixed=frozenset({"root_ref"}), dense=frozenset(tasks))

    @property
    def program_key(self) -> tuple[Any, ...] | None:
        """What two oracles' programs depend on when the body's numbers are parameters (None when they are not): the
        body's signature and joints, the strategy but its body, the engine's options."""
        if not self.lifted:
            return None
        strategy = {k: v for k, v in self._strategy_params.items() if k != "body"}
        # jit changes how the programs run, not what they are (the caches below key it apart): `jit: auto` and `true`
        # name the same compiled library; the search's rescues change neither
        engine = {k: v for k, v in self.engine_params().items() if k not in ("jit", "blocked_starts")}
        return self.numbers.signature, self._joints, repr(strategy), repr(sorted(engine.items()))

    @cached_property
    def _joints(self) -> tuple[tuple[str, str, int], ...]:
        """The body's joints: names, kinds and parents (what the programs' structure follows)."""
        model = self.body.model
        return tuple((str(model.names[j]), model.joints[j].shortname(), int(model.parents[j]))
                     for j in range(model.njoints))

    def share_programs(self, other: ProgramOracle) -> bool:
        """Take ``other``'s programs (those built and those it builds later) for this body, when one program serves
        both (:attr:`program_key`); returns whether it did. A population's members answer with the first member's
        programs, built once."""
        if self.program_key is None or self.program_key != other.program_key:
            return False
        self._cache, self._batch_cache = other._cache, other._batch_cache
        return True

    def use_reference(self, q: np.ndarray) -> None:
        super().use_reference(q)
        self.__dict__.pop("numbers", None)  # the reference's numbers (contacts, polygon) are the new posture's

    def with_body(self, params: np.ndarray) -> np.ndarray:
        """Parameters (B, k) or (k,) of the goal, start and targets, with the body's lifted numbers after them."""
        if not self.lifted:
            return params  # a program of this body's own: its numbers are constants in it
        values = self.numbers.values
        if params.ndim == 1:
            return np.concatenate([params, values])
        return np.concatenate([params, np.tile(values, (len(params), 1))], axis=1)

    def _nlpsol(self, name: str, solver: str, nlp: dict[str, Any], opts: dict[str, Any]) -> ca.Function:
        if self.jit:
            try:
                return compiled_nlpsol(name, solver, nlp, opts)
            except RuntimeError as exc:
                reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
                if self.jit_asked is True:
                    raise OracleError(f"jit compilation with {COMPILER} failed ({reason}); set jit: false",
                                      oracle=self.name, key="jit") from exc
                warnings.warn(f"casadi-ik: jit compilation failed, using CasADi's interpreter ({reason})", stacklevel=2)
                self.jit = False
        return ca.nlpsol(name, solver, nlp, opts)

    def _options(self, solver: str, max_iter: int) -> dict[str, Any]:
        if solver == "fatrop":
            # No structure detection: the problem is one stage, not an
            # optimal-control horizon. A small initial barrier parameter suits
            # warm starts, which most build solves are (docs/history.md).
            return {"print_time": 0, "structure_detection": "none", "fatrop.print_level": 0, "fatrop.tol": 1e-6,
                    "fatrop.mu_init": 1e-4, "fatrop.max_iter": max_iter}
        seconds = self.search.max_seconds
        budget = {"ipopt.max_wall_time": seconds} if seconds else {}
        return {**budget, "print_time": 0, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": max_iter,
                "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4}

    def _stage(self, k: int, x: np.ndarray, params: np.ndarray, optimum: list[float], cuts: Cuts | None,
               settled: bool = False) -> np.ndarray | None:
        """Stage k's solution from x (settled: the reach stage of a settled start), or None when the solver
        fails or (below the first stage) breaks a constraint."""
        p, programs = self.problem, self.programs
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
        task = self.order[k]
        for rounds in range(CUT_ROUNDS + 1):
            x_new = self._stage(k, x, params, optimum, cuts if cuts.count else None, settled)
            if x_new is None:
                return None
            value = float(self.programs.objectives[k](x_new, params))
            if not self.lazy or (task is self.strategy.reach and not task.attained(value)):
                return x_new, value  # a reach stage that misses the goal is not worth cutting: its verdict is no
            q = self.problem.q_of_x(x_new)
            pin.framesForwardKinematics(self.body.model, self._data, q)
            if all(t.holds(Numeric(self.body.model, self._data, q, np.zeros(3))) for t in self.lazy):
                return x_new, value
            if rounds == CUT_ROUNDS:
                break
            self.stats["cut_rounds"] += 1
            num = self.problem.numeric_x(q, self._data)
            for t in self.lazy:
                for c in t.cuts(num, CUT_WITHIN):
                    cuts.add(c.jacobian, c.need + CUT_INSIDE - c.gap + float(c.jacobian @ x_new))
        # Still broken: the reach stage's posture goes to the verdict (which
        # refuses it); a lower stage's is dropped for the stage above's.
        assert x_new is not None
        return (x_new, value) if task is self.strategy.reach else None

    def _params(self, goal: np.ndarray, x: np.ndarray, call: Call, pull: bool = False) -> np.ndarray:
        """The programs' parameters: the goal, the current posture (x itself without one) and its weight (0 unless
        pulled), the goal's task targets (``Strategy.target_rows``; the tasks' defaults without)."""
        start = call.start if call.start is not None else x
        target = call.target if call.target is not None else self.default_target
        return self.with_body(np.concatenate([goal, start, [0.0 if call.start is None and not pull else 1.0], target]))

    @cached_property
    def default_target(self) -> np.ndarray:
        """The target parameters of a goal that carries none (each task's default)."""
        return self.strategy.target_rows({}, 1)[0]
