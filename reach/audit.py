"""Auditing a tree against direct IK: how often does the vertex rule lie?

The paper assumes a box is reachable when its vertices are. ``audit`` draws
seeded random probes inside a tree's inner, final and outer cells (cells
picked in proportion to their volume, points uniform inside them), asks the
tree (with a boundary policy) and asks the strategy's own oracle directly
(the referee: its ``variant("referee")``, warm-started from the tree's
nearest reachable posture), and
reports per strategy, per cell type and per depth:

* the false-reachable rate: of the probes the tree calls reachable, the
  fraction the oracle cannot reach;
* the false-unreachable rate: of the probes the tree calls unreachable, the
  fraction the oracle reaches;

each with a 95 % Wilson confidence interval. Overall rates weight each cell
type by its volume, so they estimate the rates over the whole box.

A tree with a reachability index (see :mod:`reach.index`) is audited on it
too: seeded (reachable vertex, direction) pairs, the referee asked with the
direction held from the vertex's stored posture; ``index`` gives the rate of
directions the index calls reached that the referee does not reach (a
neighbour's agreement inherited wrongly) and of those it calls missed that
the referee reaches (a quick solve that missed), and the mean index over the
sampled vertices by the index and by the referee.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from oracles.protocol import Goals, Oracle, OracleSpec, Specified, Tunable
from reach.build import warm_hints
from reach.executor import Executor, InlineExecutor
from reach.store import Atlas
from reach.tree import FINAL, INNER, KIND_NAMES, OUTER, Policy, VATree

Z95 = 1.959963984540054


def wilson(k: int, n: int) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion k/n."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + Z95**2 / n
    centre = (p + Z95**2 / (2 * n)) / den
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def probes(tree: VATree, kind: int, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """n points uniform over the cells of one kind, and the depth of each point's cell."""
    sel = np.nonzero(tree.kind == kind)[0]
    if sel.size == 0 or n == 0:
        return np.zeros((0, tree.dim)), np.zeros(0, int)
    vol = tree.cell_size(tree.depth[sel]).prod(axis=1)
    pick = sel[rng.choice(sel.size, size=n, p=vol / vol.sum())]
    lo = tree.lattice.points(tree.corner[pick])
    return lo + rng.random((n, tree.dim)) * tree.cell_size(tree.depth[pick]), tree.depth[pick].astype(int)


def _rate(bad: np.ndarray, said: np.ndarray) -> dict[str, Any]:
    k, n = int(np.sum(bad & said)), int(np.sum(said))
    lo, hi = wilson(k, n)
    return {"rate": k / n if n else 0.0, "errors": k, "of": n, "ci95": [lo, hi]}


def _stratified(kind: np.ndarray, said: np.ndarray, wrong: np.ndarray, tree: VATree) -> tuple[float, list[float]]:
    """Volume-weighted error rate over the region where the tree said `said`, with a conservative 95 % interval.

    Each cell type is a stratum: its share of that region is its volume times
    the fraction of its probes in the region; the interval combines the
    strata's Wilson intervals with the same weights.
    """
    shares, rates, los, his = [], [], [], []
    for k in (INNER, FINAL, OUTER):
        m = kind == k
        n, n_said = int(m.sum()), int((m & said).sum())
        if n == 0 or n_said == 0:
            continue
        shares.append(tree.volume(k) * n_said / n)
        errors = int((m & wrong).sum())
        rates.append(errors / n_said)
        lo, hi = wilson(errors, n_said)
        los.append(lo)
        his.append(hi)
    if not shares:
        return 0.0, [0.0, 1.0]
    w = np.array(shares) / np.sum(shares)
    return float(w @ rates), [float(w @ los), float(w @ his)]


def audit_tree(tree: VATree, referee: Oracle | Executor, samples: int = 300, policy: Policy = "vertex", seed: int = 0) -> dict[str, Any]:
    """Audit one tree against a referee, an oracle or an executor running one (see the module docstring)."""
    rng = np.random.default_rng(seed)
    per_kind = {k: samples // 3 for k in (INNER, FINAL, OUTER)}
    points, kinds, depths = [], [], []
    for k, n in per_kind.items():
        p, d = probes(tree, k, n, rng)
        points.append(p)
        kinds.append(np.full(len(p), k))
        depths.append(d)
    pts, kind, depth = np.concatenate(points), np.concatenate(kinds), np.concatenate(depths)
    said = tree.contains(pts, policy)
    # The referee starts from the tree's nearest reachable posture too (then
    # the reference and its restarts): a stronger referee, as the build's own
    # solves were warm-started; its verdicts are still checked by Pinocchio.
    truth = referee.evaluate(Goals(pts, seeds=warm_hints(tree.vertices, tree.lattice, pts))).reachable
    out: dict[str, Any] = {"probes": int(len(pts)), "policy": policy, "by_type": {}, "by_depth": {}}
    for k in (INNER, FINAL, OUTER):
        m = kind == k
        out["by_type"][KIND_NAMES[k]] = {"probes": int(m.sum()), "volume": tree.volume(k),
                                         "false_reachable": _rate(~truth[m], said[m]), "false_unreachable": _rate(truth[m], ~said[m])}
    for d in np.unique(depth):
        m = depth == d
        out["by_depth"][str(int(d))] = {"probes": int(m.sum()), "false_reachable": _rate(~truth[m], said[m]), "false_unreachable": _rate(truth[m], ~said[m])}
    fr, fr_ci = _stratified(kind, said, ~truth & said, tree)
    fu, fu_ci = _stratified(kind, ~said, truth & ~said, tree)
    out.update(false_reachable=fr, false_unreachable=fu, false_reachable_ci95=fr_ci, false_unreachable_ci95=fu_ci,
               counts={"false_reachable": _rate(~truth, said), "false_unreachable": _rate(truth, ~said)})
    if tree.index is not None and tree.vertices.posture is not None:
        out["index"] = audit_index(tree, referee, samples, rng)
    return out


def audit_index(tree: VATree, referee: Oracle | Executor, samples: int, rng: np.random.Generator) -> dict[str, Any]:
    """The index against the referee on ``samples`` (vertex, direction) pairs (see the module docstring)."""
    assert tree.index is not None and tree.vertices.posture is not None
    rows = np.nonzero(tree.vertices.reachable)[0]
    if not rows.size:
        return {"pairs": 0}
    v = rng.choice(rows, size=samples)
    d = rng.integers(0, len(tree.index.directions), size=samples)
    points = tree.lattice.points(tree.lattice.coords(tree.vertices.keys[v]))
    aims = tree.index.directions[d]
    truth = referee.evaluate(Goals(points, {"orientation": aims}, seeds=tree.vertices.posture[v])).reachable
    said = tree.index.reached[v, d]
    return {"pairs": int(samples), "directions": len(tree.index.directions), "false_reached": _rate(~truth, said),
            "false_missed": _rate(truth, ~said), "share_by_index": float(said.mean()), "share_by_referee": float(truth.mean())}


def referee(tree: VATree, restarts: int) -> Oracle:
    """The referee: the strategy's own oracle, from the tree's spec, made thorough.

    A :class:`~oracles.protocol.Tunable` oracle gives its ``"referee"``
    variant (for the IK oracles: at least ``restarts`` random restarts, every
    start tried, the reference NLP solver whatever solver built the tree);
    any other oracle referees as it built the tree.
    """
    oracle = OracleSpec.from_dict(tree.meta["oracle"]).create()
    return oracle.variant("referee", restarts=restarts) if isinstance(oracle, Tunable) else oracle


def audit(
    atlas: Atlas, samples: int = 300, policy: Policy = "vertex", seed: int = 0, restarts: int = 6, names: list[str] | None = None,
    executor_factory: Callable[[OracleSpec], Executor] | None = None,
) -> dict[str, Any]:
    """Audit every (or the named) strategy of an atlas; the referee runs in this process or on the executors made by executor_factory."""
    result = {}
    for name in names or list(atlas.trees):
        tree = atlas.trees[name]
        judge = referee(tree, restarts)
        # Executors rebuild the referee from its spec in their workers.
        runner = executor_factory(judge.spec) if executor_factory and isinstance(judge, Specified) else InlineExecutor(judge)
        try:
            result[name] = audit_tree(tree, runner, samples, policy, seed)
        finally:
            runner.close()
    return {"strategies": result, "samples_per_strategy": samples, "policy": policy, "seed": seed}
