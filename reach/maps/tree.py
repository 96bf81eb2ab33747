"""The Volume Approximation Tree (VATree) of Rodriguez et al., section 3.

A quadtree (2-D) or octree (3-D) over an axis-aligned box B0. The same code
serves both dimensions.

Keys, nodes and the tree are kept apart, as in OctoMap:

* A *vertex* lives on the integer lattice of the finest depth ``d_max``:
  coordinates ``c`` in ``[0, 2**d_max]`` per axis, world position
  ``lo + c * (hi - lo) / 2**d_max``. Its key is the integer
  ``sum(c[i] * (2**d_max + 1)**i)``, shared by every node that touches it,
  so each vertex is evaluated once.
* A *node* is a row of flat arrays: depth, lattice corner (its minimum
  vertex), kind and index of its first child. The ``2**d`` children of a
  parent are contiguous, ordered by the bit pattern of their offset
  (bit i set = upper half along axis i).
* The tree owns the queries (classify, contains; the point location in
  :mod:`reach.maps.locate`) and the volumes; the booleans are
  :mod:`reach.maps.boolean`.

Limits: ``d_max <= 20`` (keys fit in int64 for d = 3). Resolution at the
surface is ``(hi - lo) / 2**d_max`` metres per axis. Points outside B0 are
outer; points on its upper faces belong to the last cell.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from reach.errors import TreeError, UnknownPolicy
from reach.maps.box import Box
from reach.maps.kinds import FINAL, INNER, KIND_NAMES, OUTER, PARENT
from reach.maps.locate import Locator
from reach.maps.protocol import POLICIES, Policy, Stored

__all__ = [
    "FINAL", "INNER", "KIND_NAMES", "MAX_DEPTH", "OUTER", "PARENT", "Lattice", "VATree", "VertexTable", "bfs_children",
    "corner_offsets",
]

MAX_DEPTH = 20


def corner_offsets(dim: int) -> np.ndarray:
    """(2**dim, dim) offsets in {0, 1}; row j has bit i of j on axis i."""
    j = np.arange(1 << dim)
    return ((j[:, None] >> np.arange(dim)[None, :]) & 1).astype(np.int64)


@dataclass(frozen=True)
class Lattice:
    """The integer vertex lattice of depth d_max over a box."""

    box: Box
    d_max: int

    def __post_init__(self) -> None:
        if not 0 <= self.d_max <= MAX_DEPTH:
            raise TreeError(f"d_max must be in [0, {MAX_DEPTH}], got {self.d_max}", what="d_max")

    @property
    def dim(self) -> int:
        return self.box.dim

    @property
    def cells(self) -> int:
        """Cells per axis at the finest depth."""
        return 1 << self.d_max

    @property
    def strides(self) -> np.ndarray:
        return (self.cells + 1) ** np.arange(self.dim, dtype=np.int64)  # type: ignore[no-any-return]

    @property
    def resolution(self) -> np.ndarray:
        """Edge of a finest cell per axis [m]."""
        return self.box.size / self.cells  # type: ignore[no-any-return]

    @property
    def vertex_count(self) -> int:
        """(2**d_max + 1)**dim: every vertex of the full lattice."""
        return int((self.cells + 1) ** self.dim)

    def cell_size(self, depth: np.ndarray) -> np.ndarray:
        """(n, dim) edges [m] of nodes at the given depths."""
        return self.box.size[None, :] / (1 << depth.astype(np.int64))[:, None]  # type: ignore[no-any-return]

    def keys(self, coords: np.ndarray) -> np.ndarray:
        return coords @ self.strides  # type: ignore[no-any-return]

    def coords(self, keys: np.ndarray) -> np.ndarray:
        return (np.asarray(keys)[:, None] // self.strides[None, :]) % (self.cells + 1)  # type: ignore[no-any-return]

    def points(self, coords: np.ndarray) -> np.ndarray:
        """World positions [m] of lattice coordinates."""
        return self.box.lo + coords * self.resolution  # type: ignore[no-any-return]

    def cell_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Finest cell coordinates of points, and a mask of points inside B0."""
        rel = (points - self.box.lo) / self.box.size
        inside = np.all((rel >= 0.0) & (rel <= 1.0), axis=1)
        cells = np.floor(np.where(inside[:, None], rel, 0.0) * self.cells).astype(np.int64)
        np.minimum(cells, self.cells - 1, out=cells)
        return cells, inside

    def node_vertex_keys(self, corners: np.ndarray, depth: int) -> np.ndarray:
        """(n, 2**dim) keys of the vertices of nodes at one depth."""
        step = 1 << (self.d_max - depth)
        verts = corners[:, None, :] + corner_offsets(self.dim)[None, :, :] * step
        return self.keys(verts)


def faces_of(lattice: Lattice, keys: np.ndarray) -> dict[str, int]:
    """The faces of the lattice's box (``x-``, ``x+``, ``y-`` ...) that the vertices ``keys`` lie on, and how many
    lie on each."""
    coords = lattice.coords(keys)
    out = {}
    for axis, name in enumerate("xyz"[: lattice.dim]):
        for side, at in (("-", 0), ("+", lattice.cells)):
            n = int(np.count_nonzero(coords[:, axis] == at))
            if n:
                out[f"{name}{side}"] = n
    return out


@dataclass
class VertexTable:
    """Verdicts of every evaluated vertex, sorted by key.

    Attributes:
        keys: (n,) int64 lattice keys, strictly increasing.
        reachable: (n,) bool verdicts.
        residual: (n,) float residuals [m].
        posture: (n, nq) postures, or None for oracles without postures.
        posture_names: Names of the posture coordinates.
    """

    keys: np.ndarray
    reachable: np.ndarray
    residual: np.ndarray
    posture: np.ndarray | None = None
    posture_names: tuple[str, ...] = ()

    @staticmethod
    def empty(posture_names: tuple[str, ...] = ()) -> VertexTable:
        nq = len(posture_names)
        return VertexTable(
            np.zeros(0, np.int64), np.zeros(0, bool), np.zeros(0), np.zeros((0, nq)) if nq else None, posture_names
        )

    def __len__(self) -> int:
        return int(self.keys.shape[0])

    def index(self, keys: np.ndarray) -> np.ndarray:
        """Row of each key, -1 where the key was never evaluated."""
        keys = np.asarray(keys, dtype=np.int64)
        if len(self) == 0:
            return np.full(keys.shape, -1, np.int64)
        pos = np.searchsorted(self.keys, keys)
        pos = np.minimum(pos, len(self) - 1)
        return np.where(self.keys[pos] == keys, pos, -1)

    def merged(self, keys: np.ndarray, reachable: np.ndarray, residual: np.ndarray,
               posture: np.ndarray | None) -> VertexTable:
        """A new table with new (not yet present) keys added."""
        all_keys = np.concatenate([self.keys, keys])
        order = np.argsort(all_keys, kind="stable")
        post = None
        if self.posture is not None and posture is not None:
            post = np.concatenate([self.posture, posture])[order]
        return VertexTable(
            all_keys[order], np.concatenate([self.reachable, reachable])[order],
            np.concatenate([self.residual, residual])[order],
            post,
            self.posture_names,
        )


@dataclass
class VATree:
    """An adaptive tree whose leaves approximate a volume.

    Attributes:
        box: B0, the initial box.
        d_min: Depth down to which every node is subdivided (paper's D_min).
        d_max: Maximum depth (paper's D_max); boundary leaves there are final.
        depth: (n,) uint8 depth of each node; node 0 is the root.
        corner: (n, dim) int64 lattice coordinates of each node's minimum vertex.
        kind: (n,) uint8 in {OUTER, INNER, PARENT, FINAL}.
        child: (n,) int64 index of the first of the 2**dim children, -1 for leaves.
        vertices: The vertex table.
        meta: JSON-compatible metadata (config, oracle spec, build statistics).
    """

    box: Box
    d_min: int
    d_max: int
    depth: np.ndarray
    corner: np.ndarray
    kind: np.ndarray
    child: np.ndarray
    vertices: VertexTable
    meta: dict[str, Any] = field(default_factory=dict)

    # -- structure ---------------------------------------------------------
    @property
    def lattice(self) -> Lattice:
        return Lattice(self.box, self.d_max)

    @property
    def dim(self) -> int:
        return self.box.dim

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @property
    def oracle_calls(self) -> int:
        """Points the oracle was asked about: one per distinct evaluated vertex."""
        return int(self.meta.get("build", {}).get("oracle_calls", len(self.vertices)))

    def node_counts(self) -> dict[int, dict[str, int]]:
        """Number of nodes of each kind at each depth."""
        out: dict[int, dict[str, int]] = {}
        for d in range(int(self.depth.max()) + 1 if len(self) else 0):
            at = self.kind[self.depth == d]
            out[d] = {name: int(np.count_nonzero(at == k)) for k, name in enumerate(KIND_NAMES)}
        return out

    def volume(self, kind: int = INNER) -> float:
        """Total volume [m^3] (area [m^2] in 2-D) of nodes of one kind."""
        sel = self.kind == kind
        return float(np.sum(self.box.volume / (1 << (self.dim * self.depth[sel].astype(np.int64)))))

    def extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Bounds [m] of the inner and final cells, or None when there are none."""
        sel = (self.kind == INNER) | (self.kind == FINAL)
        if not np.any(sel):
            return None
        lo = self.lattice.points(self.corner[sel])
        hi = lo + self.lattice.cell_size(self.depth[sel])
        return lo.min(axis=0), hi.max(axis=0)

    def reachable_extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Bounds [m] of the reachable vertices (the oracle's own verdicts), or None when none is reachable."""
        v = self.vertices
        if not v.reachable.any():
            return None
        pts = self.lattice.points(self.lattice.coords(v.keys[v.reachable]))
        return pts.min(axis=0), pts.max(axis=0)

    def faces(self) -> dict[str, int]:
        """The faces of B0 that reachable vertices lie on (``x-``, ``x+``, ``y-`` ...) and how many lie on each:
        the box cuts the volume there, where the paper asks that it contain it."""
        v = self.vertices
        return faces_of(self.lattice, v.keys[v.reachable])

    # -- queries -----------------------------------------------------------
    @property
    def locator(self) -> Locator:
        """The tree's point queries, made once for its nodes as they are (a tree whose arrays are replaced gets a
        new one)."""
        cached = self.__dict__.get("_locator")
        if cached is None or cached[1] is not self.kind:
            cached = (Locator(self), self.kind)
            self.__dict__["_locator"] = cached
        return cached[0]  # type: ignore[no-any-return]

    def prepare(self) -> VATree:
        """Build the lookup table of batch queries now (a server does at load), not on the first batch."""
        self.locator.table()
        return self

    def classify(self, points: np.ndarray) -> np.ndarray:
        """Kind (OUTER, INNER or FINAL) of the leaf holding each point; outer outside B0."""
        node = self.locator.locate(points)
        return np.where(node >= 0, self.kind[np.maximum(node, 0)], OUTER).astype(np.uint8)

    def contains(self, points: np.ndarray, policy: Policy = "conservative") -> np.ndarray:
        """Whether each point is in the approximated volume.

        Args:
            points: (N, dim) positions [m].
            policy: How boundary (final) cells answer: ``conservative`` says no,
                ``optimistic`` says yes, ``vertex`` takes the verdict of the
                cell's vertex nearest to the point.
        """
        if policy not in POLICIES:
            raise UnknownPolicy(policy, POLICIES)
        pts = np.asarray(points, dtype=float)
        if pts.ndim == 2 and pts.shape == (1, self.dim):
            return np.array([self.contains_one(pts[0].tolist(), policy)])
        kinds = self.classify(pts)
        result = kinds == INNER
        if policy == "optimistic":
            result |= kinds == FINAL
        elif policy == "vertex":
            fin = np.nonzero(kinds == FINAL)[0]
            if fin.size:
                result[fin] = self.locator.vertex_verdicts(pts[fin])
        return result

    def contains_one(self, point: list[float], policy: Policy = "conservative") -> bool:
        """contains() for one point in plain Python (the server's per-request path)."""
        node = self.locator.one(point)
        kind = OUTER if node < 0 else int(self.kind[node])
        if kind != FINAL or policy == "conservative":
            return kind == INNER
        if policy == "optimistic":
            return True
        row = self.locator.vertex_row(point)
        return bool(row >= 0 and self.vertices.reachable[row])

    # -- the ReachMap protocol (reach.maps.protocol): ids are vertex rows --------
    @property
    def posture_names(self) -> tuple[str, ...]:
        return self.vertices.posture_names if self.vertices.posture is not None else ()

    def stored(self) -> Stored | None:
        """The reachable vertices with postures (:class:`reach.maps.protocol.Stored`), or None."""
        v = self.vertices
        if v.posture is None:
            return None
        rows = np.nonzero(v.reachable)[0]
        return Stored(rows, self.lattice.points(self.lattice.coords(v.keys[rows])), v.posture[rows])

    def postures(self, ids: np.ndarray | int) -> np.ndarray:
        if self.vertices.posture is None:
            raise TreeError("this tree keeps no posture (its oracle returns none)")
        return self.vertices.posture[ids]  # type: ignore[no-any-return]

    def nearest_stored(self, point: list[float]) -> int:
        row = self.locator.vertex_row(point)
        return row if row >= 0 and self.vertices.posture is not None and bool(self.vertices.reachable[row]) else -1

    def unreached(self) -> np.ndarray:
        v = self.vertices
        return self.lattice.points(self.lattice.coords(v.keys[~v.reachable]))

    def index_at(self, points: np.ndarray, held: bool = True) -> np.ndarray:
        """NaN: a bare tree has no index (:class:`reach.maps.index.IndexedTree` adds it)."""
        return np.full(len(np.asarray(points, float).reshape(-1, self.dim)), np.nan)


def bfs_children(kind: np.ndarray, dim: int) -> np.ndarray:
    """First-child index of each node of a tree stored in breadth-first order.

    Each level holds exactly the children of the previous level's parents, in
    order, so the k-th parent's children start at 1 + k * 2**dim.
    """
    child = np.full(kind.shape[0], -1, np.int64)
    parents = np.nonzero(kind == PARENT)[0]
    child[parents] = 1 + np.arange(parents.size, dtype=np.int64) * (1 << dim)
    return child
