"""Booleans of two VATrees over the same B0 and lattice (the paper's Figure 9: the volume two strategies share, or
one reaches and the other does not): ``intersection``, ``union`` and ``difference``."""

from __future__ import annotations

import numpy as np

from reach.errors import TreeError
from reach.maps.tree import FINAL, INNER, OUTER, PARENT, VATree, VertexTable, bfs_children, corner_offsets


def intersection(a: VATree, b: VATree) -> VATree:
    """Cells inside both trees (the paper's Figure 9)."""
    return combine(a, b, "intersection")


def union(a: VATree, b: VATree) -> VATree:
    """Cells inside either tree."""
    return combine(a, b, "union")


def difference(a: VATree, b: VATree) -> VATree:
    """Cells inside the first tree and not the second."""
    return combine(a, b, "difference")


# Leaf-kind truth tables for booleans; FINAL is "unknown", i.e. boundary.
_NOT = np.array([INNER, OUTER, PARENT, FINAL], np.uint8)


def _combine_kinds(a: np.ndarray, b: np.ndarray, mode: str) -> np.ndarray:
    if mode == "difference":
        b = _NOT[b]
        mode = "intersection"
    if mode == "intersection":
        out = np.where((a == OUTER) | (b == OUTER), OUTER, np.where((a == INNER) & (b == INNER), INNER, FINAL))
    else:
        out = np.where((a == INNER) | (b == INNER), INNER, np.where((a == OUTER) & (b == OUTER), OUTER, FINAL))
    return out.astype(np.uint8)


def combine(a: VATree, b: VATree, mode: str) -> VATree:
    """Boolean of two trees over the same B0 and lattice, as a new tree.

    Both trees are walked together level by level; where one is a leaf and the
    other a parent, the leaf stands for all its would-be children. Vertex
    verdicts of the result combine the verdicts of both trees (a vertex one
    tree never evaluated takes that tree's answer under the vertex policy).
    """
    if mode not in ("intersection", "union", "difference"):
        raise TreeError(f"unknown boolean {mode!r}", what="mode")
    if a.box != b.box or a.d_max != b.d_max:
        raise TreeError(
            f"booleans need the same B0 and D_max; got {a.box.to_dict()} D_max {a.d_max} "
            f"and {b.box.to_dict()} D_max {b.d_max}"
        )
    dim, nchild = a.dim, 1 << a.dim
    offsets = corner_offsets(dim)
    depth_l, corner_l, kind_l = [], [], []
    ia, ib = np.zeros(1, np.int64), np.zeros(1, np.int64)
    corners = np.zeros((1, dim), np.int64)
    d = 0
    while ia.size:
        ka, kb = a.kind[ia], b.kind[ib]
        # A parent side is "unknown" (FINAL) here: where the leaf side alone
        # decides the result no descent is needed, otherwise the pair splits.
        kinds = _combine_kinds(np.where(ka == PARENT, FINAL, ka), np.where(kb == PARENT, FINAL, kb), mode)
        split = (ka == PARENT) | (kb == PARENT)
        kinds = np.where(split & (kinds == FINAL), PARENT, kinds).astype(np.uint8)
        depth_l.append(np.full(ia.size, d, np.uint8))
        corner_l.append(corners)
        kind_l.append(kinds)
        par = np.nonzero(kinds == PARENT)[0]
        step = 1 << (a.d_max - d - 1) if d < a.d_max else 0
        ca = np.where(ka[par] == PARENT, a.child[ia[par]], -1)
        cb = np.where(kb[par] == PARENT, b.child[ib[par]], -1)
        j = np.arange(nchild)
        ia = np.where(ca[:, None] >= 0, ca[:, None] + j, ia[par][:, None]).reshape(-1)
        ib = np.where(cb[:, None] >= 0, cb[:, None] + j, ib[par][:, None]).reshape(-1)
        corners = (corners[par][:, None, :] + offsets[None] * step).reshape(-1, dim)
        d += 1
    kind = np.concatenate(kind_l)
    vertices = _combine_vertices(a, b, mode)
    meta = {"boolean": {"mode": mode, "a": a.meta.get("name"), "b": b.meta.get("name")}}
    return VATree(
        a.box, min(a.d_min, b.d_min), a.d_max, np.concatenate(depth_l), np.concatenate(corner_l), kind,
        bfs_children(kind, dim), vertices, meta,
    )


def _combine_vertices(a: VATree, b: VATree, mode: str) -> VertexTable:
    keys = np.union1d(a.vertices.keys, b.vertices.keys)
    pts = a.lattice.points(a.lattice.coords(keys))

    def verdict(t: VATree) -> np.ndarray:
        row = t.vertices.index(keys)
        known = t.vertices.reachable[np.maximum(row, 0)]
        return np.where(row >= 0, known, t.contains(pts, "vertex"))

    va, vb = verdict(a), verdict(b)
    ok = va & vb if mode == "intersection" else (va | vb if mode == "union" else va & ~vb)
    return VertexTable(keys, ok, np.zeros(keys.shape[0]), None, ())
