"""Batches of starts of several calls iterated as one: a population's members solved together.

Each of a population's members has its own oracle (its own body), but with ``body_parameters`` their strategies'
programs are one program with each member's numbers as parameters (:mod:`oracles.ik.parameters`). A member's call
of the batched engine yields its batches of starts (:meth:`oracles.ik.waves.Waves.steps`); those of several members
that share a program are iterated as one batch, each row with its member's numbers, goal budget and coordinate bounds,
and each call takes back its own rows' ends. A batched step costs about the same for 50 rows as for 500 (numpy's and
CasADi's calls, not their arithmetic: a member's 7 targets x 8 starts took 71-111 ms a wave alone, 45-54 ms a member
joined with 7 others; measured here), so a population's direct answers cost less joined.

What a step reads of a batch's other rows (the lazy rows, collisions, near their bound in some posture are evaluated
for all; the active rows are padded to the posture with the most) it reads of its own call's rows alone
(:meth:`BatchProgram.joined`): each call's rows step as they would alone, to rounding (tests/test_joined.py). A
larger batch's linear algebra rounds differently (postures 1e-10 to 1e-6 apart for 16 members' crouch asked alone
and joined), and a search near a basin's edge may then end in another: 96 members x 7 targets x 4 strategies alone
and joined 16 at a time, 1 verdict of 2,688 differed (a crouch to the floor item). Read of the whole joined batch,
one of 3,500 member x target pairs (500 members) lost a verdict alone it had. So the caller keeps its groups fixed
(``reach.answers.accommodation``: groups of members by their order, whatever the processes).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from oracles.ik.batch import Ends, Starts
from oracles.ik.budget import Meter


def run_joined(requests: Sequence[Starts]) -> list[Ends]:
    """Each batch's ends; batches of one program (the same compiled functions, tolerance, stages and clock guard, no
    current posture) iterated as one."""
    out: list[Ends | None] = [None] * len(requests)
    groups: dict[tuple[object, ...], list[int]] = {}
    for k, r in enumerate(requests):
        groups.setdefault(_key(r), []).append(k)
    for key, members in groups.items():
        if key[0] is None or len(members) == 1:
            for k in members:
                out[k] = requests[k].run()
            continue
        for k, ends in zip(members, _joined([requests[k] for k in members]), strict=True):
            out[k] = ends
    return [e for e in out if e is not None]


def _key(r: Starts) -> tuple[object, ...]:
    """What batches must share to run as one (None first: this one runs alone)."""
    program = r.program
    mapped = getattr(program, "_reach", None)
    if r.start is not None or mapped is None:
        return (None, id(r))
    return (id(mapped), r.params.shape[1], r.tolerance, r.lower, r.give_up, r.lower_iter, r.meter.deadline)


def _joined(requests: list[Starts]) -> list[Ends]:
    """The batches as one: rows stacked, goals renumbered, bounds and budgets by row and goal; the ends split back."""
    rows = [len(r.x0) for r in requests]
    goals = [len(r.meter.left) for r in requests]
    row_at = np.concatenate([[0], np.cumsum(rows)])
    goal_at = np.concatenate([[0], np.cumsum(goals)])
    first = requests[0].program
    lower = np.concatenate([np.broadcast_to(r.program.lower_bound, (n, first.n)) for r, n in zip(requests, rows,
                                                                                                    strict=True)])
    upper = np.concatenate([np.broadcast_to(r.program.upper_bound, (n, first.n)) for r, n in zip(requests, rows,
                                                                                                    strict=True)])
    same = bool(np.all(lower == lower[:1]) and np.all(upper == upper[:1]))
    program = first.with_bounds(lower[0].copy(), upper[0].copy()) if same else first.with_bounds(lower, upper)
    program = program.joined(np.repeat(np.arange(len(requests)), rows))
    meter = Meter(np.concatenate([r.meter.left for r in requests]), requests[0].meter.deadline)
    meter.cut = np.concatenate([r.meter.cut for r in requests])
    decisive = None
    if any(r.decisive is not None for r in requests):
        decisive = np.concatenate([np.zeros(n, bool) if r.decisive is None else np.asarray(r.decisive, bool)
                                   for r, n in zip(requests, rows, strict=True)])
    stats: dict[str, int] = {}
    ends = Starts(program, np.concatenate([r.x0 for r in requests]), np.concatenate([r.params for r in requests]),
                  np.concatenate([np.asarray(r.goal_of, int) + a for r, a in zip(requests, goal_at[:-1], strict=True)]),
                  requests[0].tolerance, requests[0].lower, None, meter, stats, decisive, requests[0].give_up,
                  requests[0].lower_iter).run()
    out = []
    total = max(sum(rows), 1)
    for k, r in enumerate(requests):
        a, b = row_at[k], row_at[k + 1]
        r.meter.left[:] = meter.left[goal_at[k] : goal_at[k + 1]]
        r.meter.cut[:] = meter.cut[goal_at[k] : goal_at[k + 1]]
        for name, value in stats.items():  # (the iterations, shared by rows)
            r.stats[name] = r.stats.get(name, 0) + round(value * rows[k] / total)
        given_up = np.zeros(int(np.max(r.goal_of)) + 1 if len(r.goal_of) else 0, bool)  # as run alone
        found = ends.given_up[goal_at[k] : goal_at[k] + len(given_up)]
        given_up[: len(found)] = found
        out.append(Ends(ends.x[a:b], ends.dist[a:b], ends.viol[a:b], ends.liked[a:b], given_up, ends.rounds[a:b],
                        ends.blocked[a:b]))
    return out
