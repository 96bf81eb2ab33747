"""Analytic oracles: volumes whose truth is known in closed form.

They stand in for the IK oracle in tests and demos (the paper tested the
VATree on a sphere first). Residuals are the Euclidean distance [m] from the
point to the volume, 0 inside. None returns postures.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

import numpy as np

from oracles.errors import OracleError
from oracles.protocol import Goals, Oracle, OracleSpec, Verdicts


def _vector(name: str, value: Any, dim: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros((0, 0))  # refused below
    if arr.ndim != 1 or (dim is not None and arr.shape[0] != dim) or not np.all(np.isfinite(arr)):
        want = f"{dim} finite numbers" if dim else "a list of finite numbers"
        raise OracleError(f"{name} must be {want}, got {value!r}", key=name)
    return arr


def _positive(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise OracleError(f"{name} must be a positive number [m], got {value!r}", key=name) from None
    if not np.isfinite(v) or v <= 0:
        raise OracleError(f"{name} must be a positive number [m], got {value!r}", key=name)
    return v


class _Analytic(ABC):
    """Shared verdict plumbing: subclasses give the distance to the volume."""

    dim: int
    posture_names: tuple[str, ...] = ()

    @abstractmethod
    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance [m] of each point to the volume's surface (negative inside)."""

    def evaluate(self, goals: Goals | np.ndarray) -> Verdicts:
        pts = Goals.points_of(goals, self.dim)
        dist = self.distance(pts)
        return Verdicts(dist <= 0.0, np.maximum(dist, 0.0), None)


class Ball(_Analytic):
    """Closed ball (disc in 2-D) of a given centre and radius [m]."""

    def __init__(self, center: Sequence[float], radius: float) -> None:
        self.center = _vector("center", center)
        self.dim = self.center.shape[0]
        self.radius = _positive("radius", radius)

    def distance(self, points: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points - self.center, axis=1) - self.radius  # type: ignore[no-any-return]


def circle(center: Sequence[float] = (0.0, 0.0), radius: float = 1.0) -> Ball:
    """The 2-D disc of the paper's Figure 2."""
    ball = Ball(center, radius)
    if ball.dim != 2:
        raise OracleError(f"circle needs a 2-D center, got {list(center)}", oracle="circle", key="center")
    return ball


def sphere(center: Sequence[float] = (0.0, 0.0, 0.0), radius: float = 1.0) -> Ball:
    """The 3-D ball the paper first approximated."""
    ball = Ball(center, radius)
    if ball.dim != 3:
        raise OracleError(f"sphere needs a 3-D center, got {list(center)}")
    return ball


class BoxOracle(_Analytic):
    """Axis-aligned closed box [min, max] in any dimension."""

    def __init__(self, min: Sequence[float], max: Sequence[float]) -> None:  # noqa: A002
        self.lo = _vector("min", min)
        self.hi = _vector("max", max, self.lo.shape[0])
        if np.any(self.hi < self.lo):
            raise OracleError(f"box max {list(max)} must be >= min {list(min)}")
        self.dim = self.lo.shape[0]

    def distance(self, points: np.ndarray) -> np.ndarray:
        outside = np.maximum(np.maximum(self.lo - points, points - self.hi), 0.0)
        inside = np.minimum(points - self.lo, self.hi - points).min(axis=1)
        return np.where(outside.any(axis=1), np.linalg.norm(outside, axis=1), -inside)


class Torus(_Analytic):
    """Solid torus around the z axis: the volume a circle sweeps.

    Args:
        center: Centre [m].
        major: Distance [m] from the centre to the tube's centre line.
        minor: Tube radius [m]; must be below major.
    """

    dim = 3

    def __init__(self, center: Sequence[float] = (0.0, 0.0, 0.0), major: float = 1.0, minor: float = 0.3) -> None:
        self.center = _vector("center", center, 3)
        self.major = _positive("major", major)
        self.minor = _positive("minor", minor)
        if self.minor >= self.major:
            raise OracleError(f"torus minor radius {minor} must be below the major radius {major}")

    def distance(self, points: np.ndarray) -> np.ndarray:
        p = points - self.center
        ring = np.hypot(p[:, 0], p[:, 1]) - self.major
        return np.hypot(ring, p[:, 2]) - self.minor  # type: ignore[no-any-return]

    @property
    def volume(self) -> float:
        """Exact volume 2 pi^2 R r^2 [m^3]."""
        return 2.0 * np.pi**2 * self.major * self.minor**2


class Combination:
    """Union, intersection or difference of oracles of the same dimension.

    Residuals of a combination are only indicative (0 when inside); the
    verdict is exact.
    """

    posture_names: tuple[str, ...] = ()

    def __init__(self, mode: str, parts: list[Oracle]) -> None:
        if len(parts) < 2:
            raise OracleError(f"{mode} needs at least two oracles, got {len(parts)}")
        dims = {p.dim for p in parts}
        if len(dims) != 1:
            raise OracleError(f"{mode} of oracles of different dimensions {sorted(dims)}")
        self.mode = mode
        self.parts = parts
        self.dim = dims.pop()

    def evaluate(self, goals: Goals | np.ndarray) -> Verdicts:
        pts = Goals.points_of(goals, self.dim)
        verdicts = [p.evaluate(Goals(pts)) for p in self.parts]
        inside = np.stack([v.reachable for v in verdicts])
        res = np.stack([v.residual for v in verdicts])
        if self.mode == "union":
            ok, residual = inside.any(axis=0), res.min(axis=0)
        elif self.mode == "intersection":
            ok, residual = inside.all(axis=0), res.max(axis=0)
        else:
            ok = inside[0] & ~inside[1:].any(axis=0)
            residual = np.where(ok, 0.0, res[0])
        return Verdicts(np.asarray(ok), np.where(ok, 0.0, residual), None)


def _parts(oracles: list[dict[str, Any]]) -> list[Oracle]:
    if not isinstance(oracles, list):
        raise OracleError(f"'oracles' must be a list of oracle specs, got {type(oracles).__name__}")
    return [OracleSpec.from_dict(spec).create() for spec in oracles]


def union(oracles: list[dict[str, Any]]) -> Combination:
    """Points inside any of the oracles."""
    return Combination("union", _parts(oracles))


def intersection(oracles: list[dict[str, Any]]) -> Combination:
    """Points inside all of the oracles."""
    return Combination("intersection", _parts(oracles))


def difference(oracles: list[dict[str, Any]]) -> Combination:
    """Points inside the first oracle and none of the others (e.g. a hollow)."""
    return Combination("difference", _parts(oracles))
