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
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterable

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
    hosts = set(hosts)
    host = fields.get("host", "")
    if host.lower() not in hosts:
        return f"Host {host!r} is not this server ({', '.join(sorted(hosts))})"
    origin = fields.get("origin")
    if origin is not None and origin.lower() not in {f"http://{h}" for h in hosts}:
        return f"Origin {origin!r} is not this server's"
    return None


class Gate:
    """Listens on ``host:port`` (the next free port upwards) and passes allowed connections to ``upstream_port`` on 127.0.0.1.

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


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(1 << 16):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        writer.close()
