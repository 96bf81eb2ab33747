"""``reach serve``: the real-time strategy selector over ZeroMQ.

One ROUTER socket answers requests (REQ and DEALER clients alike); one PUB
socket publishes every choice, topic = the effector, with the request's id
and tag. One poll loop with a timeout; nothing a client sends can stop it:
every malformed request gets a structured error reply (see
:mod:`reach.serving.protocol` and docs/protocol.md), and an unexpected exception
becomes an ``internal`` error reply. SIGINT and SIGTERM stop the loop
cleanly when the server runs in the main thread.

With ``workers`` > 0 the loop is a load-balancing broker (zguide, chapter
3): it answers ``health``, ``strategies``, ``cells`` and stored-posture
queries itself, at once, and hands every query that needs IK refinement to
worker processes (:mod:`reach.serving.workers`), split into chunks; it works on
many requests concurrently. A request's ``deadline`` (or a default of the
budget per goal plus 5 s) bounds it: when it passes, the goals not yet
refined keep their stored postures, marked ``timeout``, the reply goes, and
the request's queued work is dropped. A resend of a pending request (same
client, same id) is answered once.

``reload`` (only with ``allow_reload``) loads the new atlas in a thread
while the current one answers, and the loop swaps it in when it is ready.

Binds to 127.0.0.1 by default. With a CURVE secret-key file (as written by
``zmq.auth.create_certificates``) both sockets encrypt, and clients must
know the server's public key.
"""

from __future__ import annotations

import gc
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import numpy as np
import zmq

from reach.answers.accommodation import load_members
from reach.answers.answer import TIMEOUT
from reach.answers.select import HANDOVER, MISS, REFINE_BUDGET, Selector
from reach.errors import InputError, ReachError
from reach.maps.atlas import load_atlas
from reach.maps.protocol import DEFAULT_POLICY
from reach.motion.planner import Planner
from reach.serving import cells
from reach.serving import protocol as P
from reach.serving.faults import Faults
from reach.serving.handlers import HANDLERS, stored_answers
from reach.serving.intake import Intake, Work, envelope_of
from reach.serving.ledger import Ledger, Pending
from reach.serving.publishing import Publisher
from reach.serving.reloading import Reloads
from reach.serving.sockets import check_endpoint, curve_keys, sockets
from reach.serving.workers import FAILED as WORKER_FAILED
from reach.serving.workers import Pool, Task

log = logging.getLogger("reach.serving.server")
READY_WAIT = 300.0  # [s] reach serve waits at most this for its workers to load the atlas before serving
REVIVE_EVERY = 0.5  # [s] how often the loop looks for dead workers
FAILED_TASK = WORKER_FAILED + b" the worker died"
ZERO_COPY = 1 << 16  # [bytes] replies this large or larger are sent without copying (pyzmq: copy=False)
# stored answers an expired request gets per pass of the loop (about 15 ms of it: 0.15 ms a goal, measured)
EXPIRE_SLICE = 100


class Server:
    """The selector behind a ROUTER and a PUB socket.

    Args:
        atlas: Atlas folder to serve.
        bind: Address of the request socket.
        pub: Address of the publishing socket, or None for none.
        policy: Boundary-cell policy of the selector.
        refine: Refine postures by IK unless a request says otherwise.
        budget: Time budget of one refinement [s] (per goal).
        handover: [rad] A strategy whose posture has joints this near their
            limits hands the goal over (see :mod:`reach.answers.select`); 0: plain priority.
        miss: What a goal the trees hold but no refinement reaches answers,
            ``unreachable`` or ``within`` (see :mod:`reach.answers.select`), unless a request says.
        allow_reload: The folder under which ``reload`` may load atlases; None
            (the default) refuses every ``reload``.
        curve_clients: With ``curve_secret``, a folder of client public-key
            files (``*.key``): only those clients are let in (pyzmq's ZAP
            authenticator). Without it any client key pair is accepted.
        chunk: Refined goals per worker task at most. Within it a task is
            sized by the goals' measured cost to take about one refinement
            budget (``reach.serving.workers.TASK_SECONDS``): a query waits for a busy
            worker to finish its task, so the chunks stay small enough to share
            the workers between clients, and large enough to refine together.
        curve_secret: Path of the server's CURVE secret-key file, or None.
        context: A zmq context (a new one by default).
        workers: Refinement worker processes; 0 refines in the request loop.
    """

    def __init__(
        self, atlas: str | Path, bind: str = P.DEFAULT_BIND, pub: str | None = P.DEFAULT_PUB, *,
        policy: str = DEFAULT_POLICY, refine: bool = True, budget: float = REFINE_BUDGET,
        curve_secret: str | Path | None = None, context: zmq.Context | None = None, workers: int = 0,
        handover: float = HANDOVER, miss: str = MISS, allow_reload: str | Path | None = None,
        curve_clients: str | Path | None = None, chunk: int = P.CHUNK_GOALS, population: str | Path | None = None,
    ) -> None:
        if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
            raise InputError("--chunk", f"expected a whole number of goals >= 1, got {chunk!r}")
        self.chunk = chunk
        # reload is off unless the operator names the folder under which atlases may be loaded.
        self.reloads = Reloads(allow_reload, self._load)
        keys = curve_keys(curve_secret, curve_clients)  # before any socket
        check_endpoint(bind, "--bind")
        if pub:
            check_endpoint(pub, "--pub")
        self.atlas_path = Path(atlas)
        self.refine, self.budget = refine, budget
        # The selector's options, as the workers' selectors get them too.
        self.options: dict[str, Any] = {"policy": policy, "refine": refine, "budget": budget, "handover": handover,
                                        "miss": miss}
        atlas_now = load_atlas(self.atlas_path)  # a bad atlas refused before any worker starts
        self.context = context or zmq.Context.instance()
        # The workers start first and build their solvers while this process builds its own: one after the other,
        # "serving" came 12.3 s after launch on the demo (2 cores, warm cache; docs/results.md).
        self.pool = Pool(self.context, self.atlas_path, self.options, int(workers)) if workers > 0 else None
        try:
            self.served = cells.serve(Selector(atlas_now, **self.options).warm_up())
            # A population's member atlases, for "accommodation" (the trees' word, answered in the loop).
            self.population = None if population is None else load_members(population)
            self.router, publisher, self.authenticator = sockets(self.context, bind, pub, keys, curve_clients)
        except BaseException:
            if self.pool is not None:
                self.pool.close()
            raise
        self.endpoint = cast(bytes, self.router.getsockopt(zmq.LAST_ENDPOINT)).decode()
        self.pub_endpoint = (None if publisher is None
                             else cast(bytes, publisher.getsockopt(zmq.LAST_ENDPOINT)).decode())
        self.publisher = Publisher(publisher, sliced=self.pool is not None)
        self.intake = Intake(self.router, self.handle, self._send)
        self._stop = threading.Event()
        # set by SIGINT/SIGTERM: a handler that only assigns can never deadlock (Event.set locks)
        self._signalled = False
        self.started = time.monotonic()
        self.requests = 0
        self.faults = Faults()
        self.ledger = Ledger()  # the requests the workers answer
        self._planner: Planner | None = None  # motions without workers, made on the first

    # -- lifecycle ---------------------------------------------------------
    def wait_ready(self, timeout: float = READY_WAIT) -> int:
        """Take the workers' READY messages until every worker has loaded the atlas and refined once (or ``timeout``
        [s] passes): a client that connects when ``reach serve`` says it serves gets refined answers at once (issue
        49: the first refined query waited 5 s for workers still starting, and came back ``timeout``). Returns how
        many workers are ready."""
        if self.pool is None:
            return 0
        end = time.monotonic() + timeout
        while self.pool.ready < self.pool.size and time.monotonic() < end:
            if self.pool.backend.poll(100):
                self.pool.receive()
            for task in self.pool.revive():  # a worker that died starting is started again
                self._finished(task, [FAILED_TASK])
        return self.pool.ready

    def stop(self) -> None:
        """Ask the loop to finish (thread- and signal-safe)."""
        self._stop.set()

    def handle_signals(self) -> None:
        """Make SIGINT and SIGTERM end the loop (from the main thread only; before "serving" is printed, so that a
        signal sent as soon as it is seen is the server's)."""
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                # Only a flag: Event.set() takes a lock, and a second signal arriving inside it blocked the process for
                # good.
                signal.signal(sig, lambda signum, frame: setattr(self, "_signalled", True))

    @property
    def running(self) -> bool:
        """Whether the loop goes on: neither stop() nor a signal has asked it to end."""
        return not (self._signalled or self._stop.is_set())

    def close(self) -> None:
        self.reloads.close()
        if self.pool is not None:
            self.pool.close()
        self.router.close(linger=0)
        if self.publisher.socket is not None:
            self.publisher.socket.close(linger=0)
        if self.authenticator is not None:
            self.authenticator.stop()

    def serve_forever(self) -> None:
        """Poll and answer until stop() or SIGINT/SIGTERM."""
        self.handle_signals()
        # What is loaded now lives as long as the server: keep it out of the
        # garbage collector's scans, which otherwise show in the latency tail.
        gc.collect()
        gc.freeze()
        try:
            if self.pool is None:
                # A blocking receive with a timeout wakes fastest; the timeout lets the
                # loop see a stop request within POLL_MS.
                self.router.setsockopt(zmq.RCVTIMEO, P.POLL_MS)
                while self.running:
                    try:
                        # No wait while large requests are held: they are read in slices between others.
                        first = self.router.recv_multipart(zmq.NOBLOCK if self.intake else 0, copy=False)
                    except zmq.Again:
                        first = None
                    if first is not None:
                        self.intake.read(first)
                    self.intake.run()
                    self._swap()
            else:
                self._broker()
        finally:
            self.close()

    def _broker(self) -> None:
        """The loop with workers: clients in front, workers behind, deadlines in between."""
        assert self.pool is not None
        poller = zmq.Poller()
        poller.register(self.router, zmq.POLLIN)
        backend = None
        next_check = time.monotonic() + REVIVE_EVERY
        while self.running:
            if backend is not self.pool.backend:  # a reload replaced the workers
                if backend is not None:
                    poller.unregister(backend)
                backend = self.pool.backend
                poller.register(backend, zmq.POLLIN)
            wait = self.ledger.wait(bool(self.publisher.queue) or bool(self.intake))
            events = dict(poller.poll(int(math.ceil(wait * 1000))))
            if self.router in events:  # clients first: a stored answer never waits behind workers' results
                self.intake.read()
            self.intake.run()
            while backend in events and backend.poll(0):  # everything the workers have sent
                got = self.pool.receive()
                if got is not None:
                    self._finished(*got)
            if time.monotonic() >= next_check:
                next_check = time.monotonic() + REVIVE_EVERY
                for task in self.pool.revive():  # a crashed worker's chunk is answered from the store
                    log.error("a refinement worker died; restarted it")
                    self._finished(task, [FAILED_TASK])
            self._expire()
            self.publisher.drain()
            self._swap()

    # -- one request -------------------------------------------------------
    def handle(self, frames: list[bytes], later: bool = False) -> None:
        """Answer one multipart message (``later``: taken from the intake's backlog, answered now whatever its cost);
        never raises for anything a client sent."""
        envelope, rest = envelope_of(frames)
        self.requests += 1
        try:
            if len(rest) != 1:
                reply: bytes | None = P.error_reply(P.BAD_FRAMES, "expected one payload frame after the envelope, "
                                                                  f"got {len(rest)}")
            else:
                reply = self.respond(rest[0], envelope, later)
        except Exception as exc:  # noqa: BLE001 - the last guard: respond() catches, but nothing may end the loop
            self.faults.internal(exc)
            reply = P.error_reply(P.INTERNAL, "the reply could not be made")
        if reply is not None:
            self._send(envelope, reply)

    def _send(self, envelope: list[bytes], reply: bytes) -> None:
        try:
            # A large reply is handed to libzmq without a copy (pyzmq's advice past about 64 KB).
            self.router.send_multipart([*envelope, reply], zmq.NOBLOCK, copy=len(reply) < ZERO_COPY)
        except zmq.ZMQError as exc:  # the peer vanished, or its queue is full
            log.warning("reply dropped: %s", exc)

    def respond(self, payload: bytes, envelope: list[bytes] | None = None, later: bool = False) -> bytes | None:
        """The reply to one payload, or None when the workers, the background or a later slice of the loop will
        answer it."""
        rid = None
        try:
            req = P.parse_request(payload)
            rid = req.id
            if envelope is not None and HANDLERS[req.op].defer(self, req, envelope):
                return None  # the workers or the background answer it
            if envelope is not None and not later and HANDLERS[req.op].costly:
                self.intake.hold(envelope, self._stepper(envelope, req), len(payload), rid)
                return None
            return _ok(HANDLERS[req.op].answer(self, req), rid)  # answered now by its operation's handler
        except Exception as exc:  # noqa: BLE001 - nothing a client sends may stop the server
            return self.faults.reply(exc, rid)

    def _stepper(self, envelope: list[bytes], req: P.Request) -> Work:
        """A costly request's answer as the intake's work: a step a call, then the reply."""
        steps = HANDLERS[req.op].steps(self, req)

        def step() -> Work | None:
            try:
                next(steps)
                return step
            except StopIteration as done:
                reply = _ok(done.value, req.id)
            except Exception as exc:  # noqa: BLE001 - nothing a client sends may stop the server
                reply = self.faults.reply(exc, req.id)
            self._send(envelope, reply)
            return None

        return step

    @property
    def planner(self) -> Planner:
        """The motion planner on the selector served now (made again after a reload)."""
        if self._planner is None or self._planner.served is not self.selector:
            self._planner = Planner(self.selector)
        return self._planner

    # -- reload: the atlas loaded now or in the background (reach.serving.reloading), swapped in -------------------
    @property
    def selector(self) -> Selector:
        return self.served.selector

    def _load(self, path: Path) -> cells.Served:
        return cells.serve(Selector(load_atlas(path), **self.options).warm_up())

    def _swap(self) -> None:
        """Serve the atlas a background reload has loaded, if one has, and answer its request."""
        job = self.reloads.ready()
        if job is None:
            return
        try:
            reply = P.ok_reply(P.encode(self.install(job.request, job.path, job.future.result)), job.request.id)
        except Exception as exc:  # noqa: BLE001 - the reload's error reply; the current atlas stays
            reply = self.faults.reply(exc, job.request.id)
        self._send(job.envelope, reply)

    def install(self, req: P.Request, path: Path, loaded: Callable[[], cells.Served]) -> dict[str, Any]:
        """Swap in the selector ``loaded`` gives (one assignment, between two requests); the workers restart on it."""
        try:
            served = loaded()
        except ReachError as exc:
            raise P.ProtocolError(P.RELOAD_FAILED, f"kept the current atlas: {exc}", req.id) from None
        self.served, self.atlas_path = served, path
        selector = served.selector
        if self.pool is not None:
            # The workers hold the old atlas: answer their requests from the store, and start new ones.
            for seq in list(self.ledger.pending):
                self.ledger.pending[seq].deadline = 0.0
            self._expire(slice_goals=sys.maxsize)  # all at once: the old atlas's workers go
            self.pool.close()
            self.pool = Pool(self.context, path, self.options, self.pool.size)
        return {"atlas": str(path), "strategies": len(selector.order)}

    # -- requests the workers answer -------------------------------------------------
    def _finished(self, task: Task, frames: list[bytes]) -> None:
        pending = self.ledger.pending.get(task.request)
        if pending is None:
            return  # answered already (its deadline passed)
        HANDLERS[pending.request.op].finish(self, task.request, pending, frames, task.part)

    def answer_now(self, seq: int, reply: bytes) -> None:
        """Answer a pending request with ``reply`` now (an error, or a motion) and drop its queued work."""
        pending = self.ledger.pop(seq)
        if self.pool is not None:
            self.pool.cancel(seq)
        self._send(pending.envelope, reply)

    def _expire(self, slice_goals: int = EXPIRE_SLICE) -> None:
        """Answer the requests whose deadline has passed: a motion or placement with ``timeout``, a query's goals
        not yet refined with their stored postures, marked ``timeout``. The stored answers are looked up at most
        ``slice_goals`` at a time, one slice a pass of the loop (a vectorised lookup of 10,000 goals still held the
        loop 1.4 s): the request's reply goes when its last slice is in."""
        now = time.monotonic()
        for seq, due in [(s, p) for s, p in self.ledger.pending.items() if p.deadline <= now]:
            assert self.pool is not None
            self.pool.cancel(seq)
            HANDLERS[due.request.op].expire(self, seq, due)
        budget = slice_goals
        expiring = self.ledger.expiring
        while expiring and budget > 0:
            seq = self.ledger.soonest_expiring()
            pending = self.ledger.pending.get(seq)
            missing = [] if pending is None else [part for part, done in enumerate(pending.parts) if done is None]
            if pending is None or not missing:
                expiring.remove(seq)
                if pending is not None:
                    self.reply_pending(seq)
                continue
            take = _whole_parts(pending, missing, budget)
            budget -= sum(pending.bounds[part][1] - pending.bounds[part][0] for part in take)
            try:
                _from_store(self.selector, pending, take)
            except Exception as exc:  # noqa: BLE001 - this request's error reply; the others go on
                expiring.remove(seq)
                self.answer_now(seq, self.faults.reply(exc, pending.request.id))

    def reply_pending(self, seq: int) -> None:
        """Answer a query whose parts are all in, and publish its choices."""
        pending = self.ledger.pop(seq)
        bodies = [body for part in pending.parts if part is not None for body in part]
        try:
            req = pending.request
            self.publisher.publish(req["effector"].encode(), bodies, req)
            self._send(pending.envelope, P.ok_reply(bodies[0], req.id) if req["single"]
                       else P.ok_batch_reply(bodies, req.id))
        except Exception as exc:  # a bug must not stop the server
            self.faults.internal(exc)
            self._send(pending.envelope, P.error_reply(P.INTERNAL, "the reply could not be made", pending.request.id))


def _ok(result: dict[str, Any] | bytes, rid: Any) -> bytes:
    """The reply of a handler's result (its object, or its encoding already made)."""
    return P.ok_reply(result if isinstance(result, bytes) else P.encode(result), rid)


def _whole_parts(pending: Pending, missing: list[int], budget: int) -> list[int]:
    """The missing parts of an expired request to answer from the store in this slice: whole parts, as many as
    ``budget`` goals hold (at least one)."""
    take: list[int] = []
    goals = 0
    for part in missing:
        size = pending.bounds[part][1] - pending.bounds[part][0]
        if take and goals + size > budget:
            break
        take.append(part)
        goals += size
    return take


def _from_store(selector: Selector, pending: Pending, take: list[int]) -> None:
    """Fill an expired query's parts ``take`` with their goals' stored answers, marked ``timeout`` (one lookup)."""
    index = np.concatenate([np.arange(*pending.bounds[part]) for part in take])
    answers = stored_answers(selector, pending.request, index, TIMEOUT)
    k = 0
    for part in take:
        a, b = pending.bounds[part]
        pending.parts[part], k = answers[k : k + b - a], k + b - a
