"""Where points fall in a VATree: the leaf holding each, and the finest-lattice vertex nearest each.

A dense table gives the node at a coarse depth in one gather; the rest is a vectorised descent, one numpy pass per
depth, never a loop over points. One point is located in plain Python: a server's per-request path, where numpy's
per-call overhead would dominate (the same descent, kept apart on purpose: it halved the server's latency tail).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from reach.errors import TreeError
from reach.maps.box import Box
from reach.maps.kinds import PARENT

TABLE_BITS = 21  # the coarse table has at most 2**21 entries (8 MB of int32)


class Nodes(Protocol):
    """What a locator reads of its tree (:class:`reach.maps.tree.VATree`)."""

    box: Box
    d_max: int
    kind: np.ndarray
    child: np.ndarray
    vertices: Any

    @property
    def dim(self) -> int: ...

    @property
    def lattice(self) -> Any: ...


class Locator:
    """The point queries of one tree's nodes and vertices (see the module docstring)."""

    def __init__(self, tree: Nodes) -> None:
        self.tree = tree
        self._table: tuple[int, np.ndarray] | None = None

    def locate(self, points: np.ndarray) -> np.ndarray:
        """Index of the leaf containing each point (N, dim) [m], -1 outside B0."""
        t = self.tree
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != t.dim:
            raise TreeError(f"points must have shape (N, {t.dim}), got {pts.shape}", what="points")
        if pts.shape[0] == 1:
            return np.array([self.one(pts[0].tolist())], np.int64)
        cells, inside = t.lattice.cell_of(pts)
        level, table = self.table()
        shift = t.d_max - level
        node = table[(cells >> shift) @ ((1 << level) ** np.arange(t.dim, dtype=np.int64))].astype(np.int64)
        active = np.nonzero(t.kind[node] == PARENT)[0]
        node = self._descend(cells, node, active, level)
        node[~inside] = -1
        return node

    def one(self, point: list[float]) -> int:
        """:meth:`locate` for a single point, in plain Python."""
        t = self.tree
        lo, size, n = t.box.lo.tolist(), t.box.size.tolist(), 1 << t.d_max
        cell = []
        for p, a, w in zip(point, lo, size, strict=True):
            rel = (p - a) / w
            if not 0.0 <= rel <= 1.0:  # also false for NaN
                return -1
            cell.append(min(int(rel * n), n - 1))
        kind, child = t.kind, t.child
        node, depth = 0, 0
        while kind[node] == PARENT:
            shift = t.d_max - depth - 1
            node = int(child[node]) + sum(((c >> shift) & 1) << i for i, c in enumerate(cell))
            depth += 1
        return node

    def _descend(self, cells: np.ndarray, node: np.ndarray, active: np.ndarray, depth: int,
                 stop: int | None = None) -> np.ndarray:
        """Walk the active rows from their nodes (at depth) down to leaves, or to depth stop."""
        t = self.tree
        weights = 1 << np.arange(t.dim, dtype=np.int64)
        while active.size and (stop is None or depth < stop):
            bits = ((cells[active] >> (t.d_max - depth - 1)) & 1) @ weights
            node[active] = t.child[node[active]] + bits
            active = active[t.kind[node[active]] == PARENT]
            depth += 1
        return node

    def table(self) -> tuple[int, np.ndarray]:
        """Dense table of the node covering each cell at a coarse depth (built once): the largest depth whose table
        has at most ``2**TABLE_BITS`` entries."""
        if self._table is None:
            t = self.tree
            level = min(t.d_max, TABLE_BITS // t.dim)
            n = 1 << level
            grid = np.stack(np.meshgrid(*[np.arange(n)] * t.dim, indexing="ij"), axis=-1).reshape(-1, t.dim)
            # Row order must match the key used in locate: axis i has weight n**i.
            grid = grid[:, ::-1] if t.dim > 1 else grid
            cells = grid.astype(np.int64) << (t.d_max - level)
            node = np.zeros(cells.shape[0], np.int64)
            node = self._descend(cells, node, np.nonzero(t.kind[node] == PARENT)[0], 0, stop=level)
            self._table = (level, node.astype(np.int32))
        return self._table

    def vertex_row(self, point: list[float]) -> int:
        """Vertex-table row of the finest-lattice vertex nearest to one point, -1 if never evaluated (plain Python)."""
        t = self.tree
        lat = t.lattice
        key = 0
        for p, lo, res, stride in zip(point, t.box.lo.tolist(), lat.resolution.tolist(), lat.strides.tolist(),
                                      strict=True):
            key += min(max(round((p - lo) / res), 0), lat.cells) * stride
        keys = t.vertices.keys
        row = int(np.searchsorted(keys, key))
        return row if row < keys.shape[0] and keys[row] == key else -1

    def vertex_verdicts(self, points: np.ndarray) -> np.ndarray:
        """Verdict of the finest-lattice vertex nearest to each point (False if never evaluated)."""
        t = self.tree
        lat = t.lattice
        coords = np.rint((points - t.box.lo) / lat.resolution).astype(np.int64)
        np.clip(coords, 0, lat.cells, out=coords)
        row = t.vertices.index(lat.keys(coords))
        return np.where(row >= 0, t.vertices.reachable[np.maximum(row, 0)], False)
