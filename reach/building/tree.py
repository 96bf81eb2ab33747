"""Algorithm 1 of the paper: build a VATree by asking an oracle about vertices.

The build is level-synchronous. At each depth D the nodes of that depth are
known; if D < D_min they are all parents (paper, step 1). Otherwise every
vertex of theirs not yet evaluated goes to the oracle in one batch, so each
distinct vertex is asked exactly once (the paper's sharing mechanism), then
each node is labelled inner (all vertices inside), outer (none), final
(mixed, at D_max) or parent (mixed, subdivided).

Each new vertex receives a warm-start hint: the posture of the nearest
reachable vertex evaluated at an earlier depth.

A build may inherit from a finished tree of a *sub-strategy* on the same
lattice (:class:`Inherited`: the same body and effector, fewer joints): a
vertex it found reachable is reachable here too, by the same posture, once
this strategy's oracle has checked that posture against its own hard tasks
(:class:`oracles.protocol.Verifying`); only the other vertices are solved.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from oracles.protocol import Goals, Oracle, OracleSpec, Verdicts
from reach.building.executor import CHUNK_SIZE, Executor, InlineExecutor
from reach.building.twins import Twins, shared
from reach.errors import TreeError
from reach.maps.box import Box
from reach.maps.tree import FINAL, INNER, OUTER, PARENT, Lattice, VATree, VertexTable, bfs_children, corner_offsets

LevelCallback = Callable[["BuildState"], object]


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
        raise TreeError(f"depths must be non-negative, got D_min {d_min} and D_max {d_max}", what="depth")
    if d_min > d_max:
        raise TreeError(f"D_min ({d_min}) must not exceed D_max ({d_max})", what="depth")


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


class Taken(NamedTuple):
    """What a strategy inherits of new vertices: ``mask`` (N,) over the keys asked, and the
    ``residual`` [m] and ``posture`` (M, nq) of the M inherited ones."""

    mask: np.ndarray
    residual: np.ndarray
    posture: np.ndarray


@dataclass(frozen=True)
class Inherited:
    """Reachable vertices of a sub-strategy's tree, and this strategy's check of a posture.

    Attributes:
        source: The sub-strategy's name (for the build's statistics).
        table: Its tree's vertex table (same lattice and posture names).
        verify: ``verify(points, postures) -> bool array``: this strategy's
            own check that a posture reaches its point with every hard task held.
    """

    source: str
    table: VertexTable
    verify: Callable[[np.ndarray, np.ndarray], np.ndarray]

    def take(self, keys: np.ndarray, points: np.ndarray) -> Taken:
        """Which keys are inherited (mask), and their residuals and postures."""
        rows = self.table.index(keys)
        cand = np.nonzero(rows >= 0)[0]
        cand = cand[self.table.reachable[rows[cand]]]
        mask = np.zeros(len(keys), bool)
        if cand.size and self.table.posture is not None:
            ok = np.asarray(self.verify(points[cand], self.table.posture[rows[cand]]), bool)
            mask[cand[ok]] = True
        rows = rows[mask]
        posture = self.table.posture[rows] if self.table.posture is not None else np.zeros((0, 0))
        return Taken(mask, self.table.residual[rows], posture)


@dataclass(frozen=True)
class Refine:
    """Build-time refinements of the vertex rule (all off by default: the paper's Algorithm 1).

    Attributes:
        centres: Before labelling a cell inner (above D_max), probe its centre;
            a failing probe makes it a parent, subdivided like a boundary cell.
            The centre is a vertex of the next depth, so a split cell's
            children reuse the verdict.
        faces: Also probe the centres of the cell's faces.
        isolated: Retry an unreachable vertex whose lattice neighbours at the
            same spacing were all found reachable, warm-started from each
            neighbour's posture (oracles with postures only).
    """

    centres: bool = False
    faces: bool = False
    isolated: bool = False

    def to_dict(self) -> dict[str, bool]:
        return {"centres": self.centres, "faces": self.faces, "isolated": self.isolated}


def _evaluate(
    keys: np.ndarray, table: VertexTable, lattice: Lattice, executor: Executor, progress: Any, label: str,
    inherit: Inherited | None = None, twins: Twins | None = None,
) -> tuple[VertexTable, int, int]:
    """Ask the oracle about keys not yet in the table (one batch), after those inherited, and with ``twins`` one of
    each set of twins; the grown table, how many were inherited and how many took a twin's verdict."""
    new = np.unique(keys)
    new = new[table.index(new) < 0]
    if new.size == 0:
        return table, 0, 0
    pts = lattice.points(lattice.coords(new))
    taken = 0
    if inherit is not None:
        mask, residual, posture = inherit.take(new, pts)
        taken = int(mask.sum())
        if taken:
            table = table.merged(new[mask], np.ones(taken, bool), residual, posture)
            new, pts = new[~mask], pts[~mask]
            if new.size == 0:
                return table, taken, 0

    def solve(asked: np.ndarray) -> Verdicts:
        at = lattice.points(lattice.coords(asked))
        if progress is not None:
            progress.reset(total=int(asked.size))
            progress.set_description(f"{getattr(progress, 'label', '')} {label}".strip())
        return executor.evaluate(Goals(at, seeds=warm_hints(table, lattice, at)),
                                 progress.update if progress is not None else None)

    if twins is None:
        verdicts, turned = solve(new), 0
    else:
        def stored(rows: np.ndarray) -> Verdicts:
            return Verdicts(table.reachable[rows], table.residual[rows],
                            None if table.posture is None else table.posture[rows])

        verdicts, turned = shared(twins, lattice, new, table.index, stored, solve)
    return table.merged(new, verdicts.reachable, verdicts.residual, verdicts.posture), taken, turned


def _retry_isolated(keys: np.ndarray, table: VertexTable, lattice: Lattice, step: int,
                    executor: Executor) -> tuple[VertexTable, int]:
    """Retry unreachable keys whose evaluated neighbours at distance step are all reachable."""
    if table.posture is None or keys.size == 0:
        return table, 0
    rows = table.index(keys)
    lonely = keys[~table.reachable[rows]]
    if lonely.size == 0:
        return table, 0
    coords = lattice.coords(lonely)
    offsets = np.concatenate([np.eye(lattice.dim, dtype=np.int64), -np.eye(lattice.dim, dtype=np.int64)]) * step
    nb = coords[:, None, :] + offsets[None]
    valid = np.all((nb >= 0) & (nb <= lattice.cells), axis=2)
    nrow = np.where(valid, table.index(lattice.keys(np.clip(nb, 0, lattice.cells))), -1)
    known = nrow >= 0
    ok = np.where(known, table.reachable[np.maximum(nrow, 0)], False)
    isolated = (known.sum(axis=1) >= lattice.dim + 1) & (ok == known).all(axis=1)
    calls = 0
    todo = np.nonzero(isolated)[0]
    for k in range(offsets.shape[0]):  # one round per neighbour posture, while points stay unreachable
        todo = todo[known[todo, k]]
        if todo.size == 0:
            break
        pts = lattice.points(coords[todo])
        v = executor.evaluate(Goals(pts, seeds=table.posture[nrow[todo, k]]))
        calls += int(todo.size)
        fixed = v.reachable
        if fixed.any():
            r = table.index(lonely[todo[fixed]])
            table.reachable[r] = True
            table.residual[r] = v.residual[fixed]
            table.posture[r] = v.posture[fixed]  # type: ignore[index]
        todo = todo[~fixed]
    return table, calls


def meets(lo: np.ndarray, hi: np.ndarray, capsules: np.ndarray) -> np.ndarray:
    """Which boxes (n, 3) [m] may meet any capsule (K, 7: a, b, radius [m]); errs towards meeting.

    The capsule's axis is sampled at spacing h, so a box within radius + h/2
    of the nearest sample may meet it, and one farther does not.
    """
    out = np.zeros(len(lo), bool)
    for cap in capsules:
        a, b, r = cap[:3], cap[3:6], float(cap[6])
        h = max(0.5 * min(r, float(np.min(hi[0] - lo[0])) if len(lo) else r), 1e-3)
        n = int(np.ceil(np.linalg.norm(b - a) / h)) + 1
        pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        gap = np.maximum(np.maximum(lo[:, None, :] - pts[None], pts[None] - hi[:, None, :]), 0.0)
        out |= np.linalg.norm(gap, axis=2).min(axis=1) <= r + 0.5 * h
    return out


def build_level(
    state: BuildState, lattice: Lattice, d_min: int, executor: Executor, progress: Any = None,
    refine: Refine | None = None,
    keep_out: np.ndarray | None = None,
    inherit: Inherited | None = None,
    twins: Twins | None = None,
) -> BuildState:
    """Process the frontier at state.depth; return the state for the next depth.

    A would-be inner cell that meets a ``keep_out`` capsule (a region the
    oracle knows holds no reachable point, as the static parts of the body
    for an arm) is mixed instead: subdivided, or final at D_max. Its corners
    alone would paint the body reachable between them.
    """
    d, frontier = state.depth, state.frontier
    t0 = time.perf_counter()
    table = state.vertices
    before = len(table)
    retried = probed = inherited = turned = 0
    if d < d_min:
        kinds = np.full(frontier.shape[0], PARENT, np.uint8)
    else:
        vkeys = lattice.node_vertex_keys(frontier, d)
        table, inherited, turned = _evaluate(vkeys, table, lattice, executor, progress, f"depth {d}", inherit, twins)
        if refine and refine.isolated:
            table, retried = _retry_isolated(np.unique(vkeys), table, lattice, 1 << (lattice.d_max - d), executor)
        inside = table.reachable[table.index(vkeys)]
        n_in = inside.sum(axis=1)
        kinds = np.where(n_in == inside.shape[1], INNER,
                         np.where(n_in == 0, OUTER, np.where(d == lattice.d_max, FINAL, PARENT)))
        kinds = kinds.astype(np.uint8)
        if keep_out is not None and len(keep_out) and lattice.dim == 3:
            inner = np.nonzero(kinds == INNER)[0]
            size = lattice.resolution * (1 << (lattice.d_max - d))
            lo = lattice.points(frontier[inner])
            kinds[inner[meets(lo, lo + size, keep_out)]] = FINAL if d == lattice.d_max else PARENT
        if refine and (refine.centres or refine.faces) and d < lattice.d_max:
            kinds, table, probed, taken, twinned = _probe_inner(frontier, kinds, d, table, lattice, executor, progress,
                                                                refine, inherit, twins)
            inherited, turned = inherited + taken, turned + twinned
    par = frontier[kinds == PARENT]
    step = 1 << (lattice.d_max - d - 1) if d < lattice.d_max else 0
    nxt = (par[:, None, :] + corner_offsets(lattice.dim)[None] * step).reshape(-1, lattice.dim)
    level = {"depth": d, "nodes": int(frontier.shape[0]), "new_vertices": len(table) - before, "probe_vertices": probed,
             "retried": retried, "inherited": inherited, "turned": turned, "seconds": time.perf_counter() - t0}
    return BuildState(d + 1, nxt, [*state.kinds, kinds], [*state.corners, frontier], table, [*state.levels, level])


def _probe_inner(
    frontier: np.ndarray, kinds: np.ndarray, d: int, table: VertexTable, lattice: Lattice, executor: Executor,
    progress: Any, refine: Refine, inherit: Inherited | None = None, twins: Twins | None = None,
) -> tuple[np.ndarray, VertexTable, int, int, int]:
    """Downgrade to parent the inner cells whose centre (or face-centre) probes fail."""
    inner = np.nonzero(kinds == INNER)[0]
    if inner.size == 0:
        return kinds, table, 0, 0, 0
    half = 1 << (lattice.d_max - d - 1)
    points = [np.full((1, lattice.dim), half, np.int64)] if refine.centres else []
    if refine.faces:
        for axis in range(lattice.dim):
            for side in (0, 2 * half):
                p = np.full((1, lattice.dim), half, np.int64)
                p[0, axis] = side
                points.append(p)
    offsets = np.concatenate(points)
    pkeys = lattice.keys(frontier[inner][:, None, :] + offsets[None])
    before = len(table)
    table, taken, turned = _evaluate(pkeys, table, lattice, executor, progress, f"depth {d} probes", inherit, twins)
    failed = ~table.reachable[table.index(pkeys)].all(axis=1)
    kinds = kinds.copy()
    kinds[inner[failed]] = PARENT
    return kinds, table, len(table) - before, taken, turned


REOPEN_ROUNDS = 8  # passes of reopen(): each may find reachable vertices on still other outer cells


def _touched(corners: np.ndarray, lattice: Lattice, d: int, reach: np.ndarray) -> np.ndarray:
    """Which of depth d's cells (their lattice corners) hold in their closed box one of the ``reach`` vertices (their
    lattice coordinates)."""
    hit = np.zeros(len(corners), bool)
    if not len(corners):
        return hit
    size = 1 << (lattice.d_max - d)
    key_of = lattice.keys(corners)
    order = np.argsort(key_of)
    ordered = key_of[order]
    for o in corner_offsets(lattice.dim):  # the cells about a vertex: the one it starts, and those it ends
        c = ((reach - o) // size) * size
        k = lattice.keys(c[np.all((c >= 0) & (c + size <= lattice.cells), axis=1)])
        pos = np.minimum(np.searchsorted(ordered, k), len(ordered) - 1)
        hit[order[pos[ordered[pos] == k]]] = True
    return hit


def reopen(state: BuildState, lattice: Lattice, executor: Executor, progress: Any = None,
           refine: Refine | None = None, keep_out: np.ndarray | None = None,
           inherit: Inherited | None = None, twins: Twins | None = None) -> tuple[BuildState, int]:
    """Subdivide the outer cells whose closed box holds a reachable vertex found after they were labelled.

    Algorithm 1 labels a cell by its corners at its own depth, before the finer vertices that its neighbours'
    subdivision brings to its faces exist. A coarse cell whose corners all miss can so hide a reachable cap that those
    finer vertices show: a UR5 whose tool points down kept its top 10 cm outside, 2.5 cells at D_max 6, above a coarse
    cell's corners (bench/ur5_truth.py). Such a cell becomes a parent and its subtree is built as the levels build
    theirs (the same rules); until no outer cell is touched. Returns the state, its levels rebuilt in breadth-first
    order, and the number of cells reopened.
    """
    reopened = 0
    for _ in range(REOPEN_ROUNDS):
        kinds = [k.copy() for k in state.kinds]
        new: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        frontier: dict[int, list[np.ndarray]] = {}
        count = 0
        reach = lattice.coords(state.vertices.keys[state.vertices.reachable])
        for d in range(min(len(kinds), lattice.d_max)):
            rows = np.nonzero(kinds[d] == OUTER)[0]
            rows = rows[_touched(state.corners[d][rows], lattice, d, reach)]
            if rows.size:
                kinds[d][rows] = PARENT
                step = 1 << (lattice.d_max - d - 1)
                frontier.setdefault(d + 1, []).append(
                    (state.corners[d][rows][:, None, :] + corner_offsets(lattice.dim)[None] * step).reshape(
                        -1, lattice.dim))
                count += int(rows.size)
        if not count:
            break
        reopened += count
        table = state.vertices
        for d in range(1, lattice.d_max + 1):
            if d not in frontier:
                continue
            part = BuildState(d, np.concatenate(frontier.pop(d)), vertices=table)
            part = build_level(part, lattice, 0, executor, progress, refine, keep_out, inherit, twins)
            table = part.vertices
            new.setdefault(d, []).append((part.corners[-1], part.kinds[-1]))
            if part.frontier.shape[0]:
                frontier.setdefault(d + 1, []).append(part.frontier)
            state.levels.append({**part.levels[-1], "reopened": True})
        state = _in_order(BuildState(state.depth, state.frontier, kinds, state.corners, table, state.levels), new,
                          lattice)
    return state, reopened


def _in_order(state: BuildState, new: dict[int, list[tuple[np.ndarray, np.ndarray]]], lattice: Lattice) -> BuildState:
    """The state's nodes and the new ones, each level in breadth-first order (a parent's children after the previous
    parent's, in corner order), as :func:`reach.maps.tree.bfs_children` reads them."""
    corners, kinds = [state.corners[0]], [state.kinds[0]]
    for d in range(1, lattice.d_max + 1):
        have_c = [state.corners[d]] if d < len(state.corners) else []
        have_k = [state.kinds[d]] if d < len(state.kinds) else []
        for c, k in new.get(d, []):
            have_c.append(c)
            have_k.append(k)
        parents = corners[-1][kinds[-1] == PARENT]
        if not parents.size:
            break
        step = 1 << (lattice.d_max - d)
        want = (parents[:, None, :] + corner_offsets(lattice.dim)[None] * step).reshape(-1, lattice.dim)
        pool_c, pool_k = np.concatenate(have_c), np.concatenate(have_k)
        keys = lattice.keys(pool_c)
        order = np.argsort(keys)
        pos = np.searchsorted(keys[order], lattice.keys(want))
        assert np.array_equal(keys[order][np.minimum(pos, len(keys) - 1)], lattice.keys(want)), "a child is missing"
        corners.append(want)
        kinds.append(pool_k[order][pos])
    return BuildState(state.depth, state.frontier, kinds, corners, state.vertices, state.levels)


def assemble(state: BuildState, box: Box, d_min: int, d_max: int, meta: dict[str, Any]) -> VATree:
    """The tree of a finished build."""
    kind = np.concatenate(state.kinds)
    depth = np.concatenate([np.full(k.shape[0], d, np.uint8) for d, k in enumerate(state.kinds)])
    meta = dict(meta)
    meta["build"] = {
        **meta.get("build", {}),
        # Each distinct vertex once, plus the retries of isolated vertices, less those inherited or given a twin's
        # verdict.
        "oracle_calls": len(state.vertices) + sum(int(lv.get("retried", 0)) - int(lv.get("inherited", 0))
                                                  - int(lv.get("turned", 0)) for lv in state.levels),
        "inherited": sum(int(lv.get("inherited", 0)) for lv in state.levels),
        "turned": sum(int(lv.get("turned", 0)) for lv in state.levels),
        "distinct_vertices": len(state.vertices),
        "lattice_vertices": Lattice(box, d_max).vertex_count,
        "levels": state.levels, "seconds": float(sum(lv["seconds"] for lv in state.levels)),
    }
    return VATree(box, d_min, d_max, depth, np.concatenate(state.corners), kind, bfs_children(kind, box.dim),
                  state.vertices, meta)


def build_tree(
    oracle: Oracle | OracleSpec,
    box: Box,
    d_min: int,
    d_max: int,
    *,
    executor: Executor | None = None,
    chunk_size: int = CHUNK_SIZE,
    progress: bool | str = False,
    meta: dict[str, Any] | None = None,
    state: BuildState | None = None,
    on_level: LevelCallback | None = None,
    refine: Refine | None = None,
    keep_out: np.ndarray | None = None, inherit: Inherited | None = None, twins: Twins | None = None,
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
        refine: Build-time refinements of the vertex rule (see :class:`Refine`).
        keep_out: Capsules (K, 7) that hold no reachable point (see :func:`build_level`).
        inherit: A sub-strategy's reachable vertices (see :class:`Inherited`).
        twins: The volume's quarter turn: one vertex of each set of twins is solved (see :mod:`reach.building.twins`).

    Returns:
        The tree, with the oracle-call count and per-depth statistics in
        ``meta["build"]``.
    """
    check_depths(d_min, d_max)
    lattice = Lattice(box, d_max)
    own = executor is None
    ex = executor if executor is not None else InlineExecutor(oracle, chunk_size)
    if ex.dim != box.dim:
        raise TreeError(f"oracle is {ex.dim}-D but B0 is {box.dim}-D", what="box")
    if state is None:
        state = BuildState(0, np.zeros((1, box.dim), np.int64), vertices=VertexTable.empty(ex.posture_names))
    bar = None
    if progress:
        # tqdm only when progress is drawn
        from tqdm import tqdm

        bar = tqdm(total=0, unit="vertex", leave=False, dynamic_ncols=True)
        bar.label = progress if isinstance(progress, str) else ""
    try:
        while state.frontier.shape[0]:
            state = build_level(state, lattice, d_min, ex, bar, refine, keep_out, inherit, twins)
            if on_level is not None:
                on_level(state)
        state, reopened = reopen(state, lattice, ex, bar, refine, keep_out, inherit, twins)
    finally:
        if bar is not None:
            bar.close()
        if own:
            ex.close()
    meta = dict(meta or {})
    meta.setdefault("build", {})["reopened"] = reopened
    if refine is not None:
        meta.setdefault("build", {})["refine"] = refine.to_dict()
    if isinstance(oracle, OracleSpec):
        meta.setdefault("oracle", oracle.to_dict())
    return assemble(state, box, d_min, d_max, meta)
