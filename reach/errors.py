"""Errors raised by reach, and the oracles' own re-exported.

Every error a user can trigger derives from :class:`ReachError` and carries
the file, key or field it is about, so that a message names what was wrong
and what was expected. The root and the oracles' errors live in
:mod:`oracles.errors` (the lower layer); they are re-exported here so that
``reach.errors`` names every error.
"""

from __future__ import annotations

from pathlib import Path

from oracles.errors import ModelError, OracleError, ReachError, TaskError

__all__ = [
    "ConfigError", "InputError", "ModelError", "ModelMismatch", "MotionError", "OracleError", "ProtocolError",
    "ReachError", "ServerError",
    "ServerUnavailable", "StoreError", "TaskError", "TreeError", "UnknownEffector", "UnknownName", "UnknownPolicy",
    "UnknownStrategy",
]


class ConfigError(ReachError):
    """A configuration file or mapping is invalid.

    Attributes:
        source: The file (or "<mapping>") the configuration came from.
        key: Dotted path of the offending key, e.g. ``depth.max``.
        reason: What was wrong and what was expected.
    """

    def __init__(self, source: str | Path, key: str, reason: str) -> None:
        self.source = str(source)
        self.key = key
        self.reason = reason
        where = f"{self.source}: {key}" if key else self.source
        super().__init__(f"{where}: {reason}")


class StoreError(ReachError):
    """A stored tree or atlas cannot be read or written.

    Attributes:
        path: The file concerned.
        reason: What is wrong with it.
    """

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class UnknownName(ReachError):
    """A name that the atlas or the model does not have.

    Attributes:
        what: What kind of name (``effector``, ``strategy``, ``policy``...).
        name: The name given.
        known: The names that would have been accepted.
    """

    what = "name"
    known_as = "expected one of"

    def __init__(self, name: str, known: list[str] | tuple[str, ...], where: str = "") -> None:
        self.name = name
        self.known = list(known)
        self.where = where
        prefix = f"{where}: " if where else ""
        super().__init__(f"{prefix}unknown {self.what} {name!r}; {self.known_as} {', '.join(self.known)}")


class UnknownEffector(UnknownName):
    """A goal was asked for an effector that no strategy of the atlas moves."""

    what = "effector"
    known_as = "this atlas has"


class UnknownStrategy(UnknownName):
    """A strategy that the atlas does not have."""

    what = "strategy"
    known_as = "the atlas has"


class ModelMismatch(ReachError):
    """A stored tree was built for another body model than its spec now builds.

    Attributes:
        path: The atlas folder.
        strategy: The strategy's name.
        stored: The model hash stored with the tree.
        current: The model hash its spec builds today.
    """

    def __init__(self, path: str | Path, strategy: str, stored: str, current: str) -> None:
        self.path, self.strategy, self.stored, self.current = str(path), strategy, stored, current
        super().__init__(f"{self.path}: strategy {strategy!r} was built for model {stored}, but its body now builds "
                         f"model {current}; rebuild the atlas")


class ProtocolError(ReachError):
    """A request the server refuses, with the code and message of its error reply.

    Attributes:
        code: One of the error codes of :mod:`reach.serving.protocol`.
        message: What was wrong and what was expected.
        request_id: The request's ``id`` when it could be read, else None.
    """

    def __init__(self, code: str, message: str, request_id: object = None) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.request_id = request_id


class ServerError(ReachError):
    """The server answered with an error reply.

    Attributes:
        code: The reply's error code.
        message: The reply's message.
    """

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code, self.message = code, message


class ServerUnavailable(ReachError):
    """No reply after every retry.

    Attributes:
        address: The server's address.
        attempts: How many requests were sent.
        timeout_ms: How long each waited [ms].
    """

    def __init__(self, address: str, attempts: int, timeout_ms: int) -> None:
        self.address, self.attempts, self.timeout_ms = address, attempts, timeout_ms
        super().__init__(f"no reply from {address} after {attempts} attempts of {timeout_ms} ms")


class TreeError(ReachError):
    """An operation on trees is impossible (e.g. booleans of mismatched lattices).

    Attributes:
        reason: What was wrong and what was expected.
        what: The argument or tree concerned, when there is one.
    """

    def __init__(self, reason: str, *, what: str | None = None) -> None:
        self.reason, self.what = reason, what
        super().__init__(f"{what}: {reason}" if what else reason)


class UnknownPolicy(UnknownName, TreeError):
    """A boundary policy other than ``conservative``, ``optimistic`` or ``vertex``."""

    what = "policy"


class InputError(ReachError):
    """A value given on the command line or through the Python API is invalid.

    Attributes:
        field: The argument or field, e.g. ``goals``.
        reason: What was wrong and what was expected.
    """

    def __init__(self, field: str, reason: str) -> None:
        self.field, self.reason = field, reason
        super().__init__(f"{field}: {reason}")


class MotionError(ReachError):
    """No motion could be planned: the goal is out of reach (with ``miss="error"``), no path holds every task, or the
    deadline passed.

    Attributes:
        code: The reason as a reply names it: ``unreachable``, ``no_motion`` or ``timeout``.
    """

    def __init__(self, message: str, code: str = "no_motion") -> None:
        super().__init__(message)
        self.code = code
