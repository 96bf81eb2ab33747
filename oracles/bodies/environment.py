"""Static boxes in the world: a table, a wall, a seat's pan and backrest.

A box is its extent ``lo``..``hi`` [m] in its own frame, turned by
``rotation`` about its centre (identity: axis-aligned in the world frame).
The obstacles task keeps segments out of boxes; a seated body carries its
seat as boxes (:mod:`oracles.bodies.seat`); the viewer draws them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from oracles.errors import TaskError

IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class Box:
    """A box [m]: its extent in its own frame, turned by ``rotation`` (rows of a 3x3 matrix) about its centre."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...] = IDENTITY
    name: str = ""

    @property
    def centre(self) -> np.ndarray:
        return 0.5 * (np.asarray(self.lo) + np.asarray(self.hi))

    @property
    def half(self) -> np.ndarray:
        return 0.5 * (np.asarray(self.hi) - np.asarray(self.lo))

    @property
    def matrix(self) -> np.ndarray:
        return np.asarray(self.rotation, float)

    def outside(self, p: np.ndarray) -> tuple[float, np.ndarray]:
        """Signed distance [m] of a world point to the box (negative inside) and the world direction away from it."""
        r = self.matrix
        local = r.T @ (np.asarray(p, float) - self.centre)
        side = np.where(local >= 0.0, 1.0, -1.0)
        d = np.abs(local) - self.half
        if np.all(d <= 0):  # inside: out through the nearest face
            k = int(np.argmax(d))
            return float(d[k]), r @ (side[k] * np.eye(3)[k])
        out = np.maximum(d, 0.0) * side
        n = float(np.linalg.norm(out))
        return n, r @ (out / n)

    def corners(self) -> np.ndarray:
        """The eight corners (8, 3) [m] in the world frame."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return self.centre + (signs * self.half) @ self.matrix.T

    def as_row(self) -> np.ndarray:
        """centre (3) [m], half sizes (3) [m], orientation quaternion (w, x, y, z): what the viewer draws."""
        q = pin.Quaternion(self.matrix)
        return np.concatenate([self.centre, self.half, [q.w, q.x, q.y, q.z]])

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"min": [round(v, 6) for v in self.lo], "max": [round(v, 6) for v in self.hi]}
        if self.rotation != IDENTITY:
            out["rpy"] = [round(float(v), 6) for v in pin.rpy.matrixToRpy(self.matrix)]
        if self.name:
            out["name"] = self.name
        return out


def turned(lo: np.ndarray, hi: np.ndarray, rpy: tuple[float, float, float], name: str = "") -> Box:
    """A box of extent lo..hi [m] turned by roll, pitch, yaw [rad] about its centre."""
    rotation = tuple(tuple(float(v) for v in row) for row in pin.rpy.rpyToMatrix(*rpy))
    return Box(tuple(float(c) for c in lo), tuple(float(c) for c in hi), rotation, name)  # type: ignore[arg-type]


def parse_box(value: Any, where: str) -> Box:
    """``{min: [x, y, z], max: [x, y, z], rpy: [r, p, y]}`` [m, rad]; rpy (optional) turns the box about its centre."""
    if not isinstance(value, dict) or not {"min", "max"} <= set(value) or set(value) - {"min", "max", "rpy", "name"}:
        raise TaskError(where, f"expected {{min: [x, y, z], max: [x, y, z]}} in metres (and optionally rpy: [r, p, "
                               f"y] in radians), got {value!r}")
    vectors = {}
    for key in ("min", "max", "rpy"):
        v = value.get(key, [0.0, 0.0, 0.0])
        if not isinstance(v, list) or len(v) != 3 or not all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                             and np.isfinite(c) for c in v):
            raise TaskError(f"{where}.{key}", f"expected [x, y, z] in {'radians' if key == 'rpy' else 'metres'}, got "
                                              f"{v!r}")
        vectors[key] = np.array(v, float)
    lo, hi = vectors["min"], vectors["max"]
    if not np.all(lo < hi):
        raise TaskError(where, f"min must be below max on every axis, got {lo.tolist()} and {hi.tolist()}")
    return turned(lo, hi, tuple(vectors["rpy"]), str(value.get("name", "")))  # type: ignore[arg-type]
