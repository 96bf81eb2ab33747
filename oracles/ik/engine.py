"""The reference IK engine (registry name ``casadi-ik``), on :class:`~oracles.ik.oracle.IKOracle`.

:class:`CasadiIK` is a lexicographic sequence of nonlinear programs
(:mod:`oracles.ik.programs`) solved by an interior-point method (fatrop or
IPOPT) one goal at a time (:mod:`oracles.ik.rounds`), or, by default, by the
batched engine: every goal's starts iterated together
(:mod:`oracles.ik.batch`, driven in waves by :mod:`oracles.ik.waves`), fatrop
polishing near misses. A lower task never degrades a higher one.
"""

from __future__ import annotations

import copy
import dataclasses
import zlib
from typing import Any, ClassVar

import numpy as np

from oracles.errors import OracleError
from oracles.ik.batch import BLOCKED_STARTS, LOWER_ITER, REFINE_LOWER_ITER, STARTS, BatchProgram, run_starts
from oracles.ik.budget import Meter
from oracles.ik.oracle import NO_CALL, Call, fresh_stats
from oracles.ik.programs import CUT_SLOTS, Cuts, ProgramOracle, Programs
from oracles.ik.waves import Waves
from oracles.protocol import Goals, Purpose, Verdicts

SOLVERS = ("batch", "fatrop", "ipopt")  # batch: oracles.ik.batch, every goal x start together (fatrop polishes)
# Batched starts of the search for a home (ReachProblem.x_home; fatrop or IPOPT take half as many random restarts):
# the squat's was found for its hand where it hangs standing from 64, not from the 16 of a cold goal (docs/results.md).
HOME_STARTS = 64
REFINE_SECONDARY_ITER = 40  # iteration cap of the lower stages when refining an answer


class CasadiIK(ProgramOracle):
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
        blocked_starts: The batched engine's fatrop solves from fresh random starts for a goal that its starts reached
            only through a collision (:meth:`oracles.ik.waves.Waves._rescue_blocked`), 0 to 256; ``auto`` (the
            default): ``BLOCKED_STARTS`` for a URDF's body, none for the generated human (docs/results.md, "Robots
            with collisions").
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
                 blocked_starts: int | str = "auto", **kwargs: Any) -> None:
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
        if blocked_starts != "auto" and (isinstance(blocked_starts, bool) or not isinstance(blocked_starts, int)
                                         or not 0 <= blocked_starts <= 256):
            raise OracleError(f"blocked_starts must be 'auto' or a whole number from 0 to 256, got {blocked_starts!r}",
                              oracle=self.name, key="blocked_starts")
        self.max_iter, self.solver, self.secondary_iter, self.starts_per_goal = (int(max_iter), solver,
            int(secondary_iter), starts)
        self.blocked_asked = blocked_starts
        # The generated human's capsules let the batched steps out of a collision: on the truth suite its rescues
        # reached nothing more and cost its hinted goals 12-130 % more CPU; a URDF's meshes fitted by capsules lock
        # joints against each other (example-robot-data's UR5: 19 / 12 cold / hinted misses of 74 without, 6 / 4 with).
        self.blocked_starts: int = (int(blocked_starts) if blocked_starts != "auto"
                                    else 0 if self.body.anthropometry is not None else BLOCKED_STARTS)
        self.lower_iter = LOWER_ITER  # the batched engine's lower-task iterations (more in a refinement: tune)
        self._batch_cache: dict[tuple[Any, ...], BatchProgram] = {}  # shared with variants, as the programs are
        self._set_jit(jit)
        self._cache: dict[tuple[Any, ...], Programs] = {}  # shared with variants (a shallow copy keeps the dict)
        self._set_order()
        self.lazy = [t for t in self.strategy.hard if t.lazy]
        if self.reference_pending:
            self._search_reference()

    def _search_reference(self) -> None:
        """``reference: auto`` where projection found nothing: this engine's search for the effector where it is,
        every hard task held, from the reference and its random restarts, uncompiled (a probe, not worth a compile);
        its posture becomes the reference when it holds the hard tasks (a UR5's tool-down strategy kept
        every joint at zero and warned)."""
        probe = copy.copy(self)
        probe.jit, probe._cache, probe._batch_cache, probe.stats = False, {}, {}, fresh_stats()
        found = probe.evaluate(Goals(self.effector_positions(self.body.q_ref[None])))
        if found.posture is not None and not self.faults(found.posture[:1])[0]:
            self.use_reference(found.posture[0])
            self.reference_pending = False

    def engine_params(self) -> dict[str, Any]:
        out = {"max_iter": self.max_iter, "solver": self.solver, "jit": self.jit_asked,
               "secondary_iter": self.secondary_iter, **({"body_parameters": True} if self.body_parameters else {})}
        if self.solver != "batch":
            return out
        # (`auto` left out: the specs and digests of trees built before it existed stay the same)
        return {**out, "starts": self.starts_per_goal,
                **({} if self.blocked_asked == "auto" else {"blocked_starts": self.blocked_asked})}

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
        if not self.problem.home_sought:
            self._seek_home()
        if self.solver == "batch":
            self.batch_program()
            if self.lazy and not programs.cut_stages:
                # fatrop's polish of a near miss cuts collision rows at once: built within a budget, its programs took
                # 1.2 s of `reach query`'s 1 s (the README's floor goal answered `timeout`, 42 mm short).
                programs.cut_stages = self._build(programs, CUT_SLOTS)

    def _seek_home(self) -> None:
        """Where a strategy whose reference breaks its hard tasks (the squat's hips above its knees, its weight over the
        heels) starts its searches: this engine's answer, from HOME_STARTS starts and never giving up, for the effector
        where the reference holds it. From the standing reference, the squat's cold goals were reached by no placed
        start and by few random ones spread about it (24 of the truth suite's 67 proven goals missed)."""
        p = self.problem
        p.home_sought = True  # before the probe, whose own prepare must not seek again (variants share the problem)
        if not self.faults(self.body.q_ref[None])[0]:
            return
        probe = copy.copy(self)
        probe.starts_per_goal, probe.stats = HOME_STARTS, fresh_stats()
        probe.search = dataclasses.replace(self.search, give_up=None, max_seconds=None,
                                           restarts=max(self.search.restarts, HOME_STARTS // 2))
        found = probe.evaluate(Goals(self.effector_positions(self.body.q_ref[None])))
        if found.reachable[0] and found.posture is not None:
            p.use_home(found.posture[0])

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

    def polisher(self) -> CasadiIK:
        """This oracle with fatrop as its engine (sharing its programs): the batched engine's polish."""
        twin = copy.copy(self)
        twin.solver = "fatrop"
        return twin

    def _evaluate(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                  targets: np.ndarray | None = None) -> Verdicts:
        if self.solver != "batch":
            return super()._evaluate(points, hints, start, targets)
        return Waves(self, points, hints, start, targets).run()

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
        params = self.with_body(np.concatenate([goals, x0, np.ones((b, 1)), np.tile(self.default_target, (b, 1))],
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
        cuts = Cuts(CUT_SLOTS, p.nx)  # kept from stage to stage: they describe the same neighbourhood
        for k, task in enumerate(self.order):
            stage = self._cut_stage(k, x, params, optimum, cuts, settled=not lower)
            if stage is None:
                break  # keep the last posture; the check decides
            x, value = stage
            optimum.append(value)
            if not task.attained(value) or (not lower and task is self.strategy.reach):
                break  # e.g. unreachable: lower tasks cannot change the verdict
        return p.q_of_x(x)
