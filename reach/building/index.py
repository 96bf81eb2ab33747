"""Computing the reachability index of a tree (see :mod:`reach.maps.index` for what it is and its sources)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from oracles.protocol import Goals
from reach.building.executor import Executor
from reach.maps.index import ReachIndex
from reach.maps.tree import VATree, corner_offsets

# the least share of a cell's corners, reachable and known, whose agreement on a direction a new vertex inherits
AGREE = 0.5


def vertex_levels(coords: np.ndarray, d_max: int) -> np.ndarray:
    """The coarsest depth (0 .. d_max) at which each lattice vertex (n, dim) is a cell corner."""
    out = np.full(len(coords), d_max, int)
    for k in range(d_max - 1, -1, -1):
        step = 1 << (d_max - k)
        out[np.all(coords % step == 0, axis=1)] = k
    return out


def _from_corners(tree: VATree, k: int, sel: np.ndarray, at: np.ndarray, known: np.ndarray, reached: np.ndarray,
                  posed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For vertices ``sel`` (lattice coordinates ``at``) first at depth k: the directions their cell's corners agree
    on, set in ``reached``; which directions are left to solve (m, n); and each one's hint, a corner's posture that
    reached it (NaN: none)."""
    v, lattice, n = tree.vertices, tree.lattice, reached.shape[1]
    step = 1 << (tree.d_max - k + 1)
    corner_rows = v.index(lattice.keys((at // step * step)[:, None, :] + corner_offsets(tree.dim)[None] * step))
    safe = np.maximum(corner_rows, 0)  # (m, 2**dim)
    # (m, 2**dim): the corners whose directions are known
    usable = (corner_rows >= 0) & v.reachable[safe] & known[safe]
    corner = reached[safe] & usable[:, :, None]  # (m, 2**dim, n)
    some = corner.any(axis=1)
    every = corner.sum(axis=1) == usable.sum(axis=1)[:, None]
    agree = (usable.sum(axis=1) >= AGREE * usable.shape[1])[:, None] & (every | ~some)
    reached[sel] = agree & every
    # A corner's posture for the same direction, when one reached it.
    first = np.argmax(corner, axis=1)  # (m, n) the first corner that reached each direction
    hint = posed[np.take_along_axis(safe, first, axis=1), np.arange(n)[None, :]].astype(float)
    hint[~some] = np.nan
    return ~agree, hint


def compute_index(tree: VATree, executor: Executor, directions: np.ndarray,
                  progress: Callable[[int], None] | None = None) -> tuple[ReachIndex, int]:
    """The index of a tree's reachable vertices, by an executor of the strategy's ``index`` variant; and the number
    of goals it solved.

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
    # the posture that reached each direction (a hint for the finer vertices)
    posed = np.full((len(v), n, v.posture.shape[1]), np.nan, np.float32)
    solved = 0
    for k in np.unique(levels):
        sel = rows[levels == k]
        at = coords[levels == k]
        todo = np.ones((len(sel), n), bool)
        hint = np.full((len(sel), n, v.posture.shape[1]), np.nan)
        if k > 0:
            todo, hint = _from_corners(tree, int(k), sel, at, known, reached, posed)
        base = v.posture[sel]
        for j in range(n):
            pick = np.nonzero(todo[:, j])[0]
            if not pick.size:
                continue
            seeds = np.stack([hint[pick, j], base[pick]], axis=1)
            goals = Goals(lattice.points(at[pick]), {"orientation": np.tile(directions[j], (len(pick), 1))},
                          seeds=seeds)
            verdicts = executor.evaluate(goals, progress)
            solved += len(pick)
            reached[sel[pick], j] = verdicts.reachable
            if verdicts.posture is not None:
                ok = pick[verdicts.reachable]
                posed[sel[ok], j] = verdicts.posture[verdicts.reachable]
        known[sel] = True
    return ReachIndex(directions, reached), solved
