"""Errors raised by oracles: the root of every error the project raises on purpose, and the oracles' own.

They live here because oracles are the lower layer: ``reach`` imports
them (and :mod:`reach.errors` re-exports them), never the other way round.
Each carries the fields that locate the problem, so that a caller can act
on them and a message names what was wrong and what was expected.
"""

from __future__ import annotations

from pathlib import Path


class ReachError(Exception):
    """Root of every error reach and its oracles raise on purpose."""


class OracleError(ReachError):
    """An oracle is unknown, misconfigured, asked something malformed, or returned malformed verdicts.

    Attributes:
        reason: What was wrong and what was expected.
        oracle: The oracle's registry name, when known.
        key: The parameter or argument concerned (``solver``, ``points``...),
            when there is one (the reason names it too).
    """

    def __init__(self, reason: str, *, oracle: str | None = None, key: str | None = None) -> None:
        self.reason, self.oracle, self.key = reason, oracle, key
        super().__init__(f"{oracle}: {reason}" if oracle else reason)


class ModelError(ReachError):
    """A body model (URDF, generated human, frame or joint name) is invalid or unknown.

    Attributes:
        reason: What was wrong and what was expected.
        source: The file or body spec the model came from, when known.
        name: The joint, frame, link or key concerned, when there is one (the
            reason names it too).
        key: Where in the spec the user wrote the offending value (``body.frames.grip.parent``,
            ``tasks[1].margin``, ``joints``), when known; enclosing specs prefix it as
            the error passes up (a config then names the key as written).
    """

    def __init__(self, reason: str, *, source: str | Path | None = None, name: str | None = None,
                 key: str | None = None) -> None:
        self.reason, self.source, self.name, self.key = reason, None if source is None else str(source), name, key
        super().__init__(reason)

    def __str__(self) -> str:
        return ": ".join([p for p in (self.source, self.key) if p] + [self.reason])

    def under(self, prefix: str) -> ModelError:
        """This error, its key placed under ``prefix`` (the enclosing spec's key); returns self."""
        self.key = f"{prefix}.{self.key}" if self.key else prefix
        return self


class TaskError(ModelError):
    """A strategy's task is misconfigured.

    Attributes:
        key: Where in the strategy, e.g. ``tasks[1].heels``.
        reason: What was wrong and what was expected.
    """

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(reason, name=key, key=key)
