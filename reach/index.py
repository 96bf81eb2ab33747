"""The reachability index: at each reachable vertex, the share of approach directions reached.

A strategy with ``directions: N`` (and an orientation task with an ``axis``,
the effector's approach axis) is solved, after its tree is built, at every
reachable vertex for N world directions of that axis spread evenly on the
sphere; the tree keeps which were reached (one bit each) and the index is
their share, as in capability maps (Zacharias, Borst & Hirzinger, IROS 2007:
the share of 200 directions reached per voxel) and Reuleaux (Makhal &
Goins, IRC 2018: of 50 poses per sphere).

The directions are the generalised spiral points of Saff & Kuijlaars
("Distributing many points on a sphere", Math. Intelligencer 19(1), 1997):
heights evenly spaced in [-1, 1], each point turned from the one before by
3.6 / sqrt(N) over the circle's radius, so that consecutive points are
neighbours about sqrt(4 pi / N) apart.

Cost: the vertices are taken coarse to fine, and a direction on which the
eight corners of the cell around a new vertex agree is inherited from them
(see :func:`compute_index`); a direction solved starts from a corner's
posture that reached it, then the vertex's stored posture, then the
reference: the reach stage only (the index needs existence, not the most
natural posture) and no random restart (the oracle's ``index`` variant).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from oracles.protocol import Goals
from reach.errors import StoreError
from reach.executor import Executor
from reach.tree import VATree, corner_offsets

MAX_DIRECTIONS = 1000  # a strategy's `directions` at most (capability maps use 200)
SPIRAL_STEP = 3.6  # Saff & Kuijlaars (1997): the spiral's turn, over sqrt(N), per point
AGREE = 0.5  # the least share of a cell's corners, reachable and known, whose agreement on a direction a new vertex inherits


def spiral(n: int) -> np.ndarray:
    """N unit vectors (n, 3) spread evenly on the sphere, consecutive ones neighbours (see the module docstring)."""
    if n < 1:
        return np.zeros((0, 3))
    if n == 1:
        return np.array([[0.0, 0.0, 1.0]])
    h = -1.0 + 2.0 * np.arange(n) / (n - 1)
    theta = np.arccos(h)
    phi = np.zeros(n)
    for k in range(1, n - 1):
        phi[k] = (phi[k - 1] + SPIRAL_STEP / math.sqrt(n) / math.sqrt(1.0 - h[k] ** 2)) % (2.0 * math.pi)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)


@dataclass(frozen=True)
class ReachIndex:
    """Which directions each vertex of a tree reaches.

    Attributes:
        directions: (N, 3) unit world directions of the effector's approach axis.
        reached: (V, N) bool, one row per row of the tree's vertex table (all False where the vertex is unreachable).
    """

    directions: np.ndarray
    reached: np.ndarray

    @property
    def share(self) -> np.ndarray:
        """(V,) the index: the share of directions each vertex reaches, in [0, 1]."""
        return self.reached.mean(axis=1) if self.reached.size else np.zeros(len(self.reached))  # type: ignore[no-any-return]

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"index_directions": self.directions.astype(float), "index_bits": np.packbits(self.reached, axis=1)}

    @staticmethod
    def from_arrays(arrays: dict[str, np.ndarray], vertices: int, where: Any) -> ReachIndex | None:
        """The index stored beside a tree's vertices (None when there is none); StoreError when it does not fit them."""
        if "index_directions" not in arrays and "index_bits" not in arrays:
            return None
        if "index_directions" not in arrays or "index_bits" not in arrays:
            raise StoreError(where, "the reachability index lacks its directions or its bits")
        d, bits = np.asarray(arrays["index_directions"]), np.asarray(arrays["index_bits"])
        if d.ndim != 2 or d.shape[1] != 3 or not np.all(np.isfinite(d)) or np.abs(np.linalg.norm(d, axis=1) - 1.0).max(initial=0.0) > 1e-6:
            raise StoreError(where, f"the reachability index's directions {d.shape} are not unit [x, y, z] rows")
        if bits.dtype != np.uint8 or bits.shape != (vertices, -(-len(d) // 8)):
            raise StoreError(where, f"the reachability index's bits {bits.shape} do not match {vertices} vertices x {len(d)} directions")
        return ReachIndex(d, np.unpackbits(bits, axis=1, count=len(d)).astype(bool))


def vertex_levels(coords: np.ndarray, d_max: int) -> np.ndarray:
    """The coarsest depth (0 .. d_max) at which each lattice vertex (n, dim) is a cell corner."""
    out = np.full(len(coords), d_max, int)
    for k in range(d_max - 1, -1, -1):
        step = 1 << (d_max - k)
        out[np.all(coords % step == 0, axis=1)] = k
    return out


def compute_index(tree: VATree, executor: Executor, directions: np.ndarray, progress: Callable[[int], None] | None = None) -> tuple[ReachIndex, int]:
    """The index of a tree's reachable vertices, by an executor of the strategy's ``index`` variant; and the number of goals it solved.

    Coarse to fine, as Algorithm 1 of the paper labels cells: a vertex that
    first appears at depth k lies in a cell of depth k - 1 whose eight
    corners are known; a direction on which those corners, all reachable,
    agree is taken from them, and only the others are solved. Each solve
    starts from a corner's posture that reached the same direction (the
    effector a cell away), then the vertex's stored posture.
    """
    v, lattice, n = tree.vertices, tree.lattice, len(directions)
    rows = np.nonzero(v.reachable)[0]
    reached = np.zeros((len(v), n), bool)
    if not rows.size or v.posture is None:
        return ReachIndex(directions, reached), 0
    coords = lattice.coords(v.keys[rows])
    levels = vertex_levels(coords, tree.d_max)
    known = np.zeros(len(v), bool)
    posed = np.full((len(v), n, v.posture.shape[1]), np.nan, np.float32)  # the posture that reached each direction (a hint for the finer vertices)
    offsets = corner_offsets(tree.dim)
    solved = 0
    for k in np.unique(levels):
        sel = rows[levels == k]
        at = coords[levels == k]
        todo = np.ones((len(sel), n), bool)
        hint = np.full((len(sel), n, v.posture.shape[1]), np.nan)
        if k > 0:
            step = 1 << (tree.d_max - k + 1)
            corner_rows = v.index(lattice.keys((at // step * step)[:, None, :] + offsets[None] * step))  # (m, 2**dim)
            safe = np.maximum(corner_rows, 0)
            usable = (corner_rows >= 0) & v.reachable[safe] & known[safe]  # (m, 2**dim): the corners whose directions are known
            corner = reached[safe] & usable[:, :, None]  # (m, 2**dim, n)
            some = corner.any(axis=1)
            every = corner.sum(axis=1) == usable.sum(axis=1)[:, None]
            agree = (usable.sum(axis=1) >= AGREE * usable.shape[1])[:, None] & (every | ~some)
            reached[sel] = agree & every
            todo = ~agree
            # A corner's posture for the same direction, when one reached it.
            first = np.argmax(corner, axis=1)  # (m, n) the first corner that reached each direction
            hint = posed[np.take_along_axis(safe, first, axis=1), np.arange(n)[None, :]].astype(float)
            hint[~some] = np.nan
        base = v.posture[sel]
        for j in range(n):
            pick = np.nonzero(todo[:, j])[0]
            if not pick.size:
                continue
            seeds = np.stack([hint[pick, j], base[pick]], axis=1)
            goals = Goals(lattice.points(at[pick]), {"orientation": np.tile(directions[j], (len(pick), 1))}, seeds=seeds)
            verdicts = executor.evaluate(goals, progress)
            solved += len(pick)
            reached[sel[pick], j] = verdicts.reachable
            if verdicts.posture is not None:
                ok = pick[verdicts.reachable]
                posed[sel[ok], j] = verdicts.posture[verdicts.reachable]
        known[sel] = True
    return ReachIndex(directions, reached), solved


def index_at(tree: VATree, points: np.ndarray, held: bool = True) -> np.ndarray:
    """The index at points (n, 3) [m]: its nearest reachable vertex's, at the points the tree holds (``vertex`` policy;
    every point with ``held`` false, e.g. the centres of drawn cells); NaN elsewhere or without an index."""
    pts = np.asarray(points, float).reshape(-1, tree.dim)
    out = np.full(len(pts), np.nan)
    rows = np.nonzero(tree.vertices.reachable)[0]
    if tree.index is None or not rows.size:
        return out
    inside = tree.contains(pts, "vertex") if held else np.ones(len(pts), bool)
    if inside.any():
        from scipy.spatial import cKDTree

        _, near = cKDTree(tree.lattice.points(tree.lattice.coords(tree.vertices.keys[rows]))).query(pts[inside])
        out[inside] = tree.index.share[rows[near]]
    return out


def summary(tree: VATree) -> dict[str, Any] | None:
    """The index's figures for reports and ``reach info``: directions, its mean and quartiles over reachable vertices, its cost."""
    if tree.index is None:
        return None
    share = tree.index.share[tree.vertices.reachable]
    q = np.percentile(share, [25, 50, 75]) if share.size else np.full(3, np.nan)
    meta = tree.meta.get("index", {})
    return {"directions": len(tree.index.directions), "mean": float(share.mean()) if share.size else None, "quartiles": q.round(4).tolist(),
            "goals": meta.get("goals"), "seconds": meta.get("seconds")}


def index_of(tree: VATree, row: int) -> float | None:
    """The index of one vertex row (None when the tree has no index)."""
    index = getattr(tree, "index", None)
    return None if index is None else float(index.reached[row].mean())
