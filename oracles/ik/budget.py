"""The work budget of a call: each goal's share, spent by the rounds of its starts, priced in the reference machine's
seconds, with the wall clock only a guard (so that the same request gets the same answer on any machine and load).

:class:`Meter` holds the goals' budgets and the clock's guard; the prices (:func:`reach_cost`, :func:`lower_cost`,
``POLISH_COST``) are what a round costs, measured on the reference machine.
"""

from __future__ import annotations

import time

import numpy as np

# A refinement's budget is work, not time, so that the same request gets the same answer on any machine and load
# (its rounds cut by the clock, 8 of 30 arm answers asked twice differed, by up to 0.1 rad). [s] what one
# start's round costs on the reference machine (AMD EPYC, one core; docs/results.md, "Refined queries"): a reach round
# 155-211 us for the demo's strategies (7 to 36 coordinates), a round of the lower tasks (their step, the step back to
# the goal, two evaluations) 1.27, 1.97, 2.26 and 2.37 ms for 7, 18, 34 and 36 coordinates; both scaled for what a
# call spends beside its rounds (the starts' checks, the liked scores), which grows with the coordinates: a call's
# time over its rounds' cost was 0.85, 1.26, 1.61 and 1.72 (medians of 30 refinements a strategy).
REACH_COST = 2.0e-4
LOWER_COST = 1.2e-3
LOWER_COST_PER_COORD = 3.5e-5


def _cost_scale(n: int) -> float:
    """The share of a call's time its rounds' cost leaves out, for ``n`` coordinates (fit to the figures above)."""
    return 0.6 + 0.03 * n


def reach_cost(n: int) -> float:
    """[s] a start's reach round at ``n`` coordinates, what a call spends beside it included."""
    return REACH_COST * _cost_scale(n)


def lower_cost(n: int) -> float:
    """[s] a start's round of the lower tasks at ``n`` coordinates, what a call spends beside it included."""
    return (LOWER_COST + LOWER_COST_PER_COORD * n) * _cost_scale(n)


POLISH_COST = 5e-3  # [s] a fatrop polish, charged whole (it is not cut: a solve's result must not depend on the clock)
WAVE_ROUNDS = 3  # a goal's random wave is started when its budget pays this many rounds of the wave's starts
# The clock's guard of a work budget: this many times the budget (an overloaded machine still answers, then not
# deterministically). At 3 times, beside two to four CPU-bound processes on 2 cores the guard cut 1 refinement in 20
# goals in 3 of 8 runs and the same request got another answer; a machine ten times as slow as the reference keeps
# its answers now, at the price of a cut refinement's answer coming up to 10 times its budget late.
GUARD = 10.0


class Meter:
    """Each goal's work budget [s of the reference machine's time, see REACH_COST], spent by rounds of its starts:
    a goal whose budget cannot pay its starts' next round stops there (``cut``). The wall clock is only a guard
    (``deadline``: an overloaded machine still answers in bounded time, then not deterministically)."""

    def __init__(self, budgets: np.ndarray, deadline: float = np.inf) -> None:
        self.left = np.asarray(budgets, float).copy()
        self.cut = np.zeros(len(self.left), bool)
        self.deadline = deadline

    @staticmethod
    def unlimited(goals: int, deadline: float = np.inf) -> Meter:
        """No work budget (a build, a hold), the clock's guard alone."""
        return Meter(np.full(goals, np.inf), deadline)

    def pay(self, goals: np.ndarray, cost: float) -> np.ndarray:
        """Charge each of ``goals`` (a goal index per start, repeated) ``cost`` a start; returns which starts are paid
        for: those of the goals that can pay them all (the others are cut)."""
        # The guard is the time itself, not a look one round ahead: beside two CPU-bound processes a round's time
        # (the process descheduled) doubled as a look ahead cut refinements well inside the guard, and the same
        # request got another answer (tests/test_select.py's clock test, 2 of 5 runs).
        if self.late():
            self.cut[goals] = True
            return np.zeros(len(goals), bool)
        need = np.bincount(goals, minlength=len(self.left)) * cost
        can = self.left >= need
        broke = ~can & (need > 0)
        self.cut |= broke
        self.left[can] -= need[can]
        return can[goals]  # type: ignore[no-any-return]

    def late(self) -> bool:
        """Whether the guard's deadline has passed."""
        return time.perf_counter() > self.deadline

    def afford(self, goal: int, cost: float) -> bool:
        """Charge one goal ``cost`` when it can pay it (a fatrop polish)."""
        if self.late() or self.left[goal] < cost:
            self.cut[goal] = True
            return False
        self.left[goal] -= cost
        return True
