"""A strategy's motion graph: the motions between stored postures, and from the reference posture, that hold.

The paper leaves "the timing of motion with stored postures" as future work
(section 6). A reach motion moves the body from its posture now to one stored
near the goal, then onto the goal. Whether a direct motion between two
postures holds every hard task of the strategy at every frame (a foot that
stays, the balance, no segment through another) is a property of the two
postures alone, so it is checked once, at build time: for every reachable
vertex, the motion from the reference posture to its stored posture (the
*home* edges), and the motion to each of its ``NEIGHBOURS`` nearest stored
postures no more than ``REACH`` apart (the edges between them); each on the
body's configuration space (:meth:`oracles.protocol.Moving.interpolate`, the
feet kept where they stand), sampled every ``STEP`` of posture distance, each
sample by the tasks' own checks (:meth:`oracles.protocol.Moving.faults`). At
request time a motion follows the graph's shortest path and checks its frames
(:mod:`reach.motion.planner`).

Stored beside the tree as ``NAME.graph.npz`` (numpy arrays: ``rows``, the
tree's vertex rows of the stored postures, in :meth:`VATree.stored` order;
``home``, whether each one's motion from the reference holds; ``edges``, (E, 2)
int32 pairs of indices into ``rows`` whose motion holds, either way; ``meta``,
JSON: the format, the tree's digest, ``STEP``, ``REACH``, the build's CPU
seconds). A graph whose tree's digest differs is not used.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from oracles.bodies.mirror import REFLECT
from oracles.protocol import Moving, Shaped
from reach.errors import StoreError
from reach.maps.store import atomic_write
from reach.maps.tree import VATree

FORMAT, VERSION = "reach-motion-graph", 1
# [rad or m] posture distance between the checked samples of a direct motion, about two frames' (a 1.1 s arm reach
# of about 3 rad at 30 Hz moves 0.09 rad a frame). The planner checks every frame again: the samples prune its search,
# and at 0.15 the demo's graphs cost 0.6 of its trees' build CPU (the bar: half).
STEP = 0.2
NEIGHBOURS = 5  # stored postures each one is linked to, nearest by where they put the effector
# [rad or m] the longest posture distance of an edge: stored neighbours farther apart hold the arm in another way (an
# elbow up for down), a motion between them a detour the hand need not take (the demo's whole body: median 0.79 rad
# between a vertex's 6 nearest, 90 % under 2.4)
REACH = 1.0
CHUNK = 8  # samples checked at a time: a motion that breaks a task stops there
# runs a function of (oracle, rows) on chunks of rows, each on a worker's own oracle (reach.building.executor)
Apply = Callable[[Callable[[Any, np.ndarray], Any], np.ndarray], list[Any]]


@dataclass(frozen=True)
class MotionGraph:
    """The motions between a tree's stored postures, and from the reference posture, that hold every hard task.

    Attributes:
        rows: (N,) the tree's vertex rows of its stored postures (``VATree.stored`` order).
        home: (N,) whether the direct motion from the reference posture to each holds at every sample.
        edges: (E, 2) pairs of indices into ``rows`` whose direct motion holds (either way).
        meta: ``tree_digest``, ``step`` and ``reach`` [rad or m], ``seconds`` (the build's CPU time), ``samples``.
    """

    rows: np.ndarray
    home: np.ndarray
    edges: np.ndarray
    meta: dict[str, Any]

    def matches(self, tree: VATree) -> bool:
        """Whether the graph was made for this tree (its digest, its stored postures' rows)."""
        found = tree.stored()
        return (found is not None and self.meta.get("tree_digest") == tree.meta.get("digest")
                and np.array_equal(found[0], self.rows))


def graph_path(tree_path: Path) -> Path:
    """Where the graph of the tree stored at ``tree_path`` (``NAME.npz``) lives: ``NAME.graph.npz``."""
    return tree_path.with_name(f"{tree_path.stem}.graph.npz")


def build_graph(tree: VATree, oracle: object, step: float = STEP, apply: Apply | None = None) -> MotionGraph | None:
    """The graph of a tree whose vertices store postures, by its strategy's oracle; None when it stores none or the
    oracle moves no body (:class:`~oracles.protocol.Moving`, :class:`~oracles.protocol.Shaped`). ``apply``: runs
    :func:`motions_hold` on chunks of the motions, on workers' own oracles (a build's executor); in this process by
    default."""
    found = tree.stored()
    if found is None or not isinstance(oracle, Moving) or not isinstance(oracle, Shaped):
        return None
    rows, points, postures = found
    reference = np.asarray(oracle.reference_posture(), float)
    pairs = neighbour_pairs(points, postures)
    # the motions, each (2, nq): from the reference to every stored posture, then between the neighbours
    motions = np.concatenate([np.stack([np.broadcast_to(reference, postures.shape), postures], axis=1),
                              np.stack([postures[pairs[:, 0]], postures[pairs[:, 1]]], axis=1)])
    motions = np.ascontiguousarray(motions)
    parts = (apply or (lambda fn, items: [fn(oracle, items)]))(partial(motions_hold, step=step), motions)
    holds = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, bool)
    home, kept = holds[: len(postures)], holds[len(postures) :]
    return MotionGraph(rows, home, pairs[kept].astype(np.int32).reshape(-1, 2),
                       {"tree_digest": tree.meta.get("digest"), "step": step, "reach": REACH,
                        "neighbours": NEIGHBOURS, "samples": int(sum(p[1] for p in parts)),
                        "seconds": round(float(sum(p[2] for p in parts)), 3)})


def motions_hold(oracle: Any, motions: np.ndarray, step: float = STEP) -> tuple[np.ndarray, int, float]:
    """Whether each direct motion (M, 2, nq: from, to) holds every hard task at its samples ``step`` apart (the ends
    hold: the reference and verdicts' postures), the samples checked, and the CPU seconds it took (a worker's)."""
    t0 = time.process_time()
    out = np.zeros(len(motions), bool)
    samples = 0
    for m, (a, b) in enumerate(motions):
        n = max(2, int(math.ceil(float(np.linalg.norm(b - a)) / step)))
        inner = oracle.interpolate(a, b, np.arange(1, n) / n)
        out[m] = True
        for k in range(0, len(inner), CHUNK):  # a motion that breaks a task stops there
            samples += len(inner[k : k + CHUNK])
            if any(oracle.faults(inner[k : k + CHUNK])):
                out[m] = False
                break
    return out, samples, time.process_time() - t0


def neighbour_pairs(points: np.ndarray, postures: np.ndarray) -> np.ndarray:
    """(P, 2) pairs a < b of stored postures among each one's ``NEIGHBOURS`` nearest by the effector's point, no more
    than ``REACH`` apart in posture."""
    if len(points) < 2:
        return np.zeros((0, 2), np.int32)
    k = min(NEIGHBOURS + 1, len(points))
    _, near = cKDTree(points).query(points, k=k)
    a = np.repeat(np.arange(len(points)), k - 1)
    b = np.asarray(near)[:, 1:].ravel()
    pairs = np.unique(np.sort(np.stack([a, b], axis=1), axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    close = np.linalg.norm(postures[pairs[:, 0]] - postures[pairs[:, 1]], axis=1) <= REACH
    return pairs[close].astype(np.int32)  # type: ignore[no-any-return]


def mirror_graph(source: MotionGraph, source_tree: VATree, tree: VATree) -> MotionGraph | None:
    """The graph of a tree mirrored from ``source_tree`` (:mod:`reach.building.mirror`): each stored posture is its
    source's image about y = 0 and the reference posture its own, so each direct motion holds where its image does."""
    found, src = tree.stored(), source_tree.stored()
    if found is None or src is None:
        return None
    lattice = source_tree.lattice
    keys = lattice.keys(np.rint((found[1] * REFLECT - lattice.box.lo) / lattice.resolution).astype(np.int64))
    rows = source_tree.vertices.index(keys)
    where = {int(r): k for k, r in enumerate(source.rows)}
    if np.any(rows < 0) or any(int(r) not in where for r in rows):
        return None
    index = np.array([where[int(r)] for r in rows], np.int64)  # this tree's k -> its image's index in the source
    if len(index) != len(source.rows) or len(np.unique(index)) != len(index):
        return None  # not a one-to-one image: made anew
    back = np.empty(len(index), np.int64)
    back[index] = np.arange(len(index))
    edges = np.sort(back[source.edges], axis=1).astype(np.int32) if len(source.edges) else source.edges
    return MotionGraph(found[0], source.home[index], edges,
                       {**source.meta, "tree_digest": tree.meta.get("digest"), "seconds": 0.0, "mirrored": True})


def save_graph(graph: MotionGraph, path: Path) -> Path:
    meta = json.dumps({"format": FORMAT, "version": VERSION, **graph.meta}, sort_keys=True)

    def write(fh: Any) -> None:
        np.savez_compressed(fh, rows=graph.rows.astype(np.int64), home=graph.home.astype(bool),
                            edges=graph.edges.astype(np.int32).reshape(-1, 2),
                            meta=np.frombuffer(meta.encode(), np.uint8))

    atomic_write(path, write)
    return path


def graph_of(tree_path: Path, tree: VATree) -> tuple[MotionGraph | None, str]:
    """The graph stored beside the tree at ``tree_path`` when it was made for that tree, and its state: ``ok``,
    ``missing``, ``stale`` (made for another tree) or ``unreadable: WHY`` (the graph then None)."""
    file = graph_path(Path(tree_path))
    if not file.is_file():
        return None, "missing"
    try:
        graph = load_graph(file)
    except StoreError as exc:
        return None, f"unreadable: {exc}"
    return (graph, "ok") if graph.matches(tree) else (None, "stale")


def load_graph(path: Path) -> MotionGraph:
    """The graph stored at ``path``; raises StoreError naming the file and what is wrong."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in ("rows", "home", "edges", "meta")}
    except (OSError, ValueError, KeyError) as exc:
        raise StoreError(path, f"not a motion graph ({exc})") from exc
    try:
        meta = json.loads(arrays["meta"].tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StoreError(path, f"meta: expected JSON text ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise StoreError(path, f"meta: expected format {FORMAT} version {VERSION}")
    rows, home, edges = arrays["rows"], arrays["home"], arrays["edges"]
    if rows.dtype != np.int64 or home.dtype != bool or rows.ndim != 1 or rows.shape != home.shape:
        raise StoreError(path, "rows and home: expected int64 and bool arrays of one length")
    if not _edges_into(edges, len(rows)):
        raise StoreError(path, f"edges: expected (E, 2) int32 indices into rows (0 to {len(rows) - 1})")
    return MotionGraph(rows, home, edges, meta)


def _edges_into(edges: np.ndarray, n: int) -> bool:
    """Whether edges are (E, 2) int32 indices into n rows."""
    shaped = edges.dtype == np.int32 and edges.ndim == 2 and edges.shape[1] == 2
    return bool(shaped and (not edges.size or (edges.min() >= 0 and edges.max() < n)))
