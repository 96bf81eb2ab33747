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
(see :func:`reach.building.index.compute_index`); a direction solved starts from a corner's
posture that reached it, then the vertex's stored posture, then the
reference: the reach stage only (the index needs existence, not the most
natural posture) and no random restart (the oracle's ``index`` variant).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from reach.errors import StoreError
from reach.maps.box import Box
from reach.maps.protocol import Policy, Stored
from reach.maps.tree import VATree

MAX_DIRECTIONS = 1000  # a strategy's `directions` at most (capability maps use 200)
SPIRAL_STEP = 3.6  # Saff & Kuijlaars (1997): the spiral's turn, over sqrt(N), per point


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
        return (self.reached.mean(axis=1) if self.reached.size
                else np.zeros(len(self.reached)))  # type: ignore[no-any-return]

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
        if (d.ndim != 2 or d.shape[1] != 3 or not np.all(np.isfinite(d))
            or np.abs(np.linalg.norm(d, axis=1) - 1.0).max(initial=0.0) > 1e-6):
            raise StoreError(where, f"the reachability index's directions {d.shape} are not unit [x, y, z] rows")
        if bits.dtype != np.uint8 or bits.shape != (vertices, -(-len(d) // 8)):
            raise StoreError(where, f"the reachability index's bits {bits.shape} do not match {vertices} vertices x "
                                    f"{len(d)} directions")
        return ReachIndex(d, np.unpackbits(bits, axis=1, count=len(d)).astype(bool))


@dataclass(frozen=True)
class IndexedTree:
    """A VATree with its reachability index: a :class:`~reach.maps.protocol.ReachMap` whose ``index_at`` answers.

    The index is kept beside the tree, not in it: the tree is what the build
    refines, the index what a later pass solves over its reachable vertices.
    """

    tree: VATree
    index: ReachIndex

    @property
    def box(self) -> Box:
        return self.tree.box

    @property
    def dim(self) -> int:
        return self.tree.dim

    @property
    def posture_names(self) -> tuple[str, ...]:
        return self.tree.posture_names

    @property
    def meta(self) -> dict[str, Any]:
        return self.tree.meta

    def prepare(self) -> IndexedTree:
        self.tree.prepare()
        return self

    def contains(self, points: np.ndarray, policy: Policy = "conservative") -> np.ndarray:
        return self.tree.contains(points, policy)

    def contains_one(self, point: list[float], policy: Policy = "conservative") -> bool:
        return self.tree.contains_one(point, policy)

    def stored(self) -> Stored | None:
        return self.tree.stored()

    def postures(self, ids: np.ndarray | int) -> np.ndarray:
        return self.tree.postures(ids)

    def nearest_stored(self, point: list[float]) -> int:
        return self.tree.nearest_stored(point)

    def unreached(self) -> np.ndarray:
        return self.tree.unreached()

    def index_at(self, points: np.ndarray, held: bool = True) -> np.ndarray:
        """The index at points (n, 3) [m]: its nearest reachable vertex's, at the points the tree holds (``vertex``
        policy; every point with ``held`` false, e.g. the centres of drawn cells); NaN elsewhere."""
        tree = self.tree
        pts = np.asarray(points, float).reshape(-1, tree.dim)
        out = np.full(len(pts), np.nan)
        rows = np.nonzero(tree.vertices.reachable)[0]
        if not rows.size:
            return out
        inside = tree.contains(pts, "vertex") if held else np.ones(len(pts), bool)
        if inside.any():
            _, near = self._kd.query(pts[inside])
            out[inside] = self.index.share[rows[near]]
        return out

    @cached_property
    def _kd(self) -> Any:
        from scipy.spatial import cKDTree  # scipy.spatial costs 0.2 s at start-up; a map without index never needs it

        rows = np.nonzero(self.tree.vertices.reachable)[0]
        return cKDTree(self.tree.lattice.points(self.tree.lattice.coords(self.tree.vertices.keys[rows])))


def summary(tree: VATree, index: ReachIndex | None) -> dict[str, Any] | None:
    """The index's figures for reports and ``reach info``: directions, its mean and quartiles over reachable
    vertices, its cost."""
    if index is None:
        return None
    share = index.share[tree.vertices.reachable]
    q = np.percentile(share, [25, 50, 75]) if share.size else np.full(3, np.nan)
    meta = tree.meta.get("index", {})
    return {"directions": len(index.directions), "mean": float(share.mean()) if share.size else None,
            "quartiles": q.round(4).tolist(), "goals": meta.get("goals"), "seconds": meta.get("seconds")}
