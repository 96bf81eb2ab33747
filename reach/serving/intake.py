"""The clients' messages as the loop reads them: small ones answered at once, large ones in turn, client by client.

libzmq's ROUTER takes one message from each peer in turn, and the loop answered each as it came: under 100 clients
each sending 1 MiB requests, a quiet client's stored query waited behind about a hundred parses of 1.4 ms each, and
its p99 was 0.97 s (bench/attacks.py ``memory``, 2 cores). Reading a message without copying it costs tens of
microseconds, parsing a large one milliseconds: so the loop reads every message that waits, answers the small ones
at once, and keeps the large ones (``LARGE`` bytes or more) in a backlog, one queue a client, which it parses in turn
for about ``SLICE`` seconds a pass. The backlog is bounded (``BACKLOG`` bytes, ``PER_CLIENT`` requests a client): a
large message beyond it is answered ``busy`` unread. A client's small request may so be answered before its earlier
large one (docs/protocol.md: a DEALER client matches replies by ``id``). A request whose answer costs the loop
milliseconds (``accommodation``) waits in the backlog the same way, once parsed.
"""

from __future__ import annotations

import functools
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any

import zmq

from reach.serving import protocol as P

LARGE = 1 << 16  # [bytes] a message this large or larger waits in the backlog (a 10,000-goal batch is about 300 KB)
# [s] the parsing of large messages one pass of the loop does at most: a quiet client's request waits about one
# pass (its read, the small messages' answers and this)
SLICE = 0.005
BACKLOG = 32 << 20  # [bytes] the backlog's messages at most, every client together ...
PER_CLIENT = 16  # ... and the requests of one client in it
# messages read in one pass of the loop (each a few tens of microseconds, unparsed): libzmq takes them from each client
# in turn, so a quiet client's is among the first hundred of a hundred clients' flood
READ_AT_MOST = 128

Frames = list[bytes]
FULL_MESSAGE = (f"the server holds as many large or costly requests as it may ({BACKLOG >> 20} MiB, {PER_CLIENT} a "
                "client): retry later")
FULL = P.error_reply(P.BUSY, FULL_MESSAGE)


def envelope_of(frames: Frames) -> tuple[list[bytes], Frames]:
    """A message's routing envelope (the identity, and a REQ client's empty delimiter) and the frames after it."""
    identity, rest = frames[0], frames[1:]
    envelope = [identity]
    if rest and rest[0] == b"" and len(rest) >= 2:
        envelope.append(b"")  # a REQ client's delimiter, echoed back
        rest = rest[1:]
    return envelope, rest


# A piece of the loop's work: called, it does a step and returns what is left of it (None: done).
Work = Callable[[], "Work | None"]


class Intake:
    """The messages a ROUTER holds, read and answered in the order the module docstring gives.

    Args:
        router: The server's ROUTER socket.
        handle: Answers one message (its frames as bytes); ``later=True`` for one taken from the backlog.
        send: Sends a reply to an envelope (a refusal's ``busy``).
    """

    def __init__(self, router: zmq.Socket, handle: Callable[[Frames, bool], None],  # type: ignore[type-arg]
                 send: Callable[[list[bytes], bytes], None]) -> None:
        self.router, self.handle, self.send = router, handle, send
        self.backlog: OrderedDict[bytes, deque[tuple[Work, int]]] = OrderedDict()
        self.bytes = 0  # the backlog's messages' bytes
        self.refused = 0  # large or costly requests answered busy (health)

    def __bool__(self) -> bool:
        """Whether work waits in the backlog (the loop then polls without waiting)."""
        return bool(self.backlog)

    @property
    def held(self) -> int:
        """Requests in the backlog (health)."""
        return sum(len(queue) for queue in self.backlog.values())

    def read(self, first: list[zmq.Frame] | None = None) -> None:
        """Answer the small messages waiting now (``first``, one the loop has read already, before them); the large
        ones go to the backlog."""
        for k in range(READ_AT_MOST):
            if k == 0 and first is not None:
                frames = first
            else:
                try:
                    frames = self.router.recv_multipart(zmq.NOBLOCK, copy=False)
                except zmq.Again:
                    return
            size = sum(len(f) for f in frames)
            if size < LARGE:
                self.handle([f.bytes for f in frames], False)
            else:
                envelope, _ = envelope_of([f.bytes if len(f) < LARGE else b"-" for f in frames])
                self.hold(envelope, functools.partial(self._later, frames), size)

    def _later(self, frames: list[zmq.Frame]) -> None:
        self.handle([f.bytes for f in frames], True)
        return None

    def hold(self, envelope: list[bytes], work: Work, size: int, rid: Any = None) -> None:
        """Keep ``work`` (a large message's, or a costly request's answer; ``size`` its message's bytes) for a later
        slice, or answer ``busy`` (with ``rid``: a large message is refused unread, with none) when the backlog is
        full."""
        client = envelope[0]
        queue = self.backlog.get(client)
        if self.bytes + size > BACKLOG or (queue is not None and len(queue) >= PER_CLIENT):
            self.refused += 1
            # one reply made once for the unread (a flood's refusals are most of what the loop sends)
            self.send(envelope, FULL if rid is None else P.error_reply(P.BUSY, FULL_MESSAGE, rid))
            return
        self.backlog.setdefault(client, deque()).append((work, size))
        self.bytes += size

    def run(self) -> None:
        """Do the backlog's work for about ``SLICE`` seconds (a step at least): a client's request to its end, then
        the next client's (in turn)."""
        end = time.perf_counter() + SLICE
        while self.backlog:
            client, queue = next(iter(self.backlog.items()))
            work, size = queue[0]
            more = work()
            if more is not None:
                queue[0] = (more, size)
            else:
                queue.popleft()
                self.bytes -= size
                if queue:
                    self.backlog.move_to_end(client)  # the next client's turn
                else:
                    del self.backlog[client]
            if time.perf_counter() >= end:
                return
