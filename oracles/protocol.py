"""The oracle protocol: what the tree builder asks and what it gets back.

An oracle answers, for a batch of points, whether each is inside the volume
(reachable), how far from it the best attempt ended (the residual, metres),
and, for oracles that find one, the posture that reaches it.

The builder never shows an oracle the tree; it only sends batches of points
with optional warm-start postures (hints).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol, runtime_checkable

import numpy as np

from reach.errors import OracleError


class Verdicts(NamedTuple):
    """Per-point answers of an oracle.

    Attributes:
        reachable: (N,) bool.
        residual: (N,) float, distance [m] between the goal and what was reached
            (0 for analytic oracles inside the volume).
        posture: (N, nq) float configurations, or None for oracles without
            postures. Rows of unreachable points hold the best attempt.
    """

    reachable: np.ndarray
    residual: np.ndarray
    posture: np.ndarray | None

    @staticmethod
    def concatenate(parts: list[Verdicts]) -> Verdicts:
        """Join the verdicts of consecutive chunks."""
        if not parts:
            return Verdicts(np.zeros(0, bool), np.zeros(0), None)
        posture = None
        if parts[0].posture is not None:
            posture = np.concatenate([p.posture for p in parts if p.posture is not None])
        return Verdicts(
            np.concatenate([p.reachable for p in parts]),
            np.concatenate([p.residual for p in parts]),
            posture,
        )


@runtime_checkable
class Oracle(Protocol):
    """Anything that classifies points.

    Attributes:
        dim: Dimension of the points (2 or 3).
        posture_names: Names of the posture coordinates (empty when the oracle
            returns no postures).
    """

    dim: int
    posture_names: tuple[str, ...]

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None = None) -> Verdicts:
        """Classify points.

        Args:
            points: (N, dim) goals [m].
            hints: Optional (N, nq) warm-start postures; a NaN row means no hint.

        Returns:
            The verdicts, one per point, in order.
        """
        ...


@dataclass(frozen=True)
class OracleSpec:
    """A serialisable description from which any process can build an oracle.

    Workers receive specs, never oracle objects, so heavy solver objects are
    built once per worker and never pickled per task.

    Attributes:
        name: Registry name, e.g. ``sphere`` or ``casadi-ik``.
        params: JSON-compatible keyword arguments of the oracle's factory.
    """

    name: str
    params: dict[str, Any] = field(default_factory=dict)

    def create(self) -> Oracle:
        """Build the oracle through the registry."""
        from oracles.registry import create

        return create(self)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "params": dict(self.params)}

    @staticmethod
    def from_dict(data: dict[str, Any]) -> OracleSpec:
        return OracleSpec(str(data["name"]), dict(data.get("params", {})))


def check_points(points: np.ndarray, dim: int) -> np.ndarray:
    """Return points as a float (N, dim) array or raise a clear error."""
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise OracleError(f"points must have shape (N, {dim}), got {arr.shape}")
    return arr


def check_verdicts(verdicts: Verdicts, n: int, nq: int) -> Verdicts:
    """Validate what an oracle returned for n points with nq posture coordinates."""
    reach = np.asarray(verdicts.reachable, dtype=bool)
    res = np.asarray(verdicts.residual, dtype=float)
    if reach.shape != (n,) or res.shape != (n,):
        raise OracleError(
            f"oracle returned reachable {reach.shape} and residual {res.shape}, expected ({n},)"
        )
    posture = verdicts.posture
    if nq and posture is None:
        raise OracleError(f"oracle declares {nq} posture names but returned no postures")
    if posture is not None:
        posture = np.asarray(posture, dtype=float)
        if posture.shape != (n, nq):
            raise OracleError(f"oracle returned postures {posture.shape}, expected ({n}, {nq})")
    return Verdicts(reach, res, posture)
