"""Error replies: what an exception raised while answering a request tells its client, and a bug's traceback in the
log (each distinct one at most once a minute: a client repeating a request must not flood the log)."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

from reach.errors import MotionError, ReachError, UnknownEffector, UnknownStrategy
from reach.serving import protocol as P

log = logging.getLogger("reach.serving.server")  # the server's: its error lines were always said there
LOG_EVERY = 60.0  # [s] an identical internal error's traceback is logged at most this often


class Faults:
    """A server's error replies and their count.

    Attributes:
        count: Error replies made so far (``health``'s ``errors``).
    """

    def __init__(self) -> None:
        self.count = 0
        self._logged: dict[str, float] = {}

    def reply(self, exc: Exception, rid: Any) -> bytes:
        """The error reply of an exception raised while answering a request (a bug's is logged as ``internal``)."""
        self.count += 1
        if isinstance(exc, P.ProtocolError):
            return P.error_reply(exc.code, exc.message, exc.request_id if exc.request_id is not None else rid)
        if isinstance(exc, MotionError):
            return P.error_reply(exc.code, str(exc), rid)
        if isinstance(exc, ReachError):
            code = (P.UNKNOWN_EFFECTOR if isinstance(exc, UnknownEffector) else P.UNKNOWN_STRATEGY
                    if isinstance(exc, UnknownStrategy) else P.BAD_REQUEST)
            return P.error_reply(code, str(exc), rid)
        self.internal(exc)
        return P.error_reply(P.INTERNAL, f"{type(exc).__name__}: {exc}", rid)

    def internal(self, exc: Exception) -> None:
        """Log a bug's traceback, each distinct one at most once every ``LOG_EVERY`` seconds."""
        key = f"{type(exc).__name__}: {exc}"[:300]
        now = time.monotonic()
        if now - self._logged.get(key, -math.inf) >= LOG_EVERY:
            self._logged[key] = now
            log.error("internal error", exc_info=exc)
