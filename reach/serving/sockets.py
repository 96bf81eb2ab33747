"""The server's sockets: its addresses checked, its ROUTER and PUB bound with their limits, and CURVE's keys and
authenticator; nothing is left behind when one cannot bind."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import zmq

from reach.errors import InputError
from reach.serving import protocol as P
from reach.serving.client import load_curve_key


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

def curve_keys(curve_secret: str | Path | None, curve_clients: str | Path | None) -> tuple[bytes, bytes | None] | None:
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


def sockets(context: zmq.Context, bind: str, pub: str | None, keys: tuple[bytes, bytes | None] | None,
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
