"""The choices a server publishes on its PUB socket: topic = the effector, then the choice with the request's id and
tag. A slow subscriber costs a dropped message, never a blocked reply."""

from __future__ import annotations

import math
from collections import deque

import zmq

from reach.serving import protocol as P

# Choices published per pass of the loop (about 5 ms of it: 5 us a message, measured): a 10,000-goal batch's
# publications held the loop 135 ms in one pass.
PUBLISH_SLICE = 1000
# plain ints: pyzmq's flag enums cost 3 us a message
PUB_MORE, PUB_LAST = int(zmq.NOBLOCK | zmq.SNDMORE), int(zmq.NOBLOCK)


class Publisher:
    """Publishes choices in order, all at once or ``PUBLISH_SLICE`` a pass of a broker's loop.

    Args:
        socket: The PUB socket, or None (nothing is published).
        sliced: At most ``PUBLISH_SLICE`` choices a call of :meth:`publish` or :meth:`drain` (a broker's loop).
    """

    def __init__(self, socket: zmq.Socket | None, sliced: bool) -> None:  # type: ignore[type-arg]
        self.socket = socket
        self.slice = PUBLISH_SLICE if sliced else math.inf
        # (topic, head, bodies, next): choices to publish
        self.queue: deque[tuple[bytes, bytes, list[bytes], int]] = deque()

    def publish(self, topic: bytes, bodies: list[bytes], req: P.Request) -> None:
        """Publish each encoded choice with the request's id and tag, in order; what the slice leaves goes on the next
        :meth:`drain`."""
        if self.socket is None:
            return
        head = b'{"id":' + P.encode_value(req.id) + b',"tag":' + P.encode_value(req["tag"])
        self.queue.append((topic, head, bodies, 0))
        self.drain()

    def drain(self) -> None:
        """Publish up to a slice of queued choices, oldest first."""
        send = self.socket.send if self.socket is not None else None
        limit = self.slice
        while self.queue and limit > 0 and send is not None:
            topic, head, bodies, k = self.queue[0]
            end = int(min(len(bodies), k + limit))
            for body in bodies[k:end]:
                try:
                    send(topic, PUB_MORE)
                    send(head + (b"," + body[1:] if body != b"{}" else b"}"), PUB_LAST)
                except zmq.Again:
                    pass
            limit -= end - k
            if end < len(bodies):
                self.queue[0] = (topic, head, bodies, end)
            else:
                self.queue.popleft()
