"""The requests a broker has handed to its workers: each one's parts, deadline and share of what a client may hold.

A resend of a request being worked on (same client, same id) is not computed again; a client, and every client
together, hold at most the queued work docs/protocol.md's limits allow (``busy`` otherwise).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from reach.serving import protocol as P

# [s] a query's goal, of the time kept before its deadline to answer it from the store if unrefined: twice the 0.15 ms
# a stored answer takes the loop (a pass also serves other clients between slices)
STORED_RESERVE = 3e-4
# [s] how much later a request being answered from the store may be answered for a new one due before it (a few
# goals' worth: a single query is not refused for it)
SPARE = 0.01


@dataclass
class Pending:
    """A request the workers are answering."""

    envelope: list[bytes]
    request: P.Request
    key: tuple[bytes, bytes] | None  # (client, id): a resend of it is not computed again
    deadline: float
    parts: list[list[bytes] | None]
    bounds: list[tuple[int, int]]
    goals: int = 0  # the goals it holds of its client's share (0: a request answered whole counts as a request)
    due: float = math.inf  # when its reply is promised (time.monotonic()); ``deadline`` is when its workers stop


class Ledger:
    """The pending requests, by sequence number (see the module docstring).

    Attributes:
        pending: The requests being answered, by sequence number.
        expiring: Requests past their deadline, answered from the store slice by slice.
        held: Goals each client has pending; ``held_requests``: its requests.
        resends: Resends of a pending request, answered once.
    """

    def __init__(self) -> None:
        self.pending: dict[int, Pending] = {}
        self.by_key: dict[tuple[bytes, bytes], int] = {}
        self.expiring: deque[int] = deque()
        self.held: dict[bytes, int] = {}
        self.held_requests: dict[bytes, int] = {}
        self.resends = 0
        self._seq = 0

    def pend(self, req: P.Request, envelope: list[bytes], wait: float, bounds: list[tuple[int, int]],
             goals: int) -> int | None:
        """Register a request the workers will answer in ``bounds`` parts, by its deadline (``wait`` [s] unless it
        gives one), holding ``goals`` of its client's share; its sequence number, or None for a resend of a request
        being worked on (answered once)."""
        key = (envelope[0], P.encode_value(req.id)) if req.id is not None else None
        if key is not None and key in self.by_key:
            self.resends += 1
            return None
        self._admit(envelope[0], goals, req.id)
        if goals:
            # One array, not a list of lists: a held 10,000-goal batch was 40,000 objects for the garbage collector
            # to scan on every full collection, in the loop.
            req.args["goals"] = np.asarray(req["goals"], float)
        given = req.args.get("deadline")
        now = time.monotonic()
        due = now + (given if given is not None else wait)
        stop = self._stops(due, goals, given, req.id, now)
        self._seq += 1
        self.pending[self._seq] = Pending(envelope, req, key, stop, [None] * len(bounds), bounds, goals, due)
        self.held[envelope[0]] = self.held.get(envelope[0], 0) + goals
        self.held_requests[envelope[0]] = self.held_requests.get(envelope[0], 0) + 1
        if key is not None:
            self.by_key[key] = self._seq
        return self._seq

    def _stops(self, due: float, goals: int, given: float | None, rid: Any, now: float) -> float:
        """When a new request's workers stop (its ``deadline``), the earlier requests' moved sooner, so that every
        query's goals still unrefined then are answered from the store by its due time; raises ProtocolError (nothing
        changed) when they would not be.

        The loop answers them one slice a pass, the soonest due first (:meth:`soonest_expiring`): a request's workers
        stop the store's time for its own goals and those of every query due no later before its due time. (Six
        10,000-goal batches with 3.5 s deadlines, each stopping 3 s early for its own goals alone, were answered up
        to 0.24 s late: 60,000 goals from the store take the loop 9 s.)"""
        queue = sorted([(p.due, p.goals, seq) for seq, p in self.pending.items() if p.goals] + [(due, goals, 0)])
        held, stops = 0, {}
        for when, count, seq in queue:
            held += count
            stops[seq] = when - held * STORED_RESERVE
        if not goals:
            return due  # answered whole by a worker: no goal of it is answered from the store
        own = goals * STORED_RESERVE
        if given is not None and own > given:
            raise P.ProtocolError(P.TIMEOUT, f"{goals} goals take about {own:.2f} s to answer from the stored "
                                             f"postures alone, more than the deadline of {given:g} s: give a longer "
                                             "deadline or fewer goals", rid)
        # An earlier request whose workers would have had to stop already (or that is being answered from the store)
        # may be delayed by at most SPARE.
        late = [seq for seq, stop in stops.items()
                if (stop < now if not seq else stop < now - SPARE and self.pending[seq].deadline > stop)]
        if late:
            soonest = min(self.pending[seq].due for seq in stops if seq) if len(stops) > 1 else now
            raise P.ProtocolError(P.BUSY, f"{goals} goals with the {held - goals} queued would take the server "
                                          f"about {held * STORED_RESERVE:.2f} s to answer from the stored postures, "
                                          "past a deadline; retry in about "
                                          f"{max(0.1, round(soonest - now, 1)):g} s, or give a longer deadline", rid)
        for seq, stop in stops.items():
            if seq and stop < self.pending[seq].deadline < math.inf:  # inf: being answered from the store
                self.pending[seq].deadline = stop
        return stops[0]

    def soonest_expiring(self) -> int:
        """The expiring request due soonest: its goals are answered from the store first."""
        return min(self.expiring, key=lambda seq: self.pending[seq].due if seq in self.pending else -math.inf)

    def _admit(self, client: bytes, goals: int, rid: Any) -> None:
        """Refuse with ``busy`` work that would take a client, or every client together, over what the server holds
        queued (docs/protocol.md, limits): memory is bounded whatever the deadlines, and a client that left holds
        at most its share until its requests' deadlines."""
        mine, requests, total = self.held.get(client, 0), self.held_requests.get(client, 0), sum(self.held.values())
        server_full = total + goals > P.MAX_QUEUED_GOALS
        if not server_full and mine + goals <= P.MAX_CLIENT_GOALS and requests + 1 <= P.MAX_CLIENT_REQUESTS:
            return
        what = (f"the server has {total} goals queued (at most {P.MAX_QUEUED_GOALS})" if server_full else
                f"this client has {mine} goals in {requests} requests queued (at most {P.MAX_CLIENT_GOALS} goals, "
                f"{P.MAX_CLIENT_REQUESTS} requests)")
        # By its deadline at the latest, the soonest of the work counted is answered (an expiring one: within passes).
        now = time.monotonic()
        soonest = min((min(p.deadline, now) for p in self.pending.values() if server_full or p.envelope[0] == client),
                      default=now)
        retry = max(0.1, round(soonest - now, 1))
        raise P.ProtocolError(P.BUSY, f"{what}; retry in about {retry:g} s, when some of it is answered", rid)

    def wait(self, busy: bool) -> float:
        """How long [s] a broker's loop may wait for messages: none when requests are expiring or it is ``busy``
        (publishing), else until the soonest deadline, at most a poll's timeout."""
        if self.expiring or busy:
            return 0.0
        soonest = min((p.deadline for p in self.pending.values()), default=math.inf)
        return max(0.0, min(P.POLL_MS / 1000.0, soonest - time.monotonic()))

    def pop(self, seq: int) -> Pending:
        """Forget an answered request, and its share of its client's held work."""
        pending = self.pending.pop(seq)
        if pending.key is not None:
            self.by_key.pop(pending.key, None)
        client = pending.envelope[0]
        left = self.held.get(client, 0) - pending.goals
        requests = self.held_requests.get(client, 0) - 1
        if left > 0 or requests > 0:
            self.held[client], self.held_requests[client] = max(left, 0), max(requests, 0)
        else:
            self.held.pop(client, None)
            self.held_requests.pop(client, None)
        return pending
