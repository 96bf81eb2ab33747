"""The reference IK engine (registry name ``casadi-ik``), on :class:`~oracles.ik.oracle.IKOracle`.

:class:`CasadiIK` is a lexicographic sequence of nonlinear programs solved by an
interior-point method (fatrop by default, or IPOPT) on the CasADi kinematics,
or by the batched engine (:mod:`oracles.ik.batch`). Stage 1 minimises the
squared reach error under the hard tasks (contacts, heels, balance polygon) as
constraints and joint limits as bounds. Each following soft task (gaze, then
posture, by priority) is minimised with every earlier objective constrained to
stay at its optimum, so a lower task never degrades a higher one.
"""

from __future__ import annotations

import copy
import shutil
import time
import warnings
import zlib
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar, NamedTuple

import casadi as ca
import numpy as np
import pinocchio as pin

from oracles.bodies.kinematics import SymbolicKinematics, model_arrays
from oracles.errors import OracleError
from oracles.ik.batch import CONTINUITY as CONTINUITY_WEIGHT
from oracles.ik.batch import (
    LOWER_ITER,
    POLISH_FAR,
    POLISH_NEAR,
    POLISHES,
    RANDOM_NEAR,
    RANDOM_SPREAD,
    REFINE_LOWER_ITER,
    STARTS,
    WAVE,
    WAVE_NEAR,
    BatchProgram,
    run_starts,
)
from oracles.ik.budget import GUARD, POLISH_COST, WAVE_ROUNDS, Meter, reach_cost
from oracles.ik.jit import COMPILER, compiled_nlpsol
from oracles.ik.oracle import NO_CALL, Call, IKOracle, fresh_stats
from oracles.ik.parameters import BodyParameters
from oracles.protocol import Goals, Purpose, Verdicts, check_points
from oracles.tasks import Numeric, Symbolic

SOLVERS = ("batch", "fatrop", "ipopt")  # batch: oracles.ik.batch, every goal x start together (fatrop polishes)
# fatrop's initial barrier parameter for a settled reach stage (see Search.settle):
# its start is a neighbour's posture a few centimetres off, which a smaller
# barrier leaves less (docs/history.md: 17-24 % fewer iterations, same verdicts).
SETTLE_MU = 1e-6
REFINE_SECONDARY_ITER = 40  # iteration cap of the lower stages when refining an answer
# Lazy tasks' cuts (see oracles.tasks.base.HardTask): how many one program
# holds, how many rounds of cutting a stage may take, how near its bound a row
# is cut [m], and how far inside its bound a cut puts it [m] (the rows are
# curved; a cut exactly on the bound lands just short of it).
CUT_SLOTS = 16
CUT_ROUNDS = 4
CUT_WITHIN = 0.02
CUT_INSIDE = 0.002
UNUSED = -1.0  # an unused cut slot's lower bound: 0 >= -1


class _Wave(NamedTuple):
    """One batched run of some goals' starts: the goals (indices), each goal's rows (``offsets``), the starts x0
    and ends x (B, nx), the ends as postures q (B, nq), their reach distances, hard-row violations, how
    little they are liked and their reach rounds (B,)."""

    goals: np.ndarray
    offsets: np.ndarray
    x0: np.ndarray
    x: np.ndarray
    q: np.ndarray
    dist: np.ndarray
    viol: np.ndarray
    liked: np.ndarray
    rounds: np.ndarray


class _Cuts:
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
class _Programs:
    """The compiled programs of one set of engine options, built on the first solve that needs them."""

    stages: list[ca.Function] = field(default_factory=list)
    cut_stages: list[ca.Function] = field(default_factory=list)  # the same with cut rows, built on the first cut
    # the settled reach stage (see Search.settle), by cut slots
    settling: dict[int, ca.Function] = field(default_factory=dict)
    bounds: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # row bounds by number of cut slots
    objectives: list[ca.Function] = field(default_factory=list)  # each stage's measure, at (x, params)


class CasadiIK(IKOracle):
    """Lexicographic NLP solves on CasADi kinematics (registry name ``casadi-ik``).

    Nothing is built at construction: the programs (and their jit
    compilation) are built on the first :meth:`solve`, so loading a config or
    building an oracle in a process that never solves (a build's parent, a
    config check) costs no compilation. Variants share the programs of equal
    engine options.

    Args:
        max_iter: Iteration cap of the reach stage.
        secondary_iter: Iteration cap of each lower stage (gaze, posture). A
            lower stage stopped at its cap keeps its last iterate when it
            honours every constraint (else the stage above's posture).
        solver: ``batch`` (default: :mod:`oracles.ik.batch`, every goal x start
            of a call together, fatrop polishing near misses), ``fatrop`` or
            ``ipopt``, the interior-point solvers shipped with CasADi, one goal
            from one start at a time. IPOPT is the referee of ``reach audit``.
        body_parameters: The body's numbers (its offsets, masses, reference posture, support polygon, capsules) as
            parameters of the programs, not constants: every body of one shape (a population's members) then
            shares one program a strategy, compiled once (:mod:`oracles.ik.parameters`; :meth:`share_programs`).
            Default false: a lone body's programs keep its numbers as constants (smaller expressions).
        jit: Compile the problem's functions to machine code with the system's
            C compiler (``gcc``): ``auto`` compiles when ``gcc`` is on the PATH
            and falls back to CasADi's interpreter if it fails, ``true``
            requires it, ``false`` (the default) never does. The libraries are
            kept on disk and shared by every process (:mod:`oracles.ik.jit`).
        (body, effector, joints, tasks, search: as :class:`IKOracle`)
    """

    name = "casadi-ik"
    # An extreme is sought (reach_extent): fatrop converges on the nearest point to an unreachable goal, where the
    # batched steps stop once progress stalls (5 mm short below configs/examples/arm7_table.yaml's table).
    extreme_params: ClassVar[dict[str, Any]] = {"solver": "fatrop"}

    def __init__(self, *args: Any, max_iter: int = 60, solver: str = "batch", jit: bool | str = False,
                 secondary_iter: int = 15, starts: int = STARTS, body_parameters: bool = False,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not isinstance(body_parameters, bool):
            raise OracleError(f"body_parameters must be true or false, got {body_parameters!r}", oracle=self.name,
                              key="body_parameters")
        self.body_parameters = body_parameters
        if solver not in SOLVERS:
            raise OracleError(f"solver must be one of {sorted(SOLVERS)}, got {solver!r}", oracle=self.name,
                              key="solver")
        if jit not in (True, False, "auto"):
            raise OracleError(f"jit must be true, false or 'auto', got {jit!r}", oracle=self.name, key="jit")
        if isinstance(starts, bool) or not isinstance(starts, int) or not 1 <= starts <= 256:
            raise OracleError(f"starts must be a whole number from 1 to 256, got {starts!r}", oracle=self.name,
                              key="starts")
        self.max_iter, self.solver, self.secondary_iter, self.starts_per_goal = (int(max_iter), solver,
            int(secondary_iter), starts)
        self.lower_iter = LOWER_ITER  # the batched engine's lower-task iterations (more in a refinement: tune)
        self._batch_cache: dict[tuple[Any, ...], BatchProgram] = {}  # shared with variants, as the programs are
        self._set_jit(jit)
        self._cache: dict[tuple[Any, ...], _Programs] = {}  # shared with variants (a shallow copy keeps the dict)
        self._set_order()
        self.lazy = [t for t in self.strategy.hard if t.lazy]
        if self.reference_pending:
            self._search_reference()

    def _search_reference(self) -> None:
        """``reference: auto`` where projection found nothing: this engine's search for the effector where it is,
        every hard task held, from the reference and its random restarts, uncompiled (a probe, not worth a compile);
        its posture becomes the reference when it holds the hard tasks (issue 49: a UR5's tool-down strategy kept
        every joint at zero and warned)."""
        probe = copy.copy(self)
        probe.jit, probe._cache, probe._batch_cache, probe.stats = False, {}, {}, fresh_stats()
        found = probe.evaluate(Goals(self.effector_positions(self.body.q_ref[None])))
        if found.posture is not None and not self.faults(found.posture[:1])[0]:
            self.use_reference(found.posture[0])
            self.reference_pending = False

    def _set_jit(self, jit: bool | str) -> None:
        has_compiler = shutil.which(COMPILER) is not None
        if jit is True and not has_compiler:
            raise OracleError(f"jit needs the C compiler {COMPILER} on the PATH; install it or set jit: false",
                              oracle=self.name, key="jit")
        self.jit_asked = jit
        self.jit = jit is True or (jit == "auto" and has_compiler)

    def engine_params(self) -> dict[str, Any]:
        out = {"max_iter": self.max_iter, "solver": self.solver, "jit": self.jit_asked,
               "secondary_iter": self.secondary_iter, **({"body_parameters": True} if self.body_parameters else {})}
        return {**out, "starts": self.starts_per_goal} if self.solver == "batch" else out

    @property
    def nlp_solver(self) -> str:
        """The interior-point solver of the programs: the engine's own, or fatrop where ``batch`` polishes."""
        return "fatrop" if self.solver == "batch" else self.solver

    def tune(self, purpose: Purpose) -> None:
        # A refinement never compiles (seconds, more than a server's few
        # solves gain) and lets the lower stages converge (its budget bounds
        # the time); the referee solves with IPOPT, the reference solver; the
        # index keeps the build's compiled programs (its many solves are worth compiling).
        if purpose == "refine":
            if self.solver != "batch":  # the batched engine's code is compiled once, kept on disk and built at warm-up
                self._set_jit(False)
            self.secondary_iter = REFINE_SECONDARY_ITER
            self.lower_iter = REFINE_LOWER_ITER
        elif purpose == "referee":
            self.solver = "ipopt"
        elif purpose == "index" and self.solver == "batch":
            # One quick verdict a (vertex, direction) from its hints: fatrop's programs solved arm7_table's index at 380
            # goals/s, the batched engine at 140-160 (its starts, and fatrop's polish of the many near misses).
            self.solver = "fatrop"
        self._set_order()

    def _set_order(self) -> None:
        """The soft tasks solved, by priority: down to reach, and the lower ones with ``secondary``."""
        soft = self.strategy.soft
        self.order = list(soft if self.search.secondary else soft[: soft.index(self.strategy.reach) + 1])

    @property
    def programs(self) -> _Programs:
        """The programs of this oracle's engine options (those a variant with the same options shares)."""
        key = (self.nlp_solver, self.jit_asked, self.max_iter, self.secondary_iter, len(self.order),
               self.search.settle > 0, self.search.max_seconds if self.nlp_solver == "ipopt" else None)
        found = self._cache.get(key)
        if found is None:
            found = self._cache[key] = _Programs()
        return found

    def _build(self, programs: _Programs, slots: int = 0) -> list[ca.Function]:
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
        # name the same compiled library
        engine = {k: v for k, v in self.engine_params().items() if k != "jit"}
        return self.numbers.signature, self._joints, repr(strategy), repr(sorted(engine.items()))

    @cached_property
    def _joints(self) -> tuple[tuple[str, str, int], ...]:
        """The body's joints: names, kinds and parents (what the programs' structure follows)."""
        model = self.body.model
        return tuple((str(model.names[j]), model.joints[j].shortname(), int(model.parents[j]))
                     for j in range(model.njoints))

    def share_programs(self, other: CasadiIK) -> bool:
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

    def _with_body(self, params: np.ndarray) -> np.ndarray:
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

    def _stage(self, k: int, x: np.ndarray, params: np.ndarray, optimum: list[float], cuts: _Cuts | None,
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
        self, k: int, x: np.ndarray, params: np.ndarray, optimum: list[float], cuts: _Cuts, settled: bool = False,
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
        target = call.target if call.target is not None else self._default_target
        return self._with_body(np.concatenate([goal, start, [0.0 if call.start is None and not pull else 1.0], target]))

    @cached_property
    def _default_target(self) -> np.ndarray:
        """The target parameters of a goal that carries none (each task's default)."""
        return self.strategy.target_rows({}, 1)[0]

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float:
        """The lowest stage's objective at a posture (the posture task's, in the shipped strategies)."""
        self.prepare()
        if len(self.order) < 2:
            return 0.0
        x = self.problem.x_of_q(posture)
        return float(self.programs.objectives[-1](x, self._params(goal, x, call)))

    def prepare(self) -> None:
        programs = self.programs
        if not programs.stages:
            programs.stages = self._build(programs)
        if self.solver == "batch":
            self.batch_program()
            if self.lazy and not programs.cut_stages:
                # fatrop's polish of a near miss cuts collision rows at once: built within a budget, its programs took
                # 1.2 s of `reach query`'s 1 s (the README's floor goal answered `timeout`, 42 mm short).
                programs.cut_stages = self._build(programs, CUT_SLOTS)

    def batch_program(self) -> BatchProgram:
        """The batched engine's compiled function of this oracle's tasks (shared by variants with the same options)."""
        key = (self.jit, tuple(t.type for t in self.order))
        found = self._batch_cache.get(key)
        if found is None:
            sym, params = self._symbols()
            hard = [c for t in self.strategy.hard for c in t.constraints(sym)]
            soft = self.order
            reach = self.strategy.reach
            lower = list(soft[soft.index(reach) + 1 :])
            p = self.problem
            # Named by what the functions depend on (the body, effector, joints and tasks, and the stages kept), not by
            # the search: a refinement's variant (another budget) shares the build's compiled code on disk (named by the
            # whole spec, the first `reach query` of each strategy compiled for 30-60 s).
            name = f"batch_{zlib.crc32(repr((self.program_key or self._strategy_params, key[1])).encode()):08x}"
            screened = [c for t in self.strategy.hard for c in t.screened(sym)]
            found = BatchProgram(sym, params, hard, reach.held(sym), lower, p.lower, p.upper, p.upper - p.lower,
                                 self.jit, name, screened)
            self._batch_cache[key] = found
        lo, hi = self.problem.lower, self.problem.upper
        if not (np.array_equal(found.lower_bound, lo) and np.array_equal(found.upper_bound, hi)):
            found = found.with_bounds(lo, hi)  # another body's program (share_programs): this body's bounds
        return found

    def _polisher(self) -> CasadiIK:
        """This oracle with fatrop as its engine (sharing its programs): the batched engine's polish."""
        twin = copy.copy(self)
        twin.solver = "fatrop"
        return twin

    def _evaluate(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                  targets: np.ndarray | None = None) -> Verdicts:
        if self.solver != "batch":
            return super()._evaluate(points, hints, start, targets)
        return self._evaluate_batch(points, hints, start, targets)

    def _batch_starts(self, goal: np.ndarray, hint: np.ndarray | None, wave: int = 0, targeted: bool = False,
                      part: str = "all") -> list[np.ndarray]:
        """A goal's K starts: its hints (the neighbour's posture first), the reference and ready postures, then
        random ones seeded by the search's seed and the goal (the same goal gets the same starts in any batch).
        Wave 1 (see :meth:`_evaluate_batch`): ``WAVE`` times K random ones, of the same seed's next draws. ``part``:
        ``placed`` (the hints, the reference and ready postures: a staged goal's first stage), ``random`` (the random
        ones: its second) or ``all``."""
        p = self.problem
        placed: list[np.ndarray] = []
        if wave == 0:
            seeds = np.zeros((0, 0)) if hint is None else np.atleast_2d(hint)
            placed += [p.x_of_q(h) for h in seeds if np.all(np.isfinite(h))]
            placed += [p.x_ref.copy(), p.x_ready.copy()]
        if part == "placed":
            return placed
        rng = np.random.default_rng([self.search.seed, zlib.crc32(np.round(goal, 9).tobytes()), wave])
        # A standing body's first random starts move every joint only part of the way into its range (RANDOM_SPREAD):
        # uniform hips and ankles throw the held feet metres off, which most starts do not come back from in 40
        # steps; the second wave's are uniform, for the far basins (a reach behind the back, measured in
        # docs/history.md, session 18).
        spread = RANDOM_SPREAD if self.strategy.floating and wave == 0 else 1.0
        count = max(self.starts_per_goal - len(placed), 0) if wave == 0 else WAVE * self.starts_per_goal
        if targeted and wave == 0:
            # A goal with a target (an orientation) is seeded with postures found for its position alone: K random
            # starts besides them (with K in all, 2 of 75 oriented goals the referee reaches on arm7_table were missed).
            count = max(count, self.starts_per_goal)
        randoms = [p.x_ref + spread * (p.random_x(rng) - p.x_ref) for _ in range(count)]
        return randoms if part == "random" else placed + randoms

    def _evaluate_batch(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                        targets: np.ndarray | None) -> Verdicts:
        """Every goal's K starts iterated together by the batched engine (:mod:`oracles.ik.batch`); the verdict is the
        Pinocchio check, in order of how well each reaching posture is liked. A cold goal (no hint, or a search that
        never gives up) that none reaches but some ended within ``WAVE_NEAR`` of gets a second wave of ``WAVE`` x K
        random starts; a goal still missed whose best start ended within ``POLISH_NEAR`` of it (``POLISH_FAR`` when
        cold) is polished by fatrop's programs from there."""
        pts = check_points(points, 3)
        hints = None if hints is None else np.asarray(hints, float)
        p, search, n = self.problem, self.search, len(pts)
        self.stats["points"] += n
        residual = (np.zeros(n) if p.anchor is None
                    else np.maximum(np.linalg.norm(pts - p.anchor, axis=1) - p.max_reach, 0.0))
        prefiltered = residual > self.strategy.tolerance
        self.stats["prefiltered"] += int(prefiltered.sum())
        reach = np.zeros(n, bool)
        posture = np.tile(self.body.q_ref, (n, 1))
        todo = np.nonzero(~prefiltered)[0]
        if not todo.size:
            return Verdicts(reach, residual, posture, None if search.max_seconds is None else np.zeros(n))
        self.prepare()  # compiling (seconds, once) is not the call's budget
        # Each goal's work budget, its share of the call's (see oracles.ik.budget.Meter); the clock is a guard at
        # GUARD times the budget.
        meter = (Meter.unlimited(n) if search.max_seconds is None
                 else Meter(np.full(n, search.max_seconds / n), time.perf_counter() + GUARD * search.max_seconds))
        budgets = meter.left.copy()
        first_hint = None if hints is None else hints[:, 0] if hints.ndim == 3 else hints
        hinted = np.zeros(n, bool) if first_hint is None else np.all(np.isfinite(first_hint), axis=1)
        # A goal's first start is decisive when it is a hint whose effector lies within `decisive` of the goal.
        decisive = np.zeros(n, bool)
        if first_hint is not None and np.isfinite(search.give_up_distance):
            decisive[todo] = [hinted[i] and p.effector_distance(first_hint[i], pts[i], self._data) <= search.decisive
                              for i in todo]
        first = np.tile(p.x_ref, (n, 1))  # each goal's first hint, as x: continuity with it is liked
        for i in todo[hinted[todo]]:
            first[i] = p.x_of_q(first_hint[i])  # type: ignore[index]
        residual[todo] = np.inf
        # A goal far from what anything found: no hint (a first call, a cold query) or a search that never gives
        # up (a refinement, the audit's referee). A build's vertex always has its nearest reachable neighbour's
        # posture, and its K starts are the build's search (measured: with every vertex's misses sent to the random
        # wave, the demo build took 1.5 times fatrop's time).
        cold = np.zeros(n, bool)
        cold[todo] = True if search.give_up is None else ~hinted[todo]
        # A hinted goal of a search that gives up, its hint not decisive, or of a refinement (``prefer``) is staged: its
        # placed starts first (the hints, the reference and ready postures), its random ones only when those end within
        # RANDOM_NEAR of it. Most goals of a build lie outside the volume, and their random starts were most of their
        # cost; a decisive goal keeps them beside its hint, which stops them when it fails (staged too, the arm's and
        # crouch's trees lost goals). A refinement's budget, shared by fewer starts, lasts them more rounds: of 240
        # answers in the demo's boundary cells at 20 ms, 162 refined ok against 147 (bench/misses.py, session 27).
        staged = np.zeros(n, bool)
        staged[todo] = hinted[todo] & (~cold[todo] | search.prefer) & ~decisive[todo]
        runs: list[_Wave] = []  # the waves the goals that are not staged are polished from
        spent: list[_Wave] = []  # every wave (what the rounds went to)
        polishes, far = np.zeros(n, int), set(np.nonzero(cold)[0].tolist())
        # The waves: every goal's starts together (a decisive hint among them stops the others when it fails, as
        # Search.give_up says); a staged goal's random starts; then WAVE x K random ones for a cold goal that the K
        # starts ended near.
        for wave in ("starts", "more", "random"):
            if wave == "starts":
                goals = todo
            elif wave == "more":
                goals = todo[staged[todo] & ~reach[todo] & (residual[todo] <= RANDOM_NEAR)]
            else:
                goals = todo[~reach[todo] & cold[todo] & (residual[todo] <= WAVE_NEAR)]
                # a goal's random wave when it can pay a few rounds of its starts (not one, which could not reach)
                wave_cost = WAVE_ROUNDS * WAVE * self.starts_per_goal * reach_cost(p.nx)
                goals = goals[meter.left[goals] >= wave_cost] if goals.size and not meter.late() else goals[:0]
            starts, kept = [], []
            for i in goals:
                part = "all" if wave == "random" or not staged[i] else "placed" if wave == "starts" else "random"
                these = self._batch_starts(pts[i], None if hints is None else hints[i], int(wave == "random"),
                                           targets is not None, part)
                if these:  # (a staged goal of a search of K <= 3 starts has no random one)
                    starts.append(these)
                    kept.append(i)
            goals = np.array(kept, int)
            if not goals.size:
                continue
            self.stats[f"wave_{wave}"] = self.stats.get(f"wave_{wave}", 0) + int(goals.size)
            run = self._run_wave(pts, goals, starts, start, targets, decisive if wave == "starts" else None, None
                                 if hints is None else first, meter)
            self._keep_reaching(run, pts, targets, reach, residual, posture)
            # A staged goal is polished after each of its waves, before the next (fatrop from the placed starts' near
            # miss reached a fifth of the goals it was tried on, without the random starts); the others after all.
            polishes += self._polish_missed([run], pts, targets, start, meter, reach, residual, posture, far, staged)
            spent.append(run)
            if wave != "more":
                runs.append(run)
        polishes += self._polish_missed(runs, pts, targets, start, meter, reach, residual, posture, far, ~staged)
        self._unsolved_residuals(pts, residual, posture)
        self.stats["reachable"] += int(reach.sum())
        for run in spent:  # where the rounds went: goals reached, goals never reached (issue 48)
            used = np.add.reduceat(run.rounds, run.offsets[:-1]) if len(run.rounds) else run.rounds
            self.stats["rounds_reached"] = self.stats.get("rounds_reached", 0) + int(used[reach[run.goals]].sum())
            self.stats["rounds_missed"] = self.stats.get("rounds_missed", 0) + int(used[~reach[run.goals]].sum())
        self.stats["polished_missed"] = self.stats.get("polished_missed", 0) + int(polishes[~reach].sum())
        # (a goal its budget cut, or the clock's guard, spent all of it: the caller's "timeout")
        return Verdicts(reach, residual, posture, None if search.max_seconds is None
                        else np.where(meter.cut, budgets, budgets - meter.left))

    def _run_wave(self, pts: np.ndarray, goals: np.ndarray, starts: list[list[np.ndarray]], start: np.ndarray | None,
                  targets: np.ndarray | None, decisive: np.ndarray | None, first: np.ndarray | None,
                  meter: Meter) -> _Wave:
        """The goals' starts iterated together (:func:`oracles.ik.batch.run_starts`)."""
        p, search = self.problem, self.search
        owner = np.concatenate([np.full(len(s), i) for i, s in zip(goals, starts, strict=True)])
        offsets = np.concatenate([[0], np.cumsum([len(s) for s in starts])])
        x0 = np.clip(np.concatenate([np.array(s) for s in starts]), p.lower, p.upper)
        b = len(x0)
        self.stats["solves"] += b
        target = np.tile(self._default_target, (b, 1)) if targets is None else targets[owner]
        params = self._with_body(np.concatenate([pts[owner], x0 if start is None else np.tile(start, (b, 1)),
                                                 np.full((b, 1), 0.0 if start is None else 1.0), target], axis=1))
        first_start = None
        if decisive is not None and decisive.any():
            first_start = np.zeros(b, bool)
            first_start[offsets[:-1][decisive[goals]]] = True
        x, dist, viol, liked, _, rounds = run_starts(
            self.batch_program(), x0, params, owner, self.strategy.tolerance, search.secondary, start, meter,
            self.stats, first_start, search.give_up_distance, self.lower_iter)
        span = p.upper - p.lower
        scored = np.isfinite(liked)
        if scored.any():
            # A reaching start the lower tasks did not score is liked least (at 0 it was liked best: a whole-body
            # refinement kept a posture twice as disliked, a joint at its limit).
            liked = np.where(scored, liked, np.inf)
        else:
            # No lower task (secondary: false): the posture nearest the reference is liked best, as fatrop's reach
            # stage from the reference keeps it (the nearest to the goal was a random start's crouch, its ankle at a
            # limit).
            liked = np.sum(((x - p.x_ref) / span) ** 2, axis=1)
        if first is not None:
            # Continuity with the neighbour's posture (the first hint) is part of "liked".
            liked = liked + CONTINUITY_WEIGHT * np.sum(((x - first[owner]) / span) ** 2, axis=1)
        return _Wave(goals, offsets, x0, x, p.q_of_x_many(x), dist, viol, liked, rounds)

    def _keep_reaching(self, run: _Wave, pts: np.ndarray, targets: np.ndarray | None, reach: np.ndarray,
                       residual: np.ndarray, posture: np.ndarray) -> None:
        """For each goal of a wave, the best-liked posture that passes the verdict's check; or, when none does and
        none did before, the nearest attempt."""
        p, tol = self.problem, self.strategy.tolerance
        for j, i in enumerate(run.goals):
            rows = np.arange(run.offsets[j], run.offsets[j + 1])
            target_i = None if targets is None else targets[i]
            near = rows[(run.dist[rows] <= tol) & (run.viol[rows] <= 1e-5)]
            # Best liked first; among postures liked alike (a strategy without lower tasks) the first start's, in the
            # starts' order (the hint, the reference, the ready posture): by distance, a random start's crouch won a
            # plain reach (tests/test_motion.py's low reach, an ankle at its limit).
            for r in near[np.argsort(run.liked[near], kind="stable")]:
                check = p.check(run.q[r], pts[i], self._data, target_i)
                if check.reachable:
                    reach[i], residual[i], posture[i] = True, check.residual, run.q[r]
                    break
            if reach[i]:
                continue
            r = rows[np.lexsort((run.dist[rows], run.viol[rows] > 1e-5))][0]
            check = p.check(run.q[r], pts[i], self._data, target_i)
            if check.residual < residual[i]:
                residual[i], posture[i] = check.residual, run.q[r]

    def _polish_missed(self, runs: list[_Wave], pts: np.ndarray, targets: np.ndarray | None, start: np.ndarray | None,
                       meter: Meter,
                       reach: np.ndarray, residual: np.ndarray, posture: np.ndarray, far: set[int],
                       mine: np.ndarray) -> np.ndarray:
        """fatrop from a missed goal's best ends: its reaching postures that break a lazy task, then its random
        starts themselves (fatrop's own restarts: another basin), or a near miss (no start reached) from its
        nearest end only: most are beyond the boundary. A near miss is one within ``POLISH_NEAR``, or
        ``POLISH_FAR`` for a cold goal (at the volume's boundary, where a
        Gauss-Newton step slows down and fatrop's second derivatives still find a way). Only the goals in ``mine``
        (a mask of the call's) are polished; returns each goal's polishes."""
        tol, polisher = self.strategy.tolerance, None
        polishes = np.zeros(len(pts), int)
        for run in runs:
            for j, i in enumerate(run.goals):
                if reach[i] or not mine[i]:
                    continue
                rows = np.arange(run.offsets[j], run.offsets[j + 1])
                ranked = rows[np.lexsort((run.dist[rows], run.viol[rows] > 1e-5))]
                if run.dist[ranked[0]] > (POLISH_FAR if i in far else POLISH_NEAR):
                    continue
                reached = rows[run.dist[rows] <= tol]
                ends = [run.x[r] for r in dict.fromkeys([*reached, *ranked[:1]])]
                target_i = None if targets is None else targets[i]
                if reached.size:
                    tries = [*ends, *run.x0[rows[::-1]]][:POLISHES]
                elif target_i is not None and i in far:
                    # A cold goal with a target (an oriented query) that no start reached: fatrop from the starts
                    # themselves too, the hints and the reference first, as the referee starts. Its posture may lie on
                    # a joint's limit, where the clamped Gauss-Newton steps stall (arm7_table: 1 of 75 oriented goals
                    # the referee reaches was missed from the nearest end alone, tests/test_orientation.py).
                    tries = [*ends[:1], *run.x0[rows]][:POLISHES]
                else:
                    tries = ends[:1]
                for guess in tries:
                    if not meter.afford(i, POLISH_COST):
                        break  # its work budget spent (or the clock's guard passed)
                    polisher = polisher or self._polisher()
                    q = polisher.solve(pts[i], guess, self.search.secondary, Call(start, meter.pace.deadline, target_i))
                    self.stats["polished"] = self.stats.get("polished", 0) + 1
                    polishes[i] += 1
                    check = self.problem.check(q, pts[i], self._data, target_i)
                    if check.reachable or check.residual < residual[i]:
                        reach[i], residual[i], posture[i] = check.reachable, check.residual, q
                    if check.reachable:
                        break
        return polishes

    def hold_many(self, postures: np.ndarray, deadline: float = np.inf) -> np.ndarray:
        """The batched engine's hold: every posture's reach steps from itself, all together, towards its own effector
        position with its hard rows held and the least change (the reach task's proximal term); a posture is held
        when the result passes the verdict's own checks (:meth:`faults`). Other engines hold one at a time."""
        q = np.asarray(postures, float)
        if self.solver != "batch" or not len(q):
            return super().hold_many(q, deadline)
        self.prepare()
        p = self.problem
        x0 = np.array([p.x_of_q(v) for v in q])
        out = np.full(q.shape, np.nan)
        # Only postures that the strategy's coordinates describe (its other joints at the reference) are held here;
        # the rest keep the one-at-a-time hold, which moves the whole posture.
        ours = np.all(np.abs(p.q_of_x_many(x0) - q) <= 1e-9, axis=1)
        if not ours.any():
            return out
        x0, goals = x0[ours], self.effector_positions(q[ours])
        b = len(x0)
        params = self._with_body(np.concatenate([goals, x0, np.ones((b, 1)), np.tile(self._default_target, (b, 1))],
                                                axis=1))
        ends = run_starts(self.batch_program(), x0, params, np.arange(b), self.strategy.tolerance, False, x0,
                          Meter.unlimited(b, deadline), self.stats)
        held = p.q_of_x_many(ends.x)
        # The verdict's own checks decide (a held contact row 0.08 mm off, past the engine's 1e-6, holds by its task's).
        ok = ends.dist <= self.strategy.tolerance
        ok[ok] = [not f for f in self.faults(held[ok])]
        rows = np.nonzero(ours)[0]
        out[rows[ok]] = held[ok]
        return out

    def solve(self, goal: np.ndarray, x0: np.ndarray, lower: bool = True, call: Call = NO_CALL) -> np.ndarray:
        self.prepare()
        p = self.problem
        x = np.clip(x0, p.lower, p.upper)
        params = self._params(goal, x, call, pull=not lower)  # settling: the start moved the least (see Search.settle)
        optimum: list[float] = []
        cuts = _Cuts(CUT_SLOTS, p.nx)  # kept from stage to stage: they describe the same neighbourhood
        for k, task in enumerate(self.order):
            stage = self._cut_stage(k, x, params, optimum, cuts, settled=not lower)
            if stage is None:
                break  # keep the last posture; the check decides
            x, value = stage
            optimum.append(value)
            if not task.attained(value) or (not lower and task is self.strategy.reach):
                break  # e.g. unreachable: lower tasks cannot change the verdict
        return p.q_of_x(x)
