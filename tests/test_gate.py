"""The gate in front of the viewer (reach.tools.gate): which request heads pass, and a real connection through it."""

from __future__ import annotations

import http.server
import socket
import threading

from reach.tools.gate import Gate, allowed_hosts, verdict


def head(host: str, origin: str | None = None) -> bytes:
    lines = ["GET / HTTP/1.1", f"Host: {host}", *([f"Origin: {origin}"] if origin else [])]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def test_only_this_servers_names_and_origin_pass():
    hosts = allowed_hosts("127.0.0.1", 8080)
    assert hosts == {"127.0.0.1:8080", "localhost:8080", "[::1]:8080"}
    assert (verdict(head("127.0.0.1:8080"), hosts) is None
            and verdict(head("LOCALHOST:8080", "http://localhost:8080"), hosts) is None)
    assert "Host 'evil.example:8080' is not this server" in verdict(head("evil.example:8080"),
        hosts)  # type: ignore[operator]
    assert "Host '127.0.0.1' is not" in verdict(head("127.0.0.1"), hosts)  # type: ignore[operator]
    assert "Origin 'http://evil.example' is not" in verdict(head("127.0.0.1:8080", "http://evil.example"),
                                                            hosts)  # type: ignore[operator]
    assert "Origin 'null' is not" in verdict(head("127.0.0.1:8080", "null"), hosts)  # type: ignore[operator]
    assert "Host '' is not" in verdict(b"GET / HTTP/1.1\r\n\r\n", hosts)  # type: ignore[operator]
    assert allowed_hosts("0.0.0.0", 9000) == {"127.0.0.1:9000", "localhost:9000", "[::1]:9000"}
    assert "10.1.2.3:9000" in allowed_hosts("10.1.2.3", 9000) and "[::2]:9000" in allowed_hosts("::2", 9000)


def test_a_connection_passes_through_to_the_server_behind_or_is_refused():
    class Hello(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - the standard library's name
            body = b"behind the gate"
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    upstream = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Hello)
    threading.Thread(target=upstream.serve_forever, daemon=True).start()
    gate = Gate("127.0.0.1", 18700, upstream.server_address[1])
    try:
        for host, expect in ((f"127.0.0.1:{gate.port}", b"behind the gate"), ("evil.example", b"403 Forbidden")):
            with socket.create_connection(("127.0.0.1", gate.port), timeout=10) as s:
                s.sendall(head(host)[:-2] + b"Connection: close\r\n\r\n")
                data = b""
                while chunk := s.recv(4096):
                    data += chunk
            assert expect in data, data
    finally:
        gate.close()
        upstream.shutdown()
        upstream.server_close()


def test_closing_the_gate_ends_the_connections_still_open():
    """A connection left open through the gate (a viewer's WebSocket) is cut when the gate closes: its pipes end
    on the gate's own loop, which then closes, so nothing is left to run on a loop that has gone."""
    upstream = socket.create_server(("127.0.0.1", 0))
    gate = Gate("127.0.0.1", 18800, upstream.getsockname()[1])
    client = socket.create_connection(("127.0.0.1", gate.port), timeout=10)
    try:
        client.sendall(head(f"127.0.0.1:{gate.port}"))
        behind, _ = upstream.accept()
        behind.settimeout(10)
        assert behind.recv(4096).startswith(b"GET / HTTP/1.1")  # the connection is open through the gate
        gate.close()
        assert not gate.thread.is_alive() and gate.loop.is_closed()
        assert client.recv(4096) == b"" and behind.recv(4096) == b""  # both ends see the gate hang up
        behind.close()
    finally:
        client.close()
        upstream.close()
