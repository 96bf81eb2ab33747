"""The search one start at a time: rounds of solves, each goal from its next start, until it reaches or gives up.

The driver of the solvers that solve a goal at a time (fatrop's and IPOPT's
programs, damped least squares: :class:`oracles.ik.solvers.single.SingleSolver`),
one :class:`Rounds` per ``evaluate`` call. (The batched engine drives its starts
in waves: :mod:`oracles.ik.waves`.) A point is reachable only when the
independent Pinocchio check of its posture says so (:meth:`ReachProblem.check`).
"""

from __future__ import annotations

import time
import zlib
from typing import NamedTuple, Protocol

import numpy as np
import pinocchio as pin

from oracles.ik.problem import Check, ReachProblem
from oracles.ik.search import Search
from oracles.ik.strategy import Strategy
from oracles.protocol import Verdicts, check_points

TARGET_RESTARTS = 4  # random starts at least, for a goal that carries a target (see Rounds.__init__)


class Call(NamedTuple):
    """What one ``evaluate`` call knows beyond its points, passed down to every solve (never stored).

    Attributes:
        start: The character's current posture as the problem's x (``Goals.current``), or None.
        deadline: ``time.perf_counter()`` past which no new solve starts (inf: no budget).
        target: The goal's task targets as the programs' parameters (``Strategy.target_rows``; set per goal),
            or None: the goal carries none.
    """

    start: np.ndarray | None = None
    deadline: float = np.inf
    target: np.ndarray | None = None


NO_CALL = Call()  # a call with neither current posture nor budget


class Searched(Protocol):
    """What the rounds read of their oracle."""

    problem: ReachProblem
    strategy: Strategy
    search: Search
    stats: dict[str, int]


class Solving(Protocol):
    """What the rounds ask of their solver."""

    def solve_many(self, goals: np.ndarray, x0: np.ndarray, lower: np.ndarray | None = None, call: Call = NO_CALL,
                   targets: np.ndarray | None = None) -> np.ndarray: ...

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float: ...


def starts(problem: ReachProblem, search: Search, goal: np.ndarray, hint: np.ndarray | None, call: Call = NO_CALL,
           restarts: int | None = None) -> list[np.ndarray]:
    """Initial postures (as the problem's x): the hint(s), the reference, then seeded random ones (``restarts`` of
    them, the search's by default).

    With ``reference_first`` and no current posture (a refinement without
    ``from``), the reference and then the *ready* posture
    (:attr:`ReachProblem.x_ready`: every joint part of the way to the middle
    of its range, off the reference's straight elbow) come first, and the
    hint rescues a goal both miss.
    """
    out = []
    seeds = np.zeros((0, 0)) if hint is None else np.atleast_2d(hint)  # one hint, or several
    out += [problem.x_of_q(h) for h in seeds if np.all(np.isfinite(h))]
    if search.reference_first and call.start is None:
        out[:0] = [problem.x_home.copy(), problem.x_ready.copy()]
    else:
        out.append(problem.x_home.copy())
    rng = np.random.default_rng([search.seed, zlib.crc32(np.round(goal, 9).tobytes())])
    out += [problem.random_x(rng) for _ in range(search.restarts if restarts is None else restarts)]
    return out


def unsolved_residuals(problem: ReachProblem, data: pin.Data, pts: np.ndarray, residual: np.ndarray,
                       posture: np.ndarray) -> None:
    """A goal no solve reached before the deadline keeps the reference posture: its true distance, not infinity."""
    for i in np.nonzero(np.isinf(residual))[0]:
        residual[i] = problem.effector_distance(posture[i], pts[i], data)


class Rounds:
    """One call's search: each goal's starts solved one round after another (see the module docstring).

    Args:
        oracle: The body, strategy and search of the oracle.
        solver: The solver that solves.
        data: Pinocchio data of the body, for the checks.
        points: Goals (N, 3) [m].
        hints: Each goal's seeds (N, nq) or (N, k, nq), the first standing for the neighbour's posture in a build.
        start: The current posture as the problem's x, or None.
        targets: Each goal's task targets (N, T) (``Strategy.target_rows``), or None.
        q_ref: The posture a goal no solve reached keeps.
    """

    def __init__(self, oracle: Searched, solver: Solving, data: pin.Data, points: np.ndarray, hints: np.ndarray | None,
                 start: np.ndarray | None, targets: np.ndarray | None, q_ref: np.ndarray) -> None:
        self.oracle, self.solver, self.data, self.targets = oracle, solver, data, targets
        self.pts = pts = check_points(points, 3)
        self.hints = None if hints is None else np.asarray(hints, float)
        search, problem, n = oracle.search, oracle.problem, len(pts)
        oracle.stats["points"] += n
        self.call = Call(start, np.inf if search.max_seconds is None else time.perf_counter() + search.max_seconds)
        self.residual = np.array([problem.prefilter(g) for g in pts])
        self.prefiltered = self.residual > oracle.strategy.tolerance
        oracle.stats["prefiltered"] += int(self.prefiltered.sum())
        self.reach = np.zeros(n, bool)
        self.done = np.zeros(n, bool)  # reached, or given up
        # the check of the posture kept so far (a pre-filtered point keeps the reference)
        self.kept: list[Check | None] = [None] * n
        self.posture = np.tile(q_ref, (n, 1))
        self.residual[~self.prefiltered] = np.inf
        self.preferred = np.full(n, np.inf)  # with prefer: the lower tasks' objective of the kept posture
        # A goal with a target (an orientation) gets random starts even in a refinement: the stored postures it is
        # seeded with were found for its position alone (measured on arm7_table: 2 of 24 oriented goals the
        # referee reaches were missed from the four other starts).
        # (Not the index's search, which gives up and tries no random start: its (vertex, direction) goals, about two
        # thirds of them out of reach, each took four more solves, and arm7_table's index 2.5 times as long.)
        restarts = max(search.restarts, TARGET_RESTARTS) if targets is not None and search.give_up is None else None
        self.starts = [starts(problem, search, g, None if self.hints is None else self.hints[i], self.call, restarts)
                       if not self.prefiltered[i] else [] for i, g in enumerate(pts)]
        self.decisive, self.settled = self._hint_gaps()

    def _hint_gaps(self) -> tuple[np.ndarray, np.ndarray]:
        """Per goal: the first start is a warm start from a nearby hint (``decisive``), and so near that it solves
        the reach stage alone (``settled``; see :class:`~oracles.ik.search.Search`)."""
        search, n = self.oracle.search, len(self.pts)
        decisive, settled = np.zeros(n, bool), np.zeros(n, bool)
        hint_first = not (search.reference_first and self.call.start is None)
        hints = self.hints
        first = None if hints is None else (hints[:, 0] if hints.ndim == 3 else hints)
        give_up = search.give_up_distance
        if first is not None and (np.isfinite(give_up) or (search.settle > 0 and hint_first)):
            for i in np.nonzero(~self.prefiltered & np.all(np.isfinite(first), axis=1))[0]:
                gap = self.oracle.problem.effector_distance(first[i], self.pts[i], self.data)
                decisive[i] = np.isfinite(give_up) and gap <= search.decisive
                settled[i] = hint_first and gap <= search.settle
        return decisive, settled

    def run(self) -> Verdicts:
        """Solve round after round; the verdicts."""
        oracle, targets, n = self.oracle, self.targets, len(self.pts)
        for r in range(max(len(s) for s in self.starts) if n else 0):
            todo = np.array([i for i in range(n) if not self.done[i] and len(self.starts[i]) > r], dtype=int)
            if todo.size == 0 or time.perf_counter() > self.call.deadline:
                break
            q = self.solver.solve_many(self.pts[todo], np.array([self.starts[i][r] for i in todo]),
                                   ~self.settled[todo] if r == 0 else None, self.call,
                                   None if targets is None else targets[todo])
            todo = todo[: len(q)]  # the goals solved before the deadline
            oracle.stats["solves"] += int(todo.size)
            for k, i in enumerate(todo):
                self._take(int(i), q[k], r)
        unsolved_residuals(oracle.problem, self.data, self.pts, self.residual, self.posture)
        oracle.stats["reachable"] += int(self.reach.sum())
        return Verdicts(self.reach, self.residual, self.posture)

    def _take(self, i: int, q: np.ndarray, r: int) -> None:
        """Keep goal i's posture q of round r if it is the best so far, and decide whether the goal is done."""
        oracle, search, targets = self.oracle, self.oracle.search, self.targets
        check = oracle.problem.check(q, self.pts[i], self.data, None if targets is None else targets[i])
        if search.prefer and check.reachable:
            call = self.call if targets is None else self.call._replace(target=targets[i])
            liked = self.solver.preference(q, self.pts[i], call)
            if not self.reach[i] or liked < self.preferred[i]:
                self.residual[i], self.posture[i], self.preferred[i], self.kept[i] = check.residual, q, liked, check
            self.reach[i] = True
            return  # every start is tried; the best liked reaching posture is kept
        if search.prefer and self.reach[i]:
            return  # a start that fails never replaces one that reached
        before = self.kept[i]  # hard_ok is asked only between two postures that both fail
        if before is None or (check.hard_ok, -check.residual) > (before.hard_ok, -before.residual):
            self.kept[i], self.residual[i], self.posture[i] = check, check.residual, q
        self.reach[i] = self.done[i] = check.reachable
        # A posture that misses by more than give_up with the engine's own rows held: the lazy ones are only cut
        # once a stage reaches (cutting cannot bring a goal nearer), so they do not count.
        given_up = check.eager_ok and check.residual > search.give_up_distance
        if not self.done[i] and r == 0 and self.decisive[i] and given_up:
            # Given up: no reference start, only the first `rescues` random ones.
            self.starts[i] = [self.starts[i][0], *self.starts[i][2 : 2 + search.rescues]]
