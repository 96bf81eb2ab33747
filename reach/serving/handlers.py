"""The server's operations, one handler each, registered in :data:`HANDLERS` by the operation's name.

:mod:`reach.serving.protocol` declares what each operation takes (its fields and bounds);
a handler here says how the server answers it: at once in its loop (:meth:`Handler.answer`), or handed over
(:meth:`Handler.defer`) to the workers or to the background, then answered from the workers' frames
(:meth:`Handler.finish`) or past its deadline (:meth:`Handler.expire`). The server
(:class:`reach.serving.server.Server`) keeps the sockets, the loop, the pending requests and the workers; a
handler asks it only for what :class:`Broker` names.

Adding an operation is its row in :data:`reach.serving.protocol.OPERATIONS` and its handler in :data:`HANDLERS`;
one the workers answer also names its worker hook (:mod:`reach.serving.services`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Generator
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from reach import __version__
from reach.answers.accommodation import held, run_steps
from reach.answers.answer import ERROR, SKIPPED, Answer, orientation_of
from reach.answers.refine import ORIENTED_BUDGET
from reach.answers.select import Selector
from reach.errors import StoreError, UnknownName
from reach.motion.planner import Planner
from reach.motion.rig import with_bones
from reach.motion.timing import Timing
from reach.serving import cells
from reach.serving import protocol as P
from reach.serving.faults import Faults
from reach.serving.intake import Intake
from reach.serving.ledger import Ledger, Pending
from reach.serving.publishing import Publisher
from reach.serving.reloading import Reloads
from reach.serving.services import place_space, placements
from reach.serving.workers import EXPIRED, Pool, Task, Tasks
from reach.serving.workers import FAILED as WORKER_FAILED

log = logging.getLogger("reach.serving.server")  # the server's: its handlers' messages are its own
SLACK = 5.0  # [s] a query's default deadline: the budget per goal, plus this ...
# [s] ... and at most this: a client that vanished without a deadline of its own holds the workers no longer
MAX_WAIT = 60.0


class Broker(Protocol):
    """What a handler asks of the server."""

    served: cells.Served
    population: tuple[list[Any], np.ndarray, Any] | None
    publisher: Publisher
    pool: Pool | None
    ledger: Ledger
    intake: Intake
    faults: Faults
    reloads: Reloads
    refine: bool
    budget: float
    chunk: int
    atlas_path: Path
    started: float
    requests: int

    @property
    def selector(self) -> Selector: ...

    @property
    def planner(self) -> Planner: ...

    def answer_now(self, seq: int, reply: bytes) -> None: ...

    def reply_pending(self, seq: int) -> None: ...

    def install(self, req: P.Request, path: Path, loaded: Callable[[], cells.Served]) -> dict[str, Any]: ...


class Handler:
    """How the server answers one operation. Answered in the loop by default; a handler that hands its requests
    over says so in :meth:`defer` and answers them in :meth:`finish` and :meth:`expire`."""

    # An answer that costs the loop milliseconds waits in the intake's backlog and is answered in its slices, between
    # other clients' requests (reach.serving.intake), a step at a time (:meth:`steps`).
    costly = False

    def steps(self, server: Broker, req: P.Request) -> Generator[None, None, dict[str, Any] | bytes]:
        """A costly request's answer a step at a time (the loop answers others between them); by default one."""
        yield
        return self.answer(server, req)

    def answer(self, server: Broker, req: P.Request) -> dict[str, Any] | bytes:
        """The result object of a valid request (or its encoding), answered now."""
        raise NotImplementedError(f"{type(self).__name__} answers only in the workers (a server without them "
                                  "cannot answer it)")

    def defer(self, server: Broker, req: P.Request, envelope: list[bytes]) -> bool:
        """Hand a request over the socket to the workers or the background; False when the loop answers it now."""
        return False

    def finish(self, server: Broker, seq: int, pending: Pending, frames: list[bytes], part: int) -> None:
        """Answer a handed-over request's ``part`` from a worker's frames (a handler that hands requests over says
        how)."""
        raise NotImplementedError(f"{type(self).__name__} hands no request over")

    def expire(self, server: Broker, seq: int, pending: Pending) -> None:
        """Answer a handed-over request whose deadline has passed (as :meth:`finish`)."""
        raise NotImplementedError(f"{type(self).__name__} hands no request over")


def stored_answers(selector: Selector, req: P.Request, index: np.ndarray, outcome: str) -> list[bytes]:
    """The stored answers of a query's goals at ``index`` (one lookup for them all), marked with why they were not
    refined."""
    goals = np.asarray(req["goals"], float)[index]
    if not len(goals):
        return []
    if req["orientation"] is not None:  # a stored posture holds no goal's orientation
        return [Answer(req["effector"], tuple(g.tolist()), None, False, refined=outcome).to_json() for g in goals]
    answers = selector.select_many(req["effector"], goals, False)
    return [dataclasses.replace(x, refined=outcome).to_json() if x.refined == SKIPPED else x.to_json()
            for x in answers]


def _deadline(req: P.Request) -> float | None:
    return None if req["deadline"] is None else time.perf_counter() + req["deadline"]


class Query(Handler):
    """Which strategy reaches each goal: stored answers in the loop, refinements in the workers, in chunks."""

    def answer(self, server: Broker, req: P.Request) -> bytes:
        # Without workers the loop refines; a deadline stops it refining, and later goals get their stored postures.
        answers = server.selector.select_many(req["effector"], np.array(req["goals"]), req["refine"],
                                              start=req["from"], miss=req["miss"],
                                              orientation=orientation_of(req["orientation"]), deadline=_deadline(req))
        bodies = [a.to_json() for a in answers]
        server.publisher.publish(req["effector"].encode(), bodies, req)
        return bodies[0] if req["single"] else P.batch_body(bodies)

    def defer(self, server: Broker, req: P.Request, envelope: list[bytes]) -> bool:
        """Hand a query's goals to the workers when they need IK or are many. Everything a worker could refuse is
        checked here first (the effector, the goals' dimension, the ``from`` joints), so a worker only fails on a
        bug."""
        if server.pool is None:
            return False
        goals = np.array(req["goals"])
        selector = server.selector
        refine = server.refine if req["refine"] is None else req["refine"]
        if refine:
            if req["orientation"] is not None:
                aims = orientation_of(req["orientation"])
                selector.oriented(req["effector"], aims[0] if isinstance(aims, list) else aims)  # type: ignore[arg-type]
            # Nothing to refine (an analytic atlas, or no strategy holds a goal): stored answers.
            refine = selector.needs_ik(req["effector"], goals, req["from"])
        elif len(goals) > P.STORED_IN_LOOP:
            selector.check_goals(req["effector"], goals, req["from"])
        if not refine and len(goals) <= P.STORED_IN_LOOP:
            # answered at once; a larger stored batch (1.4-1.8 s for 10,000 in the loop) goes to the workers
            return False
        pool = server.pool
        n = len(goals)
        # stored answers cost little each: a chunk is about 0.15 s
        chunk = pool.chunk(server.chunk) if refine else P.STORED_IN_LOOP
        size = max(1, min(chunk, math.ceil(n / max(1, pool.size))))
        bounds = [(a, min(n, a + size)) for a in range(0, n, size)]
        each = server.budget if req["orientation"] is None else max(server.budget, ORIENTED_BUDGET)
        seq = server.ledger.pend(req, envelope, min(n * each + SLACK, MAX_WAIT) if refine else MAX_WAIT, bounds, n)
        if seq is not None:
            deadline, orientation = server.ledger.pending[seq].deadline, req["orientation"]
            run = P.OPERATIONS[req.op].worker.run  # type: ignore[union-attr]

            def make(part: int) -> Task:
                a, b = bounds[part]
                return Task(seq, part, req["effector"], req["goals"][a:b].tolist(), req["from"], deadline,
                            req["miss"], envelope[0], refine=refine, run=run,
                            orientation=orientation[a:b] if isinstance(orientation, list) else orientation)

            pool.submit(Tasks(make, len(bounds), seq, envelope[0], deadline))
        return True

    def finish(self, server: Broker, seq: int, pending: Pending, frames: list[bytes], part: int) -> None:
        """A worker's answers to a part of the goals (one frame each); their stored answers when it failed."""
        a, b = pending.bounds[part]
        if frames == [EXPIRED]:
            # Its deadline has passed: the part is answered from the store with the request's others, slice by slice.
            if pending.deadline != math.inf:
                pending.deadline = 0.0
            return
        try:
            if len(frames) != b - a or not frames[0].startswith(b"{"):  # a worker's failure, not answers
                log.error("worker failed: %s", b"".join(frames)[:500].decode(errors="replace"))
                frames = stored_answers(server.selector, pending.request, np.arange(a, b), ERROR)
        except Exception as exc:  # noqa: BLE001 - this request's error reply; the others go on
            server.answer_now(seq, server.faults.reply(exc, pending.request.id))
            return
        pending.parts[part] = frames
        if all(p is not None for p in pending.parts):
            server.reply_pending(seq)

    def expire(self, server: Broker, seq: int, pending: Pending) -> None:
        """Its goals not yet refined are answered from the store, slice by slice (the server's loop)."""
        pending.deadline = math.inf
        server.ledger.expiring.append(seq)


class WholeWork(Protocol):
    """An operation one worker answers whole (:class:`Whole`): in ``frames`` frames of JSON, whose reply
    :meth:`reply` makes; ``late`` and ``failed`` begin its timeout's and its failure's messages."""

    frames: int
    late: str
    failed: str

    def answer(self, server: Broker, req: P.Request) -> dict[str, Any] | bytes: ...

    def job(self, server: Broker, req: P.Request) -> tuple[list[list[float]], dict[str, Any]]: ...

    def reply(self, server: Broker, req: P.Request, frames: list[bytes]) -> bytes: ...


class Whole(Handler):
    """A :class:`WholeWork` handed to one worker whole (answered in the loop without workers); it counts as a
    request, not as goals, against what a client may hold."""

    def __init__(self, work: WholeWork) -> None:
        self.work = work

    def answer(self, server: Broker, req: P.Request) -> dict[str, Any] | bytes:
        return self.work.answer(server, req)

    def defer(self, server: Broker, req: P.Request, envelope: list[bytes]) -> bool:
        service = P.OPERATIONS[req.op].worker
        if server.pool is None or service is None:
            return False
        goals, options = self.work.job(server, req)
        seq = server.ledger.pend(req, envelope, MAX_WAIT, [(0, 1)], 0)
        if seq is not None:
            server.pool.submit(Task(seq, 0, req.args.get("effector") or "", goals, req.args.get("from"),
                                    server.ledger.pending[seq].deadline, None, envelope[0], req.op, options,
                                    whole_cost=service.cost, run=service.run))
        return True

    def finish(self, server: Broker, seq: int, pending: Pending, frames: list[bytes], part: int) -> None:
        """The reply of the worker's frames, or its error (``failed: code: message``), or the deadline's
        ``timeout``."""
        rid = pending.request.id
        if frames == [EXPIRED]:
            server.answer_now(seq, P.error_reply(P.TIMEOUT, f"{self.work.late} by its deadline", rid))
        elif len(frames) == self.work.frames and frames[0].startswith(b"{"):
            server.answer_now(seq, P.ok_reply(self.work.reply(server, pending.request, frames), rid))
        else:
            code, _, message = b"".join(frames)[len(WORKER_FAILED):].decode(errors="replace").strip().partition(": ")
            if code not in P.WORKER_ERRORS:
                log.error("worker failed: %s", message[:500])
                code, message = P.INTERNAL, self.work.failed
            server.faults.count += 1
            server.answer_now(seq, P.error_reply(code, message, rid))

    def expire(self, server: Broker, seq: int, pending: Pending) -> None:
        self.finish(server, seq, pending, [EXPIRED], 0)


class Motion:
    """The timed reach motion: two frames, its summary (published) and the whole motion (the reply)."""

    frames, late, failed = 2, "the motion was not planned", "the motion could not be planned"

    def answer(self, server: Broker, req: P.Request) -> bytes:
        # Without workers the loop plans; a deadline stops it (a timeout error), as a worker's does.
        planner = server.planner
        motion = planner.plan(req["effector"], np.array(req["goal"]), req["from"], rate=req["rate"],
                              timing=Timing.from_dict(req["timing"]), miss=req["miss"], deadline=_deadline(req),
                              back=req["return"])
        data = with_bones(motion.to_dict(), motion, planner.body(motion.strategy)) if req["bones"] else motion.to_dict()
        return self.reply(server, req, [P.encode(motion.summary()), P.encode(data)])

    def job(self, server: Broker, req: P.Request) -> tuple[list[list[float]], dict[str, Any]]:
        server.selector.check_goals(req["effector"], np.array([req["goal"]]), req["from"])
        Timing.from_dict(req["timing"])
        return [req["goal"]], {"rate": req["rate"], "timing": req["timing"], "miss": req["miss"],
                               "bones": req["bones"], "return": req["return"]}

    def reply(self, server: Broker, req: P.Request, frames: list[bytes]) -> bytes:
        """Publish the summary (everything but the frames) on the effector's topic; the reply is the whole motion."""
        server.publisher.publish(req["effector"].encode(), [frames[0]], req)
        return frames[1]


class Place:
    """Placements of the served body ranked by its trees against the request's targets (reach.answers.place); with
    workers a worker answers it (seconds at its limit, which held the loop)."""

    frames, late, failed = 1, "the placements were not ranked", "the placements could not be ranked"

    def answer(self, server: Broker, req: P.Request) -> dict[str, Any]:
        # Without workers the loop ranks; a deadline stops it (a timeout error), as a worker's does.
        return placements(server.selector.atlas, req.args, server.selector.policy,  # type: ignore[arg-type]
                          _deadline(req))

    def job(self, server: Broker, req: P.Request) -> tuple[list[list[float]], dict[str, Any]]:
        place_space(req.args)  # too many candidates: bad_request now, not a timeout after a busy worker
        return [], {"fields": req.args}

    def reply(self, server: Broker, req: P.Request, frames: list[bytes]) -> bytes:
        return frames[0]


class Accommodation(Handler):
    """The share of the served population whose trees hold each goal (reach.answers.accommodation.held)."""

    costly = True  # about 20 ms of the loop at its limit (100 members x 2 trees x 1,000 goals, bench/attacks.py)

    def answer(self, server: Broker, req: P.Request) -> dict[str, Any]:
        return run_steps(self.steps(server, req))

    def steps(self, server: Broker, req: P.Request) -> Generator[None, None, dict[str, Any]]:
        """The checks, then a member a step (about 0.2 ms at the limit)."""
        if server.population is None:
            raise P.ProtocolError(P.FORBIDDEN, "this server serves no population; start it with reach serve ATLAS "
                                               "--population FOLDER", req.id)
        atlases, weights, _ = server.population
        effector = req["effector"]
        trees = sum(1 for a in atlases for t in a.trees.values() if t.meta.get("effector") == effector)
        if not trees:
            raise P.ProtocolError(P.UNKNOWN_EFFECTOR, f"no member's strategy has the effector {effector!r}", req.id)
        goals = np.asarray(req["goals"], float)
        if goals.shape[1] != 3:
            raise P.ProtocolError(P.BAD_REQUEST, "goals: expected [x, y, z] each", req.id)
        if len(goals) * trees > P.MAX_ACCOMMODATION_LOOKUPS:
            raise P.ProtocolError(P.TOO_LARGE, f"{len(goals)} goals x {trees} member trees is over the "
                                               f"{P.MAX_ACCOMMODATION_LOOKUPS:,} lookups one accommodation may take; "
                                               "send fewer goals a request", req.id)
        try:
            found = yield from held(atlases, weights, effector, goals, req["relative_to"])
        except UnknownName as exc:
            raise P.ProtocolError(P.BAD_REQUEST, str(exc), req.id) from None
        except StoreError as exc:
            raise P.ProtocolError(P.BAD_REQUEST, f"relative_to: a member's atlas cannot place it: {exc}",
                                  req.id) from None
        return {"members": len(atlases), **found}


class Strategies(Handler):
    def answer(self, server: Broker, req: P.Request) -> dict[str, Any]:
        selector = server.selector
        trees = selector.atlas.trees
        return {"strategies": [
            {"name": n, "effector": e, "priority": int(trees[n].meta.get("priority", 0)),
             "box": trees[n].box.to_dict(), "d_max": trees[n].d_max}
            for n, e in selector.order
        ], "effectors": selector.effectors, "frame": "world: z up, x forward, y left; metres, radians"}


class Cells(Handler):
    """Centres of the reachable cells of each strategy on a regular grid (for markers in RViz), from the fragments
    made when the atlas loaded (reach.serving.cells)."""

    def answer(self, server: Broker, req: P.Request) -> bytes:
        atlas = server.selector.atlas
        return cells.reply(server.served, atlas.select([req["strategy"]] if req["strategy"] else None), req["level"])


class Health(Handler):
    def answer(self, server: Broker, req: P.Request) -> dict[str, Any]:
        pool = server.pool
        return {
            "status": "serving", "protocol": P.VERSION, "atlas": str(server.atlas_path),
            "strategies": len(server.selector.order),
            "uptime": time.monotonic() - server.started, "requests": server.requests, "errors": server.faults.count,
            "workers": 0 if pool is None else pool.size, "pending": len(server.ledger.pending),
            "resends": server.ledger.resends, "worker_restarts": 0 if pool is None else pool.restarts,
            "workers_ready": 0 if pool is None else pool.ready,
            "workers_busy": 0 if pool is None else len(pool.busy),
            "workers_stalled": 0 if pool is None else len(pool.stalled),
            "large_held": server.intake.held, "large_refused": server.intake.refused,
        }


class Hello(Handler):
    def answer(self, server: Broker, req: P.Request) -> dict[str, Any]:
        server.publisher.publish(b"hello", [b"{}"], req)
        return {"published": server.publisher.socket is not None}


class Version(Handler):
    def answer(self, server: Broker, req: P.Request) -> dict[str, Any]:
        return {"protocol": P.VERSION, "reach": __version__, "operations": list(P.OPS)}


class Reload(Handler):
    """Load an atlas and serve it: over the socket the load runs in the background and the reply goes once the loop
    has swapped it in; an in-process call loads and swaps at once."""

    def answer(self, server: Broker, req: P.Request) -> dict[str, Any]:
        path = server.reloads.path(req, server.atlas_path)
        return server.install(req, path, lambda: server.reloads.load(path))

    def defer(self, server: Broker, req: P.Request, envelope: list[bytes]) -> bool:
        server.reloads.later(req, envelope, server.reloads.path(req, server.atlas_path))
        return True


HANDLERS: dict[str, Handler] = {
    "query": Query(), "motion": Whole(Motion()), "place": Whole(Place()), "accommodation": Accommodation(),
    "strategies": Strategies(), "cells": Cells(), "health": Health(), "hello": Hello(), "reload": Reload(),
    "version": Version(),
}

