"""A gate in front of a local web server that answers only its own origin.

The viewer's page and WebSocket (viser) accept any ``Host`` and any
``Origin``, so a web page the user visits elsewhere could drive them through
DNS rebinding or a cross-site WebSocket, even on loopback. The gate listens
where the user asked, reads the head of each connection's first request and
passes the connection on to the server behind it only when ``Host`` names
the gate itself (``127.0.0.1``, ``localhost``, ``[::1]`` or the host it was
given, with its port) and ``Origin``, when the browser sends one, is that
same ``http://`` address. Anything else gets ``403 Forbidden``. A browser
keeps a connection to one host, and opens a WebSocket on a connection of
its own, so the first request speaks for the connection.

The server behind the gate listens on a loopback port of its own, which a
rebound name reaches as well as the gate's. :func:`guarded_websockets` makes
that port check every request too, against the gate's names: only a
connection the gate passed on (its ``Host`` is the gate's) gets through, so
the gate is the only door.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

HEAD_LIMIT = 64 * 1024  # [bytes] a request head longer than this is refused
HEAD_SECONDS = 10.0  # [s] a client that sends no complete head in this time is dropped
PORT_TRIES = 1000  # ports tried upwards from the one asked for, as viser does
LOOPBACK = ("127.0.0.1", "localhost", "[::1]")


def allowed_hosts(host: str, port: int) -> set[str]:
    """The ``Host`` values that name the gate: loopback names and the host it listens on, with its port."""
    names = set(LOOPBACK)
    if host not in ("0.0.0.0", "::", ""):
        names.add(f"[{host}]" if ":" in host else host)
    return {f"{n}:{port}" for n in names}


def verdict(head: bytes, hosts: Iterable[str]) -> str | None:
    """None when a request head may pass; else why it may not."""
    fields: dict[str, str] = {}
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        fields[name.strip().lower().decode("latin-1")] = value.strip().decode("latin-1")
    return fields_verdict(fields, hosts)


def fields_verdict(fields: dict[str, str], hosts: Iterable[str]) -> str | None:
    """:func:`verdict` of header fields already parsed (names in lower case)."""
    hosts = set(hosts)
    host = fields.get("host", "")
    if host.lower() not in hosts:
        return f"Host {host!r} is not this server ({', '.join(sorted(hosts))})"
    origin = fields.get("origin")
    if origin is not None and origin.lower() not in {f"http://{h}" for h in hosts}:
        return f"Origin {origin!r} is not this server's"
    return None


class Gate:
    """Listens on ``host:port`` (the next free port upwards) and passes allowed connections to ``upstream_port`` on
    127.0.0.1.

    Attributes:
        port: The port it listens on.
    """

    def __init__(self, host: str, port: int, upstream_port: int) -> None:
        self.host, self.upstream = host, upstream_port
        self.loop = asyncio.new_event_loop()
        self._server: asyncio.Server | None = None
        ready = threading.Event()
        failure: list[BaseException] = []

        async def start() -> None:
            for candidate in range(port, port + PORT_TRIES):
                try:
                    self._server = await asyncio.start_server(self._serve, host, candidate, limit=HEAD_LIMIT)
                    self.port = candidate
                    return
                except OSError as exc:
                    failure[:] = [exc]
            raise failure[0]

        def run() -> None:
            asyncio.set_event_loop(self.loop)
            try:
                self.loop.run_until_complete(start())
                failure.clear()
            except BaseException as exc:  # noqa: BLE001 - reported to the constructor's thread
                failure[:] = [exc]
            ready.set()
            if not failure:
                self.loop.run_forever()
            self.loop.close()

        self.thread = threading.Thread(target=run, name="reach-gate", daemon=True)
        self.thread.start()
        ready.wait()
        if failure:
            raise failure[0]
        self.hosts = allowed_hosts(host, self.port)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_SECONDS)
        except (TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
            writer.close()
            return
        why = verdict(head, self.hosts)
        if why is not None:
            body = f"forbidden: {why}\n".encode()
            writer.write(b"HTTP/1.1 403 Forbidden\r\nContent-Type: text/plain\r\nConnection: close\r\nContent-Length: "
                         + str(len(body)).encode() + b"\r\n\r\n" + body)
            await writer.drain()
            writer.close()
            return
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream)
        except OSError:
            writer.close()
            return
        up_writer.write(head)
        await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))

    def close(self) -> None:
        async def stop() -> None:
            # Open connections' pipes are cancelled and awaited here, so none is
            # left to close its socket on a loop that has gone.
            if self._server is not None:
                self._server.close()
            pending = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in pending:
                task.cancel()
            await asyncio.gather(*pending, return_exceptions=True)

        if self.loop.is_running():
            asyncio.run_coroutine_threadsafe(stop(), self.loop).result(timeout=5)
            self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=5)


_PATCH = threading.Lock()  # one guarded server starts at a time: the patch below is process-wide while it does


@contextlib.contextmanager
def guarded_websockets(hosts: Callable[[], Iterable[str]]) -> Iterator[list[int]]:
    """While open, every server that ``websockets.asyncio.server.serve`` starts (viser's) refuses, with
    ``403 Forbidden``, each request whose Host or Origin is not one of ``hosts()`` (asked per request:
    the gate's names are known only once it listens; empty refuses everything).

    viser offers no hook of its own for this; its server calls ``serve`` with a ``process_request``, which is
    wrapped here. The guard stays with each server started meanwhile; ``serve`` is restored on exit. Yields a
    list that holds one entry per server guarded, so that a caller can refuse to go on when none was (a viser
    that no longer starts its server this way).
    """
    # the websockets server only behind the viewer's gate
    import websockets.asyncio.server as ws_server

    def guard(inner: Callable[..., Any] | None) -> Callable[..., Any]:
        def process_request(connection: Any, request: Any) -> Any:
            fields = {k.lower(): v for k, v in request.headers.raw_items()}
            why = fields_verdict(fields, hosts())
            if why is not None:
                return connection.respond(403, f"forbidden: {why}\n")
            return None if inner is None else inner(connection, request)

        return process_request

    guarded: list[int] = []
    with _PATCH:
        original = ws_server.serve

        def serve(*args: Any, **kwargs: Any) -> Any:
            kwargs["process_request"] = guard(kwargs.get("process_request"))
            guarded.append(1)
            return original(*args, **kwargs)

        ws_server.serve = serve  # type: ignore[assignment, misc]
        try:
            yield guarded
        finally:
            ws_server.serve = original  # type: ignore[misc]


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(1 << 16):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        writer.close()
