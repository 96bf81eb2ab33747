"""A strategy's motion graph: which stored postures the body reaches from its reference posture by a direct motion.

The paper leaves "the timing of motion with stored postures" as future work
(section 6). A reach motion moves the body from its reference posture to the
posture stored at the goal's vertex, then onto the goal. Whether that direct
motion holds every hard task of the strategy at every frame (a foot that stays,
the balance, no segment through another) is a property of the stored posture
alone, so it is checked once, at build time, for every reachable vertex: the
segment from the reference on the body's configuration space
(:meth:`oracles.protocol.Moving.interpolate`, the feet kept where they stand),
sampled every ``STEP`` of posture distance, each sample by the tasks' own
checks (:meth:`oracles.protocol.Moving.faults`). At request time a motion then
checks only its last, short stretch (:mod:`reach.motion.planner`).

Stored beside the tree as ``NAME.graph.npz`` (numpy arrays: ``rows``, the
tree's vertex rows of the stored postures, in :meth:`VATree.stored` order;
``home``, whether each one's direct motion holds; ``meta``, JSON: the format,
the tree's digest, ``STEP``, the build's CPU seconds). A graph whose tree's
digest differs is not used.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from oracles.bodies.mirror import REFLECT
from oracles.protocol import Moving, Shaped
from reach.errors import StoreError
from reach.maps.store import atomic_write
from reach.maps.tree import VATree

FORMAT, VERSION = "reach-motion-graph", 1
# [rad or m] posture distance between the checked samples of a direct motion: about a frame's (a 1.1 s arm reach of
# about 3 rad at 30 Hz moves 0.09 rad a frame; bench/motion.py checks every frame of its motions independently)
STEP = 0.15


@dataclass(frozen=True)
class MotionGraph:
    """Which stored postures of a tree the reference posture's direct motion reaches, every hard task held.

    Attributes:
        rows: (N,) the tree's vertex rows of its stored postures (``VATree.stored`` order).
        home: (N,) whether the direct motion from the reference posture to each holds at every sample.
        meta: ``tree_digest``, ``step`` [rad or m], ``seconds`` (the build's CPU time), ``samples`` checked.
    """

    rows: np.ndarray
    home: np.ndarray
    meta: dict[str, Any]

    def matches(self, tree: VATree) -> bool:
        """Whether the graph was made for this tree (its digest, its stored postures' rows)."""
        found = tree.stored()
        return (found is not None and self.meta.get("tree_digest") == tree.meta.get("digest")
                and np.array_equal(found[0], self.rows))


def graph_path(tree_path: Path) -> Path:
    """Where the graph of the tree stored at ``tree_path`` (``NAME.npz``) lives: ``NAME.graph.npz``."""
    return tree_path.with_name(f"{tree_path.stem}.graph.npz")


def build_graph(tree: VATree, oracle: object, step: float = STEP) -> MotionGraph | None:
    """The graph of a tree whose vertices store postures, by its strategy's oracle; None when it stores none or the
    oracle moves no body (:class:`~oracles.protocol.Moving`, :class:`~oracles.protocol.Shaped`)."""
    found = tree.stored()
    if found is None or not isinstance(oracle, Moving) or not isinstance(oracle, Shaped):
        return None
    rows, _, postures = found
    t0 = time.process_time()
    reference = np.asarray(oracle.reference_posture(), float)
    home = np.zeros(len(rows), bool)
    samples = 0
    for k, q in enumerate(postures):
        n = max(2, int(math.ceil(float(np.linalg.norm(q - reference)) / step)))
        inner = oracle.interpolate(reference, q, np.arange(1, n) / n)  # the ends hold: the reference and a verdict's
        samples += len(inner)
        home[k] = not any(oracle.faults(inner))
    return MotionGraph(rows, home, {"tree_digest": tree.meta.get("digest"), "step": step, "samples": samples,
                                    "seconds": round(time.process_time() - t0, 3)})


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
    home = source.home[[where[int(r)] for r in rows]]
    return MotionGraph(found[0], home, {**source.meta, "tree_digest": tree.meta.get("digest"), "seconds": 0.0,
                                        "mirrored": True})


def save_graph(graph: MotionGraph, path: Path) -> Path:
    meta = json.dumps({"format": FORMAT, "version": VERSION, **graph.meta}, sort_keys=True)

    def write(fh: Any) -> None:
        np.savez_compressed(fh, rows=graph.rows.astype(np.int64), home=graph.home.astype(bool),
                            meta=np.frombuffer(meta.encode(), np.uint8))

    atomic_write(path, write)
    return path


def load_graph(path: Path) -> MotionGraph:
    """The graph stored at ``path``; raises StoreError naming the file and what is wrong."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in ("rows", "home", "meta")}
    except (OSError, ValueError, KeyError) as exc:
        raise StoreError(path, f"not a motion graph ({exc})") from exc
    try:
        meta = json.loads(arrays["meta"].tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StoreError(path, f"meta: expected JSON text ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise StoreError(path, f"meta: expected format {FORMAT} version {VERSION}")
    rows, home = arrays["rows"], arrays["home"]
    if rows.dtype != np.int64 or home.dtype != bool or rows.ndim != 1 or rows.shape != home.shape:
        raise StoreError(path, "rows and home: expected int64 and bool arrays of one length")
    return MotionGraph(rows, home, meta)
