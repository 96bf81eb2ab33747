"""A motion played in real time (or slower) on a thread of its own, paused at once."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class Playback:
    """Frames shown one at a time at a rate, until the last or until stopped."""

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    @property
    def playing(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, first: int, last: int, rate: float, show: Callable[[int], None]) -> None:
        """Show frames ``first`` .. ``last`` at ``rate`` [Hz], each at its time from now."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, args=(first, last, rate, show), daemon=True)
        self._thread.start()

    def _run(self, first: int, last: int, rate: float, show: Callable[[int], None]) -> None:
        t0 = time.monotonic()
        for k in range(first, last + 1):
            if self._stop.wait(max(0.0, t0 + (k - first) / rate - time.monotonic())):
                return
            show(k)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._thread = None
