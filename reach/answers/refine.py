"""The paper's "additional inverse kinematics simulation": a stored posture refined by IK at the exact goal.

A :class:`Refiner` refines a strategy's goals from the postures its tree stored near them (the nearest and the
best-liked of the ``SEEDS`` nearest), or from the character's own posture, with the strategy's oracle's ``refine``
variant, within a budget: of work with the batched engine, the same answer on any machine
(:class:`oracles.ik.budget.Meter`). Which strategy answers is :mod:`reach.answers.select`'s.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from oracles.protocol import Goals, Oracle, Preferring, Preparable, Tunable, Verdicts
from reach.answers.answer import FAILED, REFINED, TIMEOUT, joint_names, set_joints
from reach.errors import InputError
from reach.maps.protocol import ReachMap

# [s] the least budget of a goal with an orientation: its stored postures hold none, so its refinement tries random
# starts too; within 20 ms it timed out on 4-5 of 72 oriented arm7_table goals the referee reaches (commit 81c9e1e). The
# batched engine's K starts and K random ones take 0.10-0.15 s on an idle machine: 0.2 s timed out on a loaded one (CI).
ORIENTED_BUDGET = 0.5
# The share of a refinement's budget its solve gets, leaving at most SOLVE_RESERVE [s] for the seeding (the best-liked
# stored posture near the goal), the verdict's checks and the answer: 6-8 ms around a solve given all of 20 ms (demo
# atlas, bench/refined.py: its queries took 27-30 ms). An oriented goal's 0.5 s keeps all but that.
SOLVE_SHARE = 0.7
SOLVE_RESERVE = 0.006
# A refinement left less than this share of one goal's budget is not started (a timeout): a handover after a first
# choice that took most of the budget took 2-5 ms more for a solve of 1-2 ms (bench/refined.py).
LEAST_SOLVE = 0.25
# A refinement without `from` also starts from the best-liked of this many
# nearest stored postures (when it is not the nearest's): the nearest can sit
# in a worse basin of the posture task than its neighbours, and two goals 1 cm
# apart then ended in different basins (its measurement not found again: as first written).
SEEDS = 8


Refined = tuple[np.ndarray, "float | None", str]  # a refinement: the posture, its residual [m] and its outcome
Prefetched = dict[str, Refined]  # one goal's refinements made ahead, by strategy (see reach.answers.passes)


@dataclass
class Purse:
    """One goal's refinement budget [s], shared by its refinements (the first choice's, a fallback's, a handover's):
    each pays the work its oracle says it spent (``Verdicts.spent``; an oracle whose budget is the clock, the time it
    took) and the reserve kept for its seeding and checks. Paid by work, what is left is the same for the same
    request on any machine, and so is the answer."""

    left: float

    def pay(self, spent: float) -> None:
        self.left = max(self.left - spent, 0.0)


def start_posture(tree: ReachMap, stored: np.ndarray, start: dict[str, float] | None) -> np.ndarray | None:
    """The query's ``from`` as a full posture: the stored one with the given joints replaced."""
    if start is None:
        return None
    names = tree.posture_names
    unknown = sorted(set(start) - set(joint_names(names)))
    if unknown:
        raise InputError("from", f"unknown joints {unknown[:5]}; the posture's names are "
                                 f"{', '.join(joint_names(names))}")
    q = set_joints(names, stored.copy(), start, "from")
    if "root_qx" in names:  # a client's quaternion, rounded, made a rotation again
        i = names.index("root_qx")
        q[i : i + 4] /= np.linalg.norm(q[i : i + 4])
    return q

class Refiner:
    """Refinements of goals by their strategies (see the module docstring).

    Args:
        maps: The atlas's trees by strategy.
        oracle: A strategy's refinement oracle (its ``refine`` variant) by name.
        budget: One refinement's budget [s].
        neighbours: A strategy's k stored postures (k, nq) nearest a goal, or None when it stores none.
    """

    def __init__(self, maps: Mapping[str, ReachMap], oracle: Callable[[str], Oracle], budget: float,
                 neighbours: Callable[[str, np.ndarray, int], np.ndarray | None]) -> None:
        self.maps, self.oracle, self.budget, self.neighbours = maps, oracle, float(budget), neighbours

    def refine(self, name: str, goal: np.ndarray, q: np.ndarray, residual: float | None,
                start_joints: dict[str, float] | None = None, aim: np.ndarray | None = None,
                done: Prefetched | None = None, purse: Purse | None = None) -> Refined:
        """One goal's refinement by strategy ``name`` from its stored posture q (``residual`` [m] from the goal): from
        the character's posture ``start_joints`` when given, else from q and the best-liked stored posture near it;
        with the goal's orientation ``aim``; taken from ``done`` when made ahead; paid from the goal's ``purse``."""
        if done is not None and name in done:
            q_done, residual_done, outcome = done[name]
            return (q_done, residual_done, outcome) if outcome == REFINED else (q, residual, outcome)
        self.ready(name)
        if start_joints is None:  # from the stored posture and the best liked near it, as a batch's goals are
            return self.refine_many(name, goal[None], q[None], [residual], [aim], None, purse)[0]
        oracle, budget, reserve = self._tuned(name, 1, aim, purse)
        if budget < LEAST_SOLVE * self.budget:
            return q, residual, TIMEOUT
        t0 = time.perf_counter()
        start = start_posture(self.maps[name], q, start_joints)  # from the character's posture
        v = oracle.evaluate(Goals(goal[None], {} if aim is None else {"orientation": aim[None]}, start))
        over = self._spent(v, budget, t0, purse, reserve)[0]
        if v.reachable[0] and v.posture is not None:
            return v.posture[0], float(v.residual[0]), REFINED
        return q, residual, TIMEOUT if over else FAILED

    def ready(self, name: str) -> None:
        """A strategy's solvers built (once; a server's at warm-up), so that building them is never charged to a
        refinement's budget."""
        if isinstance(oracle := self.oracle(name), Preparable):
            oracle.prepare()

    @staticmethod
    def _spent(v: Verdicts, budget: float, t0: float, purse: Purse | None, reserve: float) -> np.ndarray:
        """Which goals of a refinement call spent their budget (``budget`` pooled over them): by the work the oracle
        reports, else by the clock; the goal's purse (a single goal's) pays that and the reserve."""
        n = len(v.reachable)
        spent = (np.full(n, (time.perf_counter() - t0) / n) if v.spent is None
                 else np.asarray(v.spent, float))
        if purse is not None:
            purse.pay(float(spent.sum()) + reserve)
        return spent >= budget / n * (1.0 - 1e-9)  # type: ignore[no-any-return]

    def goal_budget(self, aim: np.ndarray | None) -> float:
        """One goal's refinement budget [s]: the selector's, at least ``ORIENTED_BUDGET`` with an orientation."""
        return self.budget if aim is None else max(self.budget, ORIENTED_BUDGET)

    def _tuned(self, name: str, goals: int, aim: np.ndarray | None,
               purse: Purse | None = None) -> tuple[Oracle, float, float]:
        """The strategy's refinement oracle for ``goals`` goals, its solve's budget [s] (theirs pooled, each at least
        ``ORIENTED_BUDGET`` with an orientation; a single goal's, what its purse has left) and the reserve [s] kept
        from it for the seeding and checks."""
        oracle = self.oracle(name)
        budget = goals * self.goal_budget(aim)
        if purse is not None:
            budget = min(budget, purse.left)
        reserve = min((1.0 - SOLVE_SHARE) * budget, SOLVE_RESERVE)
        budget -= reserve
        if budget > 0 and isinstance(oracle, Tunable):
            oracle = oracle.variant("refine", budget=budget)
        return oracle, budget, reserve

    def refine_many(self, name: str, goals: np.ndarray, stored: np.ndarray, residuals: list[float | None],
                     aims: list[np.ndarray | None], deadline: float | None,
                     purse: Purse | None = None) -> list[Refined]:
        """:meth:`refine` for a strategy's goals (m, 3) in one evaluate call: each from its stored posture and the
        best-liked one near it, within m refinements' budgets. A batch's ``deadline`` leaves its budget whole for as
        many goals, in order, as it has time for; the others are not refined (``timeout``). (Shrunk to the time left,
        the budget was each goal's share of it: a deadline too short for all refined none.)"""
        m = len(goals)
        self.ready(name)
        if deadline is not None:
            k = min(m, max(int((deadline - time.perf_counter()) / self.goal_budget(aims[0])), 0))
            if k < m:
                first = self.refine_many(name, goals[:k], stored[:k], residuals[:k], aims[:k], None) if k else []
                return [*first, *[(q, r, TIMEOUT) for q, r in zip(stored[k:], residuals[k:], strict=True)]]
        tuned, budget, reserve = self._tuned(name, m, aims[0], purse)
        if budget < LEAST_SOLVE * self.budget:
            return [(q, r, TIMEOUT) for q, r in zip(stored, residuals, strict=True)]
        seeds = self._seeds(name, tuned, goals, stored)
        t0 = time.perf_counter()
        targets = {} if aims[0] is None else {"orientation": np.stack(aims)}  # type: ignore[arg-type]
        v = tuned.evaluate(Goals(goals, targets, None, seeds))
        over = self._spent(v, budget, t0, purse, reserve)
        return [(v.posture[k], float(v.residual[k]), REFINED) if v.reachable[k] and v.posture is not None
                else (stored[k], residuals[k], TIMEOUT if over[k] else FAILED) for k in range(m)]

    def _seeds(self, name: str, oracle: Oracle, goals: np.ndarray, stored: np.ndarray) -> np.ndarray:
        """Each goal's starts (m, k, nq): its stored posture, and the best-liked one near it where the oracle likes
        another better (NaN rows: none)."""
        liked = ([self._best_liked(name, oracle, goal, q) for goal, q in zip(goals, stored, strict=True)]
                 if isinstance(oracle, Preferring) else [])
        if not any(q is not None for q in liked):
            return stored[:, None]
        return np.stack([stored, np.array([np.full(stored.shape[1], np.nan) if q is None else q for q in liked])],
                        axis=1)

    def _best_liked(self, name: str, oracle: Preferring, goal: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        """The stored posture the oracle likes best among the ``SEEDS`` reachable vertices nearest the goal,
        None when that is ``q`` itself or the oracle likes them all alike (it cannot tell; see ``SEEDS``)."""
        near = self.neighbours(name, goal, SEEDS)
        if near is None:
            return None
        candidates = list(near)
        liked = [oracle.preference(c, goal) for c in candidates]
        if min(liked) == max(liked):
            return None  # no preference: another start would only cost a solve
        best = candidates[int(np.argmin(liked))]
        return None if np.array_equal(best, q) else best
