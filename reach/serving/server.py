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

import concurrent.futures
import dataclasses
import gc
import logging
import math
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import zmq
import zmq.auth

from reach.answers.accommodation import load_members
from reach.answers.answer import SKIPPED, TIMEOUT, Answer
from reach.answers.select import HANDOVER, MISS, REFINE_BUDGET, Selector
from reach.errors import InputError, MotionError, ReachError, UnknownEffector, UnknownStrategy
from reach.maps.atlas import load_atlas
from reach.maps.protocol import DEFAULT_POLICY
from reach.motion.planner import Planner
from reach.serving import cells
from reach.serving import protocol as P
from reach.serving.client import load_curve_key
from reach.serving.handlers import HANDLERS, Pending
from reach.serving.workers import FAILED as WORKER_FAILED
from reach.serving.workers import Pool, Task

log = logging.getLogger("reach.serving.server")
READY_WAIT = 300.0  # [s] reach serve waits at most this for its workers to load the atlas before serving
LOG_EVERY = 60.0  # [s] an identical internal error's traceback is logged at most this often
REVIVE_EVERY = 0.5  # [s] how often the loop looks for dead workers
FAILED_TASK = WORKER_FAILED + b" the worker died"
# Choices published per pass of the loop (about 5 ms of it: 5 us a message, measured): a 10,000-goal batch's
# publications held the loop 135 ms in one pass.
PUBLISH_SLICE = 1000
# plain ints: pyzmq's flag enums cost 3 us a message
PUB_MORE, PUB_LAST = int(zmq.NOBLOCK | zmq.SNDMORE), int(zmq.NOBLOCK)
ZERO_COPY = 1 << 16  # [bytes] replies this large or larger are sent without copying (pyzmq: copy=False)
# stored answers an expired request gets per pass of the loop (about 15 ms of it: 0.15 ms a goal, measured)
EXPIRE_SLICE = 100
# [s] a query's goal, of the time kept before its deadline to answer it from the store if unrefined: twice the 0.15 ms
# a stored answer takes the loop (a pass also serves other clients between slices)
STORED_RESERVE = 3e-4


# Linux's limits on a path and on one of its names [bytes]: past them the file system raises ENAMETOOLONG.
PATH_MAX, NAME_MAX = 4096, 255


@dataclass
class Reloading:
    """An atlas loading in the background for a ``reload`` request."""

    envelope: list[bytes]
    request: P.Request
    path: Path
    future: concurrent.futures.Future


def check_endpoint(address: str, flag: str) -> None:
    """A ZeroMQ address a server may bind, or an InputError naming the flag: ``tcp://HOST:PORT`` (PORT 1-65535, or
    ``*`` for any free one), ``ipc://PATH`` or ``inproc://NAME``. libzmq itself took port 99999 as another port."""
    scheme, sep, rest = address.partition("://")
    if not sep or scheme not in ("tcp", "ipc", "inproc") or not rest or "\0" in rest:
        raise InputError(flag, f"expected tcp://HOST:PORT, ipc://PATH or inproc://NAME, got {address!r}")
    if scheme == "tcp":
        host, colon, port = rest.rpartition(":")
        if not colon or not host or not (port == "*" or (port.isdigit() and 1 <= int(port) <= 65535)):
            raise InputError(flag, f"expected tcp://HOST:PORT with PORT from 1 to 65535 or *, got {address!r}")


def _bind(socket: zmq.Socket, address: str, flag: str) -> None:  # type: ignore[type-arg]
    try:
        socket.bind(address)
    except zmq.ZMQError as exc:
        raise InputError(flag, f"cannot bind {address}: {exc.strerror}") from None

def _curve_keys(curve_secret: str | Path | None, curve_clients: str | Path | None) -> tuple[bytes, bytes | None] | None:
    """The server's CURVE key pair (public, secret) from ``--curve-secret-key``, or None; ``--curve-clients``, a folder
    of public-key files, checked with it."""
    keys = load_curve_key(curve_secret, secret=True, what="--curve-secret-key") if curve_secret else None
    if curve_clients is not None and (keys is None or not Path(curve_clients).is_dir()):
        raise InputError("--curve-clients", f"{curve_clients}: expected a folder of client public-key files, "
                                            "with --curve-secret-key")
    if curve_clients is not None:
        # Each file the authenticator will read (pyzmq reads *.key), checked now: one malformed file emptied the
        # allow-list after "serving" was printed, and every client was refused.
        for key_file in sorted(Path(curve_clients).glob("*.key")):
            load_curve_key(key_file, secret=False, what="--curve-clients")
    return keys


def _sockets(context: zmq.Context, bind: str, pub: str | None, keys: tuple[bytes, bytes | None] | None,
             curve_clients: str | Path | None) -> tuple[zmq.Socket[bytes], zmq.Socket[bytes] | None, Any]:
    """The server's bound ROUTER, its PUB (or None) and its CURVE authenticator thread (or None); nothing is left
    behind when one cannot bind."""
    router = context.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    # A hard cap far above the protocol limit: larger requests still get a
    # too_large reply; only absurd ones drop the connection.
    router.setsockopt(zmq.MAXMSGSIZE, 64 * P.MAX_MESSAGE_BYTES)
    # A client that reconnects under its identity (a Lazy Pirate resend) takes it over.
    router.setsockopt(zmq.ROUTER_HANDOVER, 1)
    # What one client can make the server hold unread: RCVHWM messages of at most 1 MiB each (the default of
    # 1000 let 40 requests of 60 MiB take the loop from 311 MB to 3.19 GB).
    router.setsockopt(zmq.RCVHWM, P.RCVHWM)
    publisher = context.socket(zmq.PUB) if pub else None
    sockets = [router] + ([publisher] if publisher else [])
    authenticator = None
    if curve_clients is not None:
        # the CURVE authenticator only when keys are given
        from zmq.auth.thread import ThreadAuthenticator

        # ZAP: libzmq asks this thread about every CURVE handshake; keys not in the folder are refused.
        authenticator = ThreadAuthenticator(context, log=logging.getLogger("reach.serving.server.auth"))
        authenticator.start()
        authenticator.configure_curve(domain="*", location=str(curve_clients))
    if keys is not None:
        for s in sockets:
            s.curve_secretkey, s.curve_publickey, s.curve_server = keys[1], keys[0], True
    try:
        _bind(router, bind, "--bind")
        if publisher is not None:
            publisher.setsockopt(zmq.LINGER, 0)
            publisher.setsockopt(zmq.SNDHWM, P.PUB_HWM)
            _bind(publisher, pub, "--pub")  # type: ignore[arg-type]
    except InputError:
        # Nothing of a server that could not bind is left behind: its sockets, and the CURVE thread.
        for s in sockets:
            s.close(linger=0)
        if authenticator is not None:
            authenticator.stop()
        raise
    return router, publisher, authenticator


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
        self.reload_root = None if allow_reload is None else Path(allow_reload).resolve()
        keys = _curve_keys(curve_secret, curve_clients)  # before any socket
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
            self.router, self.publisher, self.authenticator = _sockets(self.context, bind, pub, keys, curve_clients)
        except BaseException:
            if self.pool is not None:
                self.pool.close()
            raise
        self.endpoint = cast(bytes, self.router.getsockopt(zmq.LAST_ENDPOINT)).decode()
        self.pub_endpoint = (None if self.publisher is None
                             else cast(bytes, self.publisher.getsockopt(zmq.LAST_ENDPOINT)).decode())
        self._stop = threading.Event()
        # set by SIGINT/SIGTERM: a handler that only assigns can never deadlock (Event.set locks)
        self._signalled = False
        self.started = time.monotonic()
        self.requests = 0
        self.errors = 0
        self.resends = 0
        self._logged: dict[str, float] = {}
        self.pending: dict[int, Pending] = {}
        self.by_key: dict[tuple[bytes, bytes], int] = {}
        self.expiring: deque[int] = deque()  # requests past their deadline, answered from the store slice by slice
        # (topic, head, bodies, next): choices to publish
        self.publishing: deque[tuple[bytes, bytes, list[bytes], int]] = deque()
        self.held: dict[bytes, int] = {}  # goals each client has pending (see _admit)
        self.held_requests: dict[bytes, int] = {}
        self._seq = 0
        # reload loads in this thread, so no request waits for it; the loop swaps the atlas in when it is ready.
        self._loader: concurrent.futures.ThreadPoolExecutor | None = None
        self.reloading: Reloading | None = None
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
                signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, frame: object) -> None:
        # Only a flag: Event.set() takes a lock, and a second signal arriving inside it blocked the process for good.
        self._signalled = True

    @property
    def running(self) -> bool:
        """Whether the loop goes on: neither stop() nor a signal has asked it to end."""
        return not (self._signalled or self._stop.is_set())

    def close(self) -> None:
        if self._loader is not None:
            self._loader.shutdown(wait=True, cancel_futures=True)
        if self.pool is not None:
            self.pool.close()
        self.router.close(linger=0)
        if self.publisher is not None:
            self.publisher.close(linger=0)
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
                        frames = self.router.recv_multipart()
                    except zmq.Again:
                        frames = None
                    if frames is not None:
                        self.handle(frames)
                    if self.reloading is not None and self.reloading.future.done():
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
            soonest = min((p.deadline for p in self.pending.values()), default=math.inf)
            wait = (0.0 if self.expiring or self.publishing
                    else max(0.0, min(P.POLL_MS / 1000.0, soonest - time.monotonic())))
            events = dict(poller.poll(int(math.ceil(wait * 1000))))
            if self.router in events:
                for _ in range(64):  # clients first: a stored answer never waits behind workers' results
                    try:
                        frames = self.router.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    self.handle(frames)
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
            self._drain_publications()
            if self.reloading is not None and self.reloading.future.done():
                self._swap()

    # -- one request -------------------------------------------------------
    def handle(self, frames: list[bytes]) -> None:
        """Answer one multipart message; never raises for anything a client sent."""
        identity, rest = frames[0], frames[1:]
        envelope = [identity]
        if rest and rest[0] == b"" and len(rest) >= 2:
            envelope.append(b"")  # a REQ client's delimiter, echoed back
            rest = rest[1:]
        self.requests += 1
        try:
            if len(rest) != 1:
                reply: bytes | None = P.error_reply(P.BAD_FRAMES, "expected one payload frame after the envelope, "
                                                                  f"got {len(rest)}")
            else:
                reply = self.respond(rest[0], envelope)
        except Exception as exc:  # noqa: BLE001 - the last guard: respond() catches, but nothing may end the loop
            self._log_internal(exc)
            reply = P.error_reply(P.INTERNAL, "the reply could not be made")
        if reply is not None:
            self._send(envelope, reply)

    def _send(self, envelope: list[bytes], reply: bytes) -> None:
        try:
            # A large reply is handed to libzmq without a copy (pyzmq's advice past about 64 KB).
            self.router.send_multipart([*envelope, reply], zmq.NOBLOCK, copy=len(reply) < ZERO_COPY)
        except zmq.ZMQError as exc:  # the peer vanished, or its queue is full
            log.warning("reply dropped: %s", exc)

    def respond(self, payload: bytes, envelope: list[bytes] | None = None) -> bytes | None:
        """The reply to one payload, or None when the workers will answer it."""
        rid = None
        try:
            req = P.parse_request(payload)
            rid = req.id
            if envelope is not None and HANDLERS[req.op].defer(self, req, envelope):
                return None  # the workers or the background answer it
            result = HANDLERS[req.op].answer(self, req)  # answered now by its operation's handler
            return P.ok_reply(result if isinstance(result, bytes) else P.encode(result), rid)
        except Exception as exc:  # noqa: BLE001 - nothing a client sends may stop the server
            return self.error(exc, rid)

    def error(self, exc: Exception, rid: Any) -> bytes:
        """The error reply of an exception raised while answering a request (a bug's is logged as ``internal``)."""
        self.errors += 1
        if isinstance(exc, P.ProtocolError):
            return P.error_reply(exc.code, exc.message, exc.request_id if exc.request_id is not None else rid)
        if isinstance(exc, MotionError):
            return P.error_reply(exc.code, str(exc), rid)
        if isinstance(exc, ReachError):
            code = (P.UNKNOWN_EFFECTOR if isinstance(exc, UnknownEffector) else P.UNKNOWN_STRATEGY
                    if isinstance(exc, UnknownStrategy) else P.BAD_REQUEST)
            return P.error_reply(code, str(exc), rid)
        self._log_internal(exc)
        return P.error_reply(P.INTERNAL, f"{type(exc).__name__}: {exc}", rid)

    @property
    def planner(self) -> Planner:
        """The motion planner on the selector served now (made again after a reload)."""
        if self._planner is None or self._planner.served is not self.selector:
            self._planner = Planner(self.selector)
        return self._planner

    # -- reload: its path checked, the atlas loaded now or in the background and swapped in ---------------------
    def reload_path(self, req: P.Request) -> Path:
        if self.reload_root is None:
            raise P.ProtocolError(P.FORBIDDEN, "reload is off; the operator allows it with reach serve "
                                               "--allow-reload ROOT", req.id)
        if "\0" in (req["path"] or ""):
            raise P.ProtocolError(P.BAD_REQUEST, "path: a NUL character cannot be in a file path", req.id)
        # Checked before the path is touched: a refused path reveals nothing of what exists there.
        try:
            path = (self.reload_root / req["path"]).resolve() if req["path"] else self.atlas_path
        except (OSError, UnicodeError, ValueError) as exc:  # too long for the system, a lone surrogate
            raise P.ProtocolError(P.BAD_REQUEST, f"path: not a file path this system can name ({exc})"[:300],
                                  req.id) from None
        if len(str(path).encode()) >= PATH_MAX or any(len(part.encode()) > NAME_MAX for part in path.parts):
            raise P.ProtocolError(P.BAD_REQUEST, f"path: longer than a file path may be ({PATH_MAX} bytes, "
                                                 f"{NAME_MAX} a name)", req.id)
        if not path.is_relative_to(self.reload_root):
            raise P.ProtocolError(P.FORBIDDEN, f"reload loads atlases under {self.reload_root} only", req.id)
        return path

    @property
    def selector(self) -> Selector:
        return self.served.selector

    def _load(self, path: Path) -> cells.Served:
        return cells.serve(Selector(load_atlas(path), **self.options).warm_up())

    def reload_now(self, req: P.Request, path: Path) -> dict[str, Any]:
        """Load and swap at once (an in-process call)."""
        return self._install(req, path, lambda: self._load(path))

    def reload_later(self, req: P.Request, envelope: list[bytes], path: Path) -> None:
        """Start loading a ``reload``'s atlas in the background; its reply goes when the loop has swapped it in."""
        if self.reloading is not None:
            raise P.ProtocolError(P.RELOAD_FAILED, f"kept the current atlas: another reload ({self.reloading.path}) "
                                                   "is loading", req.id)
        if self._loader is None:
            self._loader = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="reach-reload")
        self.reloading = Reloading(envelope, req, path, self._loader.submit(self._load, path))

    def _swap(self) -> None:
        """Serve the atlas a background reload has loaded, and answer its request."""
        job, self.reloading = self.reloading, None
        assert job is not None
        try:
            reply = P.ok_reply(P.encode(self._install(job.request, job.path, job.future.result)), job.request.id)
        except Exception as exc:  # noqa: BLE001 - the reload's error reply; the current atlas stays
            reply = self.error(exc, job.request.id)
        self._send(job.envelope, reply)

    def _install(self, req: P.Request, path: Path, loaded: Callable[[], cells.Served]) -> dict[str, Any]:
        """Swap in the selector ``loaded`` gives (one assignment, between two requests); the workers restart on it."""
        try:
            served = loaded()
        except ReachError as exc:
            raise P.ProtocolError(P.RELOAD_FAILED, f"kept the current atlas: {exc}", req.id) from None
        self.served, self.atlas_path = served, path
        selector = served.selector
        if self.pool is not None:
            # The workers hold the old atlas: answer their requests from the store, and start new ones.
            for seq in list(self.pending):
                self.pending[seq].deadline = 0.0
            self._expire(slice_goals=sys.maxsize)  # all at once: the old atlas's workers go
            self.pool.close()
            self.pool = Pool(self.context, path, self.options, self.pool.size)
        return {"atlas": str(path), "strategies": len(selector.order)}

    # -- requests the workers answer -------------------------------------------------
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
        given = req.args.get("deadline")  # place has none
        reply_by = time.monotonic() + (given if given is not None else wait)
        # A query's goals still unrefined at its deadline are answered from the store, one slice a pass of the loop:
        # the workers stop early enough for that to end by the deadline (an expired 10,000-goal batch's
        # reply came 13.7 s after its 0.5 s deadline). A deadline too short for it is refused before anything is held.
        reserve = goals * STORED_RESERVE
        if given is not None and reserve > given:
            raise P.ProtocolError(P.TIMEOUT, f"{goals} goals take about {reserve:.2f} s to answer from the stored "
                                             f"postures alone, more than the deadline of {given:g} s: give a longer "
                                             "deadline or fewer goals", req.id)
        deadline = reply_by - reserve
        self._seq += 1
        self.pending[self._seq] = Pending(envelope, req, key, deadline, [None] * len(bounds), bounds, goals)
        self.held[envelope[0]] = self.held.get(envelope[0], 0) + goals
        self.held_requests[envelope[0]] = self.held_requests.get(envelope[0], 0) + 1
        if key is not None:
            self.by_key[key] = self._seq
        return self._seq

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

    def _release(self, pending: Pending) -> None:
        """Forget a pending request's share of its client's held work (it is answered)."""
        client = pending.envelope[0]
        left = self.held.get(client, 0) - pending.goals
        requests = self.held_requests.get(client, 0) - 1
        if left > 0 or requests > 0:
            self.held[client], self.held_requests[client] = max(left, 0), max(requests, 0)
        else:
            self.held.pop(client, None)
            self.held_requests.pop(client, None)

    def stored(self, req: P.Request, a: int, b: int, outcome: str) -> list[bytes]:
        """The stored answers of goals a..b, marked with why they were not refined."""
        return self._stored_at(req, np.arange(a, b), outcome)

    def _stored_at(self, req: P.Request, index: np.ndarray, outcome: str) -> list[bytes]:
        """The stored answers of the request's goals at ``index`` (one lookup for them all), marked with why they
        were not refined."""
        goals = np.asarray(req["goals"], float)[index]
        if not len(goals):
            return []
        if req["orientation"] is not None:  # a stored posture holds no goal's orientation
            return [Answer(req["effector"], tuple(g.tolist()), None, False, refined=outcome).to_json() for g in goals]
        answers = self.selector.select_many(req["effector"], goals, False)
        return [dataclasses.replace(x, refined=outcome).to_json() if x.refined == SKIPPED else x.to_json()
                for x in answers]

    def _finished(self, task: Task, frames: list[bytes]) -> None:
        pending = self.pending.get(task.request)
        if pending is None:
            return  # answered already (its deadline passed)
        HANDLERS[pending.request.op].finish(self, task.request, pending, frames, task.part)

    def answer_now(self, seq: int, reply: bytes) -> None:
        """Answer a pending request with ``reply`` now (an error, or a motion) and drop its queued work."""
        pending = self.pending.pop(seq)
        self._release(pending)
        if pending.key is not None:
            self.by_key.pop(pending.key, None)
        if self.pool is not None:
            self.pool.cancel(seq)
        self._send(pending.envelope, reply)

    def _expire(self, slice_goals: int = EXPIRE_SLICE) -> None:
        """Answer the requests whose deadline has passed: a motion or placement with ``timeout``, a query's goals
        not yet refined with their stored postures, marked ``timeout``. The stored answers are looked up at most
        ``slice_goals`` at a time, one slice a pass of the loop (a vectorised lookup of 10,000 goals still held the
        loop 1.4 s): the request's reply goes when its last slice is in."""
        now = time.monotonic()
        for seq in [s for s, p in self.pending.items() if p.deadline <= now]:
            pending = self.pending[seq]
            assert self.pool is not None
            self.pool.cancel(seq)
            HANDLERS[pending.request.op].expire(self, seq, pending)
        budget = slice_goals
        while self.expiring and budget > 0:
            seq = self.expiring[0]
            found = self.pending.get(seq)
            missing = [] if found is None else [part for part, done in enumerate(found.parts) if done is None]
            if found is None or not missing:
                self.expiring.popleft()
                if found is not None:
                    self.reply_pending(seq)
                continue
            pending = found
            # Whole parts, as many as the slice holds (at least one).
            take: list[int] = []
            goals = 0
            for part in missing:
                size = pending.bounds[part][1] - pending.bounds[part][0]
                if take and goals + size > budget:
                    break
                take.append(part)
                goals += size
            budget -= goals
            try:
                index = np.concatenate([np.arange(*pending.bounds[part]) for part in take])
                answers = self._stored_at(pending.request, index, TIMEOUT)
                k = 0
                for part in take:
                    a, b = pending.bounds[part]
                    pending.parts[part], k = answers[k : k + b - a], k + b - a
            except Exception as exc:  # noqa: BLE001 - this request's error reply; the others go on
                self.expiring.popleft()
                self.answer_now(seq, self.error(exc, pending.request.id))

    def reply_pending(self, seq: int) -> None:
        """Answer a query whose parts are all in, and publish its choices."""
        pending = self.pending.pop(seq)
        self._release(pending)
        if pending.key is not None:
            self.by_key.pop(pending.key, None)
        bodies = [body for part in pending.parts if part is not None for body in part]
        try:
            req = pending.request
            self.publish(req["effector"].encode(), bodies, req)
            self._send(pending.envelope, P.ok_reply(bodies[0], req.id) if req["single"]
                       else P.ok_batch_reply(bodies, req.id))
        except Exception as exc:  # a bug must not stop the server
            self._log_internal(exc)
            self._send(pending.envelope, P.error_reply(P.INTERNAL, "the reply could not be made", pending.request.id))

    def _log_internal(self, exc: Exception) -> None:
        """Log a bug's traceback, each distinct one at most once a minute (a client repeating a request must not
        flood the log)."""
        key = f"{type(exc).__name__}: {exc}"[:300]
        now = time.monotonic()
        if now - self._logged.get(key, -math.inf) >= LOG_EVERY:
            self._logged[key] = now
            log.error("internal error", exc_info=exc)

    def publish(self, topic: bytes, bodies: list[bytes], req: P.Request) -> None:
        """Publish each encoded choice with the request's id and tag, in order; a slow subscriber costs a dropped
        message, never a blocked reply. With workers, at most ``PUBLISH_SLICE`` go now and the rest one slice a pass
        of the loop."""
        if self.publisher is None:
            return
        head = b'{"id":' + P.encode_value(req.id) + b',"tag":' + P.encode_value(req["tag"])
        self.publishing.append((topic, head, bodies, 0))
        self._drain_publications(PUBLISH_SLICE if self.pool is not None else math.inf)

    def _drain_publications(self, limit: float = PUBLISH_SLICE) -> None:
        """Publish up to ``limit`` queued choices, oldest first."""
        send = self.publisher.send if self.publisher is not None else None
        while self.publishing and limit > 0 and send is not None:
            topic, head, bodies, k = self.publishing[0]
            end = int(min(len(bodies), k + limit))
            for body in bodies[k:end]:
                try:
                    send(topic, PUB_MORE)
                    send(head + (b"," + body[1:] if body != b"{}" else b"}"), PUB_LAST)
                except zmq.Again:
                    pass
            limit -= end - k
            if end < len(bodies):
                self.publishing[0] = (topic, head, bodies, end)
            else:
                self.publishing.popleft()
