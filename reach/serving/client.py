"""A Python client of ``reach serve``: REQ with timeouts and reconnection.

The Lazy Pirate pattern (zguide, ``lpclient.py``): each request waits at most
``timeout`` ms; on a timeout the socket is closed with linger 0, reopened and
the request sent again, up to ``retries`` times. Replies carry the request's
id, which is checked, so a late reply to an abandoned request is never taken
for the current one.
"""

from __future__ import annotations

import itertools
import json
import uuid
from pathlib import Path
from typing import Any

import zmq
import zmq.auth

from reach.errors import InputError, ServerError, ServerUnavailable
from reach.serving import protocol as P

REQUEST_TIMEOUT_MS = P.REQUEST_TIMEOUT_MS
REQUEST_RETRIES = P.REQUEST_RETRIES

__all__ = ["Client", "ServerError", "ServerUnavailable"]


def load_curve_key(path: str | Path, *, secret: bool, what: str) -> tuple[bytes, bytes | None]:
    """The (public, secret) keys of a ZeroMQ certificate file (``reach keys``), or an InputError naming ``what``."""
    try:
        public, secret_key = zmq.auth.load_certificate(str(path))
    except (OSError, ValueError) as exc:
        raise InputError(what,
                         f"{path}: cannot read a CURVE key file ({exc}); write one with `reach keys DIR`") from None
    if secret and secret_key is None:
        raise InputError(what, f"{path}: not a CURVE secret-key file (expected the .key_secret written by `reach "
                               "keys DIR`)")
    return public, secret_key


class Client:
    """Talks to a reach server.

    Args:
        address: The server's request address, e.g. ``tcp://127.0.0.1:5555``.
        timeout: Milliseconds to wait for each reply.
        retries: Attempts before giving up.
        curve_server_key: Path of the server's public-key file, for CURVE.
        curve_client_key: Path of this client's secret-key file (``reach keys``),
            for a server that allows listed clients only; a fresh pair otherwise.
    """

    def __init__(self, address: str = P.DEFAULT_BIND, timeout: int = REQUEST_TIMEOUT_MS, retries: int = REQUEST_RETRIES,
                 curve_server_key: str | Path | None = None, context: zmq.Context | None = None,
                 curve_client_key: str | Path | None = None) -> None:
        self.address, self.timeout, self.retries = address, timeout, retries
        self.context = context or zmq.Context.instance()
        self.curve = None
        if curve_server_key:
            server_public, _ = load_curve_key(curve_server_key, secret=False, what="curve_server_key")
            if curve_client_key:  # this client's own pair, the public half on the server's allow-list
                client_public, client_secret = load_curve_key(curve_client_key, secret=True, what="curve_client_key")
            else:
                client_public, client_secret = zmq.curve_keypair()
            self.curve = (server_public, client_public, client_secret)
        self._ids = itertools.count(1)
        # One routing identity for every socket this client opens: a resend
        # after a timeout then reaches the server as the same client (which
        # hands the identity over to the new connection), so a request still
        # being worked on is answered once, not computed again.
        self.identity = b"reach-" + uuid.uuid4().hex.encode()
        self.socket = self._connect()

    def _connect(self) -> zmq.Socket:
        sock = self.context.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SNDTIMEO, self.timeout)  # a send waits for a connection this long at most
        sock.setsockopt(zmq.ROUTING_ID, self.identity)
        if self.curve:
            sock.curve_serverkey, sock.curve_publickey, sock.curve_secretkey = self.curve
        sock.connect(self.address)
        return sock

    def close(self) -> None:
        self.socket.close(linger=0)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __getattr__(self, name: str) -> Any:
        """Every operation of the table (:data:`reach.serving.protocol.OPERATIONS`) as a method: ``client.version()``,
        ``client.health()``; fields as keyword arguments (``from`` as ``from_``)."""
        if name in P.OPERATIONS:
            return lambda **fields: self.call(name, **{k.rstrip("_"): v for k, v in fields.items()})
        raise AttributeError(f"{type(self).__name__!r} has no attribute {name!r}")

    def call(self, op: str, **fields: Any) -> dict[str, Any]:
        """Send one request and return the reply's fields; raises ServerError or ServerUnavailable.

        An operation or field the protocol does not declare raises InputError before anything is sent.
        """
        known = P.OPERATIONS.get(op)
        if known is None:
            raise InputError("op", f"unknown operation {op!r}; operations are {', '.join(P.OPS)}")
        extra = sorted(set(fields) - {f.name for f in known.fields})
        if extra:
            raise InputError(op, f"unknown fields {extra}; {op} takes "
                                 f"{', '.join(f.name for f in known.fields) or 'none'}")
        rid = next(self._ids)
        payload = json.dumps({"op": op, "id": rid, **fields}).encode()
        for _ in range(self.retries):
            try:
                self.socket.send(payload)
            except zmq.Again:
                # No connection to send on within the timeout (a CURVE handshake refused or not yet done: a REQ
                # socket without one blocked here for good, seen once in a test under load): as no reply.
                sent = False
            else:
                sent = True
            if sent and self.socket.poll(self.timeout, zmq.POLLIN):
                reply = json.loads(self.socket.recv())
                if reply.get("id") != rid:
                    raise ServerError("bad_id", f"reply to request {reply.get('id')!r} while waiting for {rid}")
                if not reply.get("ok"):
                    err = reply.get("error", {})
                    raise ServerError(err.get("code", "?"), err.get("message", ""))
                return dict(reply)
            # No reply in time: the REQ socket is stuck; rebuild it and resend.
            self.socket.close(linger=0)
            self.socket = self._connect()
        raise ServerUnavailable(self.address, self.retries, self.timeout)

    def query(self, effector: str, goal: list[float], refine: bool | None = None, start: dict[str, float] | None = None,
              miss: str | None = None, orientation: dict[str, list[float]] | None = None) -> dict[str, Any]:
        """One goal [m]; ``start`` is the character's current posture (joint name -> rad or m), the query's ``from``;
        ``miss``: ``unreachable`` or ``within``; ``orientation``: ``{"direction": [x, y, z]}`` or
        ``{"quaternion": [qx, qy, qz, qw]}`` (see docs/protocol.md)."""
        return self.call("query", **self._fields(effector, refine, start, miss, orientation),
                         goal=[float(v) for v in goal])

    def query_many(self, effector: str, goals: list[list[float]], refine: bool | None = None,
                   start: dict[str, float] | None = None, miss: str | None = None,
                   orientation: dict[str, list[float]] | list[dict[str, list[float]]] | None = None) -> list[dict[str,
                       Any]]:
        """Goals [m] (``orientation``: one for all, or a list of one per goal; the rest as :meth:`query`)."""
        fields = self._fields(effector, refine, start, miss, orientation)
        return list(self.call("query", **fields, goals=[[float(v) for v in g] for g in goals])["answers"])

    @staticmethod
    def _fields(effector: str, refine: bool | None, start: dict[str, float] | None, miss: str | None,
                orientation: dict[str, list[float]] | list[dict[str, list[float]]] | None = None) -> dict[str, Any]:
        fields: dict[str, Any] = {"effector": effector}
        if orientation is not None:
            each = orientation if isinstance(orientation, list) else [orientation]
            wire = [{str(k): [float(x) for x in v] for k, v in o.items()} for o in each]
            fields["orientation"] = wire if isinstance(orientation, list) else wire[0]
        if refine is not None:
            fields["refine"] = refine
        if start is not None:
            fields["from"] = {str(k): float(v) for k, v in start.items()}
        if miss is not None:
            fields["miss"] = miss
        return fields

    def cells(self, strategy: str | None = None, level: int = 4) -> dict[str, Any]:
        """Centres [m] and size of each strategy's reachable cells on a 2**level grid."""
        return dict(self.call("cells", level=level, **({"strategy": strategy} if strategy else {}))["cells"])

    def reload(self, path: str | None = None) -> dict[str, Any]:
        return self.call("reload", **({"path": path} if path else {}))
