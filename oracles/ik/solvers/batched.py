"""The batched solver (``batch``, the default): every goal x start of a call iterated together, fatrop polishing.

Its step is :mod:`oracles.ik.batch` (a damped Gauss-Newton step with the hard
rows as an active set, over CasADi functions mapped over a batch); its search
the waves of :mod:`oracles.ik.waves`; its polish of near misses, the
interior-point solver's fatrop programs (:class:`~oracles.ik.solvers.interior.InteriorPoint`),
which it holds and whose formulation its function shares.
"""

from __future__ import annotations

import copy
import zlib
from collections.abc import Generator
from typing import Any

import numpy as np

from oracles.errors import OracleError
from oracles.ik.batch import LOWER_ITER, REFINE_LOWER_ITER, BatchProgram, Ends, Starts, run_starts
from oracles.ik.budget import Meter
from oracles.ik.rounds import NO_CALL, Call
from oracles.ik.solvers.interior import REFINE_SECONDARY_ITER, InteriorPoint
from oracles.ik.solvers.protocol import Room, Solver
from oracles.ik.waves import RANDOM_SPREAD, Waves
from oracles.protocol import Purpose, Verdicts

# Default starts per goal (K): the hint(s), the reference, the ready posture, seeded random ones. Cold goals (no hint,
# seed 7; docs/results.md, IK engines): K = 4 / 8 / 12 reached 96 / 97 / 97 of 200 arm goals and 46 / 48 / 48 of 100
# whole-body ones, at 3.2 / 4.0 / 4.7 and 21.6 / 39.0 / 39.0 ms each: 8 is the fewest that misses none 12 reaches.
STARTS = 8
# the most fatrop solves from fresh random starts of a goal that its starts reached only through a collision (a
# URDF's default of `blocked_starts`): on example-robot-data's UR5 with self-collision and a
# floor box, a suite of 74 proven goals (bench/truth.py --config), misses cold / hinted 19 / 12 with none, 6 / 4 with 12
# (docs/results.md, "Robots with collisions")
BLOCKED_STARTS = 12


class Batched:
    """Every goal x start of a call together (see the module docstring).

    Args:
        room: The oracle's body, strategy and search.
        starts: Starts a goal in the first wave (``STARTS``).
        spread: The share of the way from the home posture to a uniform random one that a floating body's first random
            starts go (default ``RANDOM_SPREAD``, 0.5: uniform hips and ankles throw the held feet metres off); a
            strategy whose answers lie far from its home in posture (the torsion's pelvis turned on its hips) may
            take 1.
        blocked_starts: fatrop solves from fresh random starts for a goal that its starts reached only through a
            collision (:meth:`oracles.ik.waves.Waves._rescue_blocked`), 0 to 256; ``auto`` (the default):
            ``BLOCKED_STARTS`` for a URDF's body, none for the generated human (docs/results.md, "Robots with
            collisions").
        (max_iter, secondary_iter, jit, body_parameters: the polish's, as
        :class:`~oracles.ik.solvers.interior.InteriorPoint`; ``jit`` compiles this solver's function too)
    """

    name = "batch"
    oracle = "casadi-ik"
    thorough = True

    def __init__(self, room: Room, starts: int = STARTS, blocked_starts: int | str = "auto",
                 spread: float | None = None, **polish: Any) -> None:
        self.room = room
        self.polish = InteriorPoint(room, "fatrop", **polish)
        if isinstance(starts, bool) or not isinstance(starts, int) or not 1 <= starts <= 256:
            raise OracleError(f"starts must be a whole number from 1 to 256, got {starts!r}", oracle=self.oracle,
                              key="starts")
        if blocked_starts != "auto" and (isinstance(blocked_starts, bool) or not isinstance(blocked_starts, int)
                                         or not 0 <= blocked_starts <= 256):
            raise OracleError(f"blocked_starts must be 'auto' or a whole number from 0 to 256, got {blocked_starts!r}",
                              oracle=self.oracle, key="blocked_starts")
        if spread is not None and (isinstance(spread, bool) or not isinstance(spread, (int, float))
                                   or not 0 < spread <= 1):
            raise OracleError(f"spread must be a share above 0 and at most 1, got {spread!r}", oracle=self.oracle,
                              key="spread")
        self.starts_per_goal = starts
        self.spread_asked = spread
        self.spread = RANDOM_SPREAD if spread is None else float(spread)
        self.blocked_asked = blocked_starts
        # The generated human's capsules let the batched steps out of a collision: on the truth suite its rescues
        # reached nothing more and cost its hinted goals 12-130 % more CPU; a URDF's meshes fitted by capsules lock
        # joints against each other (example-robot-data's UR5: 19 / 12 cold / hinted misses of 74 without, 6 / 4 with).
        self.blocked_starts: int = (int(blocked_starts) if blocked_starts != "auto"
                                    else 0 if room.body.anthropometry is not None else BLOCKED_STARTS)
        self.lower_iter = LOWER_ITER  # the lower tasks' iterations (more in a refinement)
        self._batch_cache: dict[tuple[Any, ...], BatchProgram] = {}  # shared with twins, as the programs are

    def options(self) -> dict[str, Any]:
        # (`auto` left out: the specs and digests of trees built before it existed stay the same)
        return {**self.polish.options(), "solver": self.name, "starts": self.starts_per_goal,
                **({} if self.blocked_asked == "auto" else {"blocked_starts": self.blocked_asked}),
                **({} if self.spread_asked is None else {"spread": self.spread_asked})}

    def twin(self, room: Room, *, purpose: Purpose | None = None, compiled: bool = True,
             starts: int | None = None) -> Solver:
        # The referee solves with IPOPT, the reference solver; the index with fatrop's programs (one quick verdict a
        # (vertex, direction) from its hints: they solved arm7_table's index at 380 goals/s, the batched steps at
        # 140-160, with their starts and fatrop's polish of the many near misses). A refinement keeps this solver's
        # compiled code (kept on disk and built at warm-up) and lets the lower tasks converge.
        if purpose == "referee":
            return self.polish.twin(room, purpose="referee", compiled=compiled)
        if purpose == "index":
            return self.polish.twin(room, compiled=compiled)
        out = copy.copy(self)
        out.room = room
        out.polish = self.polish.twin(room, compiled=compiled)
        if not compiled:
            out._batch_cache = {}
        if starts is not None:
            out.starts_per_goal = starts
        if purpose == "refine":
            out.polish.secondary_iter = REFINE_SECONDARY_ITER
            out.lower_iter = REFINE_LOWER_ITER
        return out

    @property
    def jit(self) -> bool:
        return self.polish.jit

    def prepare(self) -> None:
        # fatrop's polish of a near miss cuts collision rows at once: built within a budget, its programs took 1.2 s
        # of `reach query`'s 1 s (the README's floor goal answered `timeout`, 42 mm short).
        self.polish.prepare(cut=True)
        self.batch_program()

    def batch_program(self) -> BatchProgram:
        """The compiled function of this oracle's tasks (shared by twins with the same options)."""
        polish, room = self.polish, self.room
        order = polish.order
        key = (polish.jit, tuple(t.type for t in order))
        found = self._batch_cache.get(key)
        if found is None:
            sym, params = polish.formulation.symbols()
            strategy, p = room.strategy, room.problem
            hard = [c for t in strategy.hard for c in t.constraints(sym)]
            lower = list(order[order.index(strategy.reach) + 1 :])
            # Named by what the functions depend on (the body, effector, joints and tasks, and the stages kept), not by
            # the search: a refinement's twin (another budget) shares the build's compiled code on disk (named by the
            # whole spec, the first `reach query` of each strategy compiled for 30-60 s).
            name = f"batch_{zlib.crc32(repr((self.program_key() or room.strategy_params, key[1])).encode()):08x}"
            screened = [c for t in strategy.hard for c in t.screened(sym)]
            found = BatchProgram(sym, params, hard, strategy.reach.held(sym), lower, p.lower, p.upper,
                                 p.upper - p.lower, polish.jit, name, screened)
            self._batch_cache[key] = found
        lo, hi = self.room.problem.lower, self.room.problem.upper
        if not (np.array_equal(found.lower_bound, lo) and np.array_equal(found.upper_bound, hi)):
            found = found.with_bounds(lo, hi)  # another body's program (share): this body's bounds
        return found

    def program_key(self) -> tuple[Any, ...] | None:
        """As :meth:`Formulation.program_key`, with this solver's options."""
        return self.polish.formulation.program_key(self.options())

    @property
    def default_target(self) -> np.ndarray:
        return self.polish.formulation.default_target

    def with_body(self, params: np.ndarray) -> np.ndarray:
        return self.polish.formulation.with_body(params)

    def solve(self, goal: np.ndarray, x0: np.ndarray, lower: bool = True, call: Call = NO_CALL) -> np.ndarray:
        return self.polish.solve(goal, x0, lower, call)

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float:
        return self.polish.preference(posture, goal, call)

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                 targets: np.ndarray | None) -> Verdicts:
        return Waves(self.room, self, points, hints, start, targets).run()

    def evaluate_steps(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                       targets: np.ndarray | None) -> Generator[Starts, Ends, Verdicts]:
        """:meth:`evaluate`, yielding its batches of starts for the caller to iterate (:mod:`oracles.ik.joined`)."""
        return Waves(self.room, self, points, hints, start, targets).steps()

    def hold_many(self, postures: np.ndarray, deadline: float = np.inf) -> np.ndarray:
        """Every posture's reach steps from itself, all together, towards its own effector position with its hard rows
        held and the least change (the reach task's proximal term); a posture is held when the result passes the
        verdict's own checks (the room's ``faults``)."""
        q = np.asarray(postures, float)
        out = np.full(q.shape, np.nan)
        if not len(q):
            return out
        self.prepare()
        room, p = self.room, self.room.problem
        x0 = np.array([p.x_of_q(v) for v in q])
        # Only postures that the strategy's coordinates describe (its other joints at the reference) are held here;
        # the rest keep the one-at-a-time hold, which moves the whole posture.
        ours = np.all(np.abs(p.q_of_x_many(x0) - q) <= 1e-9, axis=1)
        if not ours.any():
            return out
        x0, goals = x0[ours], room.effector_positions(q[ours])
        b = len(x0)
        params = self.with_body(np.concatenate([goals, x0, np.ones((b, 1)), np.tile(self.default_target, (b, 1))],
                                               axis=1))
        tolerance = room.strategy.tolerance
        ends = run_starts(self.batch_program(), x0, params, np.arange(b), tolerance, False, x0,
                          Meter.unlimited(b, deadline), room.stats)
        held = p.q_of_x_many(ends.x)
        # The verdict's own checks decide (a held contact row 0.08 mm off, past the engine's 1e-6, holds by its task's).
        ok = ends.dist <= tolerance
        ok[ok] = [not f for f in room.faults(held[ok])]
        rows = np.nonzero(ours)[0]
        out[rows[ok]] = held[ok]
        return out

    def share(self, other: Solver) -> bool:
        if not isinstance(other, Batched) or not self.polish.formulation.shares_programs(
                self.options(), other.polish.formulation, other.options()):
            return False
        self.polish._cache, self._batch_cache = other.polish._cache, other._batch_cache
        return True
