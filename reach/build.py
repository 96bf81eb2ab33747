"""Algorithm 1 of the paper: build a VATree by asking an oracle about vertices.

The build is level-synchronous. At each depth D the nodes of that depth are
known; if D < D_min they are all parents (paper, step 1). Otherwise every
vertex of theirs not yet evaluated goes to the oracle in one batch, so each
distinct vertex is asked exactly once (the paper's sharing mechanism), then
each node is labelled inner (all vertices inside), outer (none), final
(mixed, at D_max) or parent (mixed, subdivided).

Each new vertex receives a warm-start hint: the posture of the nearest
reachable vertex evaluated at an earlier depth.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from oracles.protocol import Oracle, OracleSpec
from reach.errors import TreeError
from reach.executor import Executor, InlineExecutor
from reach.tree import FINAL, INNER, OUTER, PARENT, Box, Lattice, VATree, VertexTable, bfs_children, corner_offsets

LevelCallback = Callable[["BuildState"], None]


@dataclass
class BuildState:
    """Everything a build knows after finishing a depth; enough to resume.

    Attributes:
        depth: The next depth to process.
        frontier: (n, dim) lattice corners of the nodes at that depth.
        kinds: Kinds of the nodes of every finished depth, one array each.
        corners: Corners of the nodes of every finished depth.
        vertices: Every vertex evaluated so far.
        levels: Per-depth statistics.
    """

    depth: int
    frontier: np.ndarray
    kinds: list[np.ndarray] = field(default_factory=list)
    corners: list[np.ndarray] = field(default_factory=list)
    vertices: VertexTable = field(default_factory=VertexTable.empty)
    levels: list[dict[str, Any]] = field(default_factory=list)


def check_depths(d_min: int, d_max: int) -> None:
    if d_max < 0 or d_min < 0:
        raise TreeError(f"depths must be non-negative, got D_min {d_min} and D_max {d_max}")
    if d_min > d_max:
        raise TreeError(f"D_min ({d_min}) must not exceed D_max ({d_max})")


def warm_hints(table: VertexTable, lattice: Lattice, points: np.ndarray) -> np.ndarray | None:
    """Posture of the nearest reachable evaluated vertex for each point (None if no postures)."""
    if table.posture is None:
        return None
    hints = np.full((points.shape[0], table.posture.shape[1]), np.nan)
    ok = np.nonzero(table.reachable)[0]
    if ok.size and points.shape[0]:
        known = lattice.points(lattice.coords(table.keys[ok]))
        _, nearest = cKDTree(known).query(points)
        hints[:] = table.posture[ok[nearest]]
    return hints


def build_level(state: BuildState, lattice: Lattice, d_min: int, executor: Executor, progress: Any = None) -> BuildState:
    """Process the frontier at state.depth; return the state for the next depth."""
    d, frontier = state.depth, state.frontier
    t0 = time.perf_counter()
    n_new = 0
    table = state.vertices
    if d < d_min:
        kinds = np.full(frontier.shape[0], PARENT, np.uint8)
    else:
        vkeys = lattice.node_vertex_keys(frontier, d)
        uniq = np.unique(vkeys)
        new = uniq[table.index(uniq) < 0]
        n_new = int(new.size)
        if n_new:
            pts = lattice.points(lattice.coords(new))
            hints = warm_hints(table, lattice, pts)
            if progress is not None:
                progress.reset(total=n_new)
                progress.set_description(f"{getattr(progress, 'label', '')} depth {d}".strip())
            verdicts = executor.evaluate(pts, hints, progress.update if progress is not None else None)
            table = table.merged(new, verdicts.reachable, verdicts.residual, verdicts.posture)
        inside = table.reachable[table.index(vkeys)]
        n_in = inside.sum(axis=1)
        kinds = np.where(n_in == inside.shape[1], INNER, np.where(n_in == 0, OUTER, np.where(d == lattice.d_max, FINAL, PARENT)))
        kinds = kinds.astype(np.uint8)
    par = frontier[kinds == PARENT]
    step = 1 << (lattice.d_max - d - 1) if d < lattice.d_max else 0
    nxt = (par[:, None, :] + corner_offsets(lattice.dim)[None] * step).reshape(-1, lattice.dim)
    level = {"depth": d, "nodes": int(frontier.shape[0]), "new_vertices": n_new, "seconds": time.perf_counter() - t0}
    return BuildState(d + 1, nxt, [*state.kinds, kinds], [*state.corners, frontier], table, [*state.levels, level])


def assemble(state: BuildState, box: Box, d_min: int, d_max: int, meta: dict[str, Any]) -> VATree:
    """The tree of a finished build."""
    kind = np.concatenate(state.kinds)
    depth = np.concatenate([np.full(k.shape[0], d, np.uint8) for d, k in enumerate(state.kinds)])
    meta = dict(meta)
    meta["build"] = {
        **meta.get("build", {}),
        "oracle_calls": len(state.vertices),
        "lattice_vertices": Lattice(box, d_max).vertex_count,
        "levels": state.levels,
        "seconds": float(sum(lv["seconds"] for lv in state.levels)),
    }
    return VATree(box, d_min, d_max, depth, np.concatenate(state.corners), kind, bfs_children(kind, box.dim), state.vertices, meta)


def build_tree(
    oracle: Oracle | OracleSpec,
    box: Box,
    d_min: int,
    d_max: int,
    *,
    executor: Executor | None = None,
    chunk_size: int = 2048,
    progress: bool | str = False,
    meta: dict[str, Any] | None = None,
    state: BuildState | None = None,
    on_level: LevelCallback | None = None,
) -> VATree:
    """Build a VATree (Algorithm 1).

    Args:
        oracle: The oracle, or its spec.
        box: B0; it must contain the volume.
        d_min: Depth to which every node is subdivided regardless of verdicts.
        d_max: Maximum depth; its cells are the surface resolution.
        executor: Who runs the oracle; inline in this process by default.
        chunk_size: Points per oracle call for the default executor.
        progress: Show a progress bar per depth (a string labels it).
        meta: Metadata stored with the tree.
        state: A checkpointed state to resume from.
        on_level: Called with the state after each depth (for checkpoints).

    Returns:
        The tree, with the oracle-call count and per-depth statistics in
        ``meta["build"]``.
    """
    check_depths(d_min, d_max)
    lattice = Lattice(box, d_max)
    own = executor is None
    ex = executor if executor is not None else InlineExecutor(oracle, chunk_size)
    if ex.dim != box.dim:
        raise TreeError(f"oracle is {ex.dim}-D but B0 is {box.dim}-D")
    if state is None:
        state = BuildState(0, np.zeros((1, box.dim), np.int64), vertices=VertexTable.empty(ex.posture_names))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=0, unit="vertex", leave=False, dynamic_ncols=True)
        bar.label = progress if isinstance(progress, str) else ""
    try:
        while state.frontier.shape[0]:
            state = build_level(state, lattice, d_min, ex, bar)
            if on_level is not None:
                on_level(state)
    finally:
        if bar is not None:
            bar.close()
        if own:
            ex.close()
    meta = dict(meta or {})
    if isinstance(oracle, OracleSpec):
        meta.setdefault("oracle", oracle.to_dict())
    return assemble(state, box, d_min, d_max, meta)
