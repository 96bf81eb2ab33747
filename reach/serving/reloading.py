"""``reload``: its path checked under the folder the operator allows, and the atlas loaded in a background thread
while the current one answers; the server's loop swaps it in when it is ready."""

from __future__ import annotations

import concurrent.futures
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from reach.serving import cells
from reach.serving import protocol as P

# Linux's limits on a path and on one of its names [bytes]: past them the file system raises ENAMETOOLONG.
PATH_MAX, NAME_MAX = 4096, 255


@dataclass
class Reloading:
    """An atlas loading in the background for a ``reload`` request."""

    envelope: list[bytes]
    request: P.Request
    path: Path
    future: concurrent.futures.Future


class Reloads:
    """A server's reloads.

    Args:
        root: The folder under which ``reload`` may load atlases; None refuses every ``reload``.
        load: Loads an atlas folder and makes what the server serves of it.
    """

    def __init__(self, root: str | Path | None, load: Callable[[Path], cells.Served]) -> None:
        self.root = None if root is None else Path(root).resolve()
        self.load = load
        self.job: Reloading | None = None
        self._loader: concurrent.futures.ThreadPoolExecutor | None = None

    def path(self, req: P.Request, current: Path) -> Path:
        """The atlas folder a ``reload`` asks for (``current`` when it names none), or ProtocolError: reload off, a
        path no file system can name, or one outside the root."""
        if self.root is None:
            raise P.ProtocolError(P.FORBIDDEN, "reload is off; the operator allows it with reach serve "
                                               "--allow-reload ROOT", req.id)
        if "\0" in (req["path"] or ""):
            raise P.ProtocolError(P.BAD_REQUEST, "path: a NUL character cannot be in a file path", req.id)
        # Checked before the path is touched: a refused path reveals nothing of what exists there.
        try:
            path = (self.root / req["path"]).resolve() if req["path"] else current
        except (OSError, UnicodeError, ValueError) as exc:  # too long for the system, a lone surrogate
            raise P.ProtocolError(P.BAD_REQUEST, f"path: not a file path this system can name ({exc})"[:300],
                                  req.id) from None
        if len(str(path).encode()) >= PATH_MAX or any(len(part.encode()) > NAME_MAX for part in path.parts):
            raise P.ProtocolError(P.BAD_REQUEST, f"path: longer than a file path may be ({PATH_MAX} bytes, "
                                                 f"{NAME_MAX} a name)", req.id)
        if not path.is_relative_to(self.root):
            raise P.ProtocolError(P.FORBIDDEN, f"reload loads atlases under {self.root} only", req.id)
        return path

    def later(self, req: P.Request, envelope: list[bytes], path: Path) -> None:
        """Start loading a ``reload``'s atlas in the background; :meth:`ready` gives it when it is loaded."""
        if self.job is not None:
            raise P.ProtocolError(P.RELOAD_FAILED, f"kept the current atlas: another reload ({self.job.path}) "
                                                   "is loading", req.id)
        if self._loader is None:
            self._loader = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="reach-reload")
        self.job = Reloading(envelope, req, path, self._loader.submit(self.load, path))

    def ready(self) -> Reloading | None:
        """The background reload whose atlas is loaded (or failed to load), taken; None while none is."""
        if self.job is None or not self.job.future.done():
            return None
        job, self.job = self.job, None
        return job

    def close(self) -> None:
        if self._loader is not None:
            self._loader.shutdown(wait=True, cancel_futures=True)
