"""``reach serve``: the real-time strategy selector over ZeroMQ.

One ROUTER socket answers requests (REQ and DEALER clients alike); one PUB
socket publishes every choice, topic = the effector. One poll loop with a
timeout; nothing a client sends can stop it: every malformed request gets a
structured error reply (see :mod:`reach.protocol` and docs/protocol.md), and
an unexpected exception becomes an ``internal`` error reply. SIGINT and
SIGTERM stop the loop cleanly when the server runs in the main thread.

Binds to 127.0.0.1 by default. With a CURVE secret-key file (as written by
``zmq.auth.create_certificates``) both sockets encrypt, and clients must
know the server's public key.
"""

from __future__ import annotations

import gc
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zmq
import zmq.auth

from reach import protocol as P
from reach.errors import ReachError, UnknownEffector, UnknownStrategy
from reach.select import REFINE_BUDGET, Selector
from reach.store import load_atlas
from reach.tree import DEFAULT_POLICY

log = logging.getLogger("reach.server")


class Server:
    """The selector behind a ROUTER and a PUB socket.

    Args:
        atlas: Atlas folder to serve.
        bind: Address of the request socket.
        pub: Address of the publishing socket, or None for none.
        policy: Boundary-cell policy of the selector.
        refine: Refine postures by IK unless a request says otherwise.
        budget: Time budget of one refinement [s].
        curve_secret: Path of the server's CURVE secret-key file, or None.
        context: A zmq context (a new one by default).
    """

    def __init__(
        self, atlas: str | Path, bind: str = P.DEFAULT_BIND, pub: str | None = P.DEFAULT_PUB, *, policy: str = DEFAULT_POLICY,
        refine: bool = True, budget: float = REFINE_BUDGET, curve_secret: str | Path | None = None, context: zmq.Context | None = None,
    ) -> None:
        self.atlas_path = Path(atlas)
        self.policy, self.refine, self.budget = policy, refine, budget
        self.selector = Selector(load_atlas(self.atlas_path), policy, refine, budget).warm_up()  # type: ignore[arg-type]
        self.context = context or zmq.Context.instance()
        self.router = self.context.socket(zmq.ROUTER)
        self.router.setsockopt(zmq.LINGER, 0)
        # A hard cap far above the protocol limit: larger requests still get a
        # too_large reply; only absurd ones drop the connection.
        self.router.setsockopt(zmq.MAXMSGSIZE, 64 * P.MAX_MESSAGE_BYTES)
        self.publisher = self.context.socket(zmq.PUB) if pub else None
        sockets = [self.router] + ([self.publisher] if self.publisher else [])
        if curve_secret:
            public, secret = zmq.auth.load_certificate(str(curve_secret))
            if secret is None:
                raise ReachError(f"{curve_secret}: not a CURVE secret-key file (expected one written by zmq.auth.create_certificates)")
            for s in sockets:
                s.curve_secretkey, s.curve_publickey, s.curve_server = secret, public, True
        self.router.bind(bind)
        self.endpoint = self.router.getsockopt(zmq.LAST_ENDPOINT).decode()
        self.pub_endpoint = None
        if self.publisher is not None:
            self.publisher.setsockopt(zmq.LINGER, 0)
            self.publisher.setsockopt(zmq.SNDHWM, P.PUB_HWM)
            self.publisher.bind(pub)  # type: ignore[arg-type]
            self.pub_endpoint = self.publisher.getsockopt(zmq.LAST_ENDPOINT).decode()
        self._stop = threading.Event()
        self.started = time.monotonic()
        self.requests = 0
        self.errors = 0

    # -- lifecycle ---------------------------------------------------------
    def stop(self) -> None:
        """Ask the loop to finish (thread- and signal-safe)."""
        self._stop.set()

    def close(self) -> None:
        self.router.close(linger=0)
        if self.publisher is not None:
            self.publisher.close(linger=0)

    def serve_forever(self) -> None:
        """Poll and answer until stop() or SIGINT/SIGTERM."""
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self.stop())
        # What is loaded now lives as long as the server: keep it out of the
        # garbage collector's scans, which otherwise show in the latency tail.
        gc.collect()
        gc.freeze()
        # A blocking receive with a timeout wakes fastest; the timeout lets the
        # loop see a stop request within POLL_MS.
        self.router.setsockopt(zmq.RCVTIMEO, P.POLL_MS)
        try:
            while not self._stop.is_set():
                try:
                    frames = self.router.recv_multipart()
                except zmq.Again:
                    continue
                self.handle(frames)
        finally:
            self.close()

    # -- one request -------------------------------------------------------
    def handle(self, frames: list[bytes]) -> None:
        """Answer one multipart message; never raises for anything a client sent."""
        identity, rest = frames[0], frames[1:]
        envelope = [identity]
        if rest and rest[0] == b"" and len(rest) >= 2:
            envelope.append(b"")  # a REQ client's delimiter, echoed back
            rest = rest[1:]
        self.requests += 1
        if len(rest) != 1:
            reply = P.error_reply(P.BAD_FRAMES, f"expected one payload frame after the envelope, got {len(rest)}")
        else:
            reply = self.respond(rest[0])
        try:
            self.router.send_multipart([*envelope, reply], zmq.NOBLOCK)
        except zmq.ZMQError as exc:  # the peer vanished, or its queue is full
            log.warning("reply dropped: %s", exc)

    def respond(self, payload: bytes) -> bytes:
        """The reply to one payload."""
        rid = None
        try:
            req = P.parse_request(payload)
            rid = req.id
            return P.ok_reply(self.dispatch(req), rid)
        except P.ProtocolError as exc:
            self.errors += 1
            return P.error_reply(exc.code, exc.message, exc.request_id if exc.request_id is not None else rid)
        except ReachError as exc:
            self.errors += 1
            code = P.UNKNOWN_EFFECTOR if isinstance(exc, UnknownEffector) else P.UNKNOWN_STRATEGY if isinstance(exc, UnknownStrategy) else P.BAD_REQUEST
            return P.error_reply(code, str(exc), rid)
        except Exception as exc:  # a bug must not stop the server
            self.errors += 1
            log.exception("internal error")
            return P.error_reply(P.INTERNAL, f"{type(exc).__name__}: {exc}", rid)

    def dispatch(self, req: P.Request) -> bytes:
        """The encoded result object of a valid request."""
        if req.op == "query":
            assert req.effector is not None and req.goals is not None
            answers = self.selector.select_many(req.effector, np.array(req.goals), req.refine, start=req.start)
            bodies = [a.to_json() for a in answers]
            self.publish(req.effector, bodies)
            return bodies[0] if req.single else b'{"answers":[' + b",".join(bodies) + b"]}"
        return P.encode(self.control(req))

    def control(self, req: P.Request) -> dict[str, Any]:
        """Results of the health, strategies and reload ops."""
        if req.op == "health":
            return {
                "status": "serving", "protocol": P.VERSION, "atlas": str(self.atlas_path), "strategies": len(self.selector.order),
                "uptime": time.monotonic() - self.started, "requests": self.requests, "errors": self.errors,
            }
        if req.op == "strategies":
            return {"strategies": [
                {"name": n, "effector": e, "priority": int(self.selector.atlas.trees[n].meta.get("priority", 0)),
                 "box": self.selector.atlas.trees[n].box.to_dict(), "d_max": self.selector.atlas.trees[n].d_max}
                for n, e in self.selector.order
            ], "effectors": self.selector.effectors, "frame": "world: z up, x forward, y left; metres, radians"}
        if req.op == "cells":
            return self.cells(req)
        if req.op == "reload":
            path = Path(req.path) if req.path else self.atlas_path
            try:
                selector = Selector(load_atlas(path), self.policy, self.refine, self.budget).warm_up()  # type: ignore[arg-type]
            except ReachError as exc:
                raise P.ProtocolError(P.RELOAD_FAILED, f"kept the current atlas: {exc}", req.id) from None
            self.selector, self.atlas_path = selector, path
            return {"atlas": str(path), "strategies": len(selector.order)}
        raise P.ProtocolError(P.UNKNOWN_OP, f"unknown op {req.op!r}", req.id)

    def cells(self, req: P.Request) -> dict[str, Any]:
        """Centres of the reachable cells of each strategy on a regular grid (for markers in RViz)."""
        from reach.report import raster

        atlas = self.selector.atlas
        trees = atlas.trees
        out = {}
        for name in atlas.select([req.strategy] if req.strategy else None):
            tree = trees[name]
            level = min(req.level, tree.d_max)
            occ, edges = raster(tree, level)
            centres = np.stack(np.meshgrid(*[0.5 * (e[1:] + e[:-1]) for e in edges], indexing="ij"), axis=-1)[occ]
            out[name] = {"effector": tree.meta.get("effector"), "priority": tree.meta.get("priority"),
                         "size": (tree.box.size / (1 << level)).tolist(), "centres": np.round(centres, 6).tolist()}
        return {"cells": out, "level": req.level}

    def publish(self, effector: str, bodies: list[bytes]) -> None:
        """Publish each encoded choice; a slow subscriber costs a dropped message, never a blocked reply."""
        if self.publisher is None:
            return
        topic = effector.encode()
        for body in bodies:
            try:
                self.publisher.send_multipart([topic, body], zmq.NOBLOCK)
            except zmq.Again:
                pass
