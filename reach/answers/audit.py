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

A tree with a reachability index (see :mod:`reach.maps.index`) is audited on it
too: seeded (reachable vertex, direction) pairs, the referee asked with the
direction held from the vertex's stored posture; ``index`` gives the rate of
directions the index calls reached that the referee does not reach (a
neighbour's agreement inherited wrongly) and of those it calls missed that
the referee reaches (a quick solve that missed), and the mean index over the
sampled vertices by the index and by the referee.

Uniform probes miss what hides in a small volume, so three more kinds of
probe are reported apart:

* ``surface``: points on lattice edges whose two vertices the tree labels
  differently (the surface crosses them), just inside or just outside it;
* ``rays``: points along rays from the strategy's reach bound's centre (its
  anchor: a robot's base, the shoulder) out to the bound; per ray, the
  farthest point the tree holds against the farthest the referee reaches:
  a ray where the tree stops more than two of its finest cells short
  (``short``) is a region the tree lacks (a UR5's tree held nothing above
  z = 0.888 m; its tool reaches 1.08 m);
* ``twins`` (a :class:`~oracles.protocol.Turning` oracle: a base joint that
  turns a full turn): each uniform probe's twin turned 90 deg about that
  axis; the tree's verdicts on the two should agree, and where they do not,
  the referee says which one lies.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from oracles.protocol import Ball, Goals, Oracle, OracleSpec, ReachBound, Specified, Tunable, Turning
from reach.building.atlas import tree_summary
from reach.building.executor import Executor, InlineExecutor
from reach.building.tree import warm_hints
from reach.errors import StoreError
from reach.maps.atlas import Atlas, load_audit
from reach.maps.graph import graph_of
from reach.maps.index import ReachIndex, spiral
from reach.maps.protocol import Policy
from reach.maps.tree import FINAL, INNER, KIND_NAMES, OUTER, VATree

Z95 = 1.959963984540054
RAYS, RAY_POINTS = 16, 10  # rays from the reach bound's centre, and probes along each (evenly in radius)
SHORT_CELLS = 2  # a ray whose tree stops this many of its finest cells short of the referee is reported short
TWIN_TURN = math.pi / 2  # [rad] a probe's twin about a freely turning axis
TWIN_CHECKS = 24  # disagreeing twin pairs the referee settles at most


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
    vol = tree.lattice.cell_size(tree.depth[sel]).prod(axis=1)
    pick = sel[rng.choice(sel.size, size=n, p=vol / vol.sum())]
    lo = tree.lattice.points(tree.corner[pick])
    return lo + rng.random((n, tree.dim)) * tree.lattice.cell_size(tree.depth[pick]), tree.depth[pick].astype(int)


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


def audit_tree(tree: VATree, referee: Oracle | Executor, samples: int = 300, policy: Policy = "vertex", seed: int = 0,
               index: ReachIndex | None = None) -> dict[str, Any]:
    """Audit one tree, and its reachability index when given, against a referee, an oracle or an executor running one
    (see the module docstring)."""
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
                                         "false_reachable": _rate(~truth[m], said[m]),
                                         "false_unreachable": _rate(truth[m], ~said[m])}
    for d in np.unique(depth):
        m = depth == d
        out["by_depth"][str(int(d))] = {"probes": int(m.sum()), "false_reachable": _rate(~truth[m], said[m]),
                                        "false_unreachable": _rate(truth[m], ~said[m])}
    fr, fr_ci = _stratified(kind, said, ~truth & said, tree)
    fu, fu_ci = _stratified(kind, ~said, truth & ~said, tree)
    out.update(false_reachable=fr, false_unreachable=fu, false_reachable_ci95=fr_ci, false_unreachable_ci95=fu_ci,
               counts={"false_reachable": _rate(~truth, said), "false_unreachable": _rate(truth, ~said)})
    out["surface"] = audit_surface(tree, referee, max(samples // 3, 1), policy, rng)
    oracle = getattr(referee, "oracle", referee)  # an executor's local oracle, for its capabilities
    out["rays"] = audit_rays(tree, referee, oracle, policy)
    turn = oracle.free_turn() if isinstance(oracle, Turning) else None
    if turn is not None:
        out["twins"] = audit_twins(tree, referee, pts, said, turn, policy)
    if index is not None and tree.vertices.posture is not None:
        out["index"] = audit_index(tree, index, referee, samples, rng)
    return out


def _judge(tree: VATree, referee: Oracle | Executor, points: np.ndarray) -> np.ndarray:
    """The referee's verdicts, warm-started from the tree's nearest reachable postures."""
    if not len(points):
        return np.zeros(0, bool)
    return np.asarray(referee.evaluate(Goals(points, seeds=warm_hints(tree.vertices, tree.lattice, points))).reachable)


def audit_surface(tree: VATree, referee: Oracle | Executor, n: int, policy: Policy,
                  rng: np.random.Generator) -> dict[str, Any]:
    """Probes just inside and just outside the tree's surface: on lattice edges (at every vertex spacing) whose ends the
    tree labels differently, a quarter of the edge from the reachable end and from the unreachable one."""
    v, lat = tree.vertices, tree.lattice
    coords = lat.coords(v.keys)
    pairs = []
    for step in (1 << k for k in range(int(tree.depth.max(initial=0)) + 1)):
        for axis in range(tree.dim):
            nb = coords.copy()
            nb[:, axis] += step
            ok = np.all(nb <= lat.cells, axis=1)
            rows = np.full(len(coords), -1)
            rows[ok] = v.index(lat.keys(nb[ok]))
            found = rows >= 0
            differ = found & (v.reachable != v.reachable[np.maximum(rows, 0)])
            pairs.append(np.stack([np.nonzero(differ)[0], rows[differ]], axis=1))
    edges = np.concatenate(pairs) if pairs else np.zeros((0, 2), int)
    if not len(edges) or n <= 0:
        return {"edges": 0}
    pick = edges[rng.integers(0, len(edges), size=n)]
    inside = np.where(v.reachable[pick[:, 0]], pick[:, 0], pick[:, 1])
    outside = np.where(v.reachable[pick[:, 0]], pick[:, 1], pick[:, 0])
    a, b = lat.points(coords[inside]), lat.points(coords[outside])
    pts = np.concatenate([a + 0.25 * (b - a), a + 0.75 * (b - a)])
    said, truth = tree.contains(pts, policy), _judge(tree, referee, pts)
    near = np.repeat([True, False], n)
    return {"edges": int(len(edges)), "probes": int(len(pts)),
            "inside": {"false_reachable": _rate(~truth[near], said[near]),
                       "false_unreachable": _rate(truth[near], ~said[near])},
            "outside": {"false_reachable": _rate(~truth[~near], said[~near]),
                        "false_unreachable": _rate(truth[~near], ~said[~near])}}


def audit_rays(tree: VATree, referee: Oracle | Executor, oracle: Any, policy: Policy) -> dict[str, Any]:
    """Probes along rays from the reach bound's centre (the box's centre without one) out to the bound (the box's
    half diagonal); each ray's farthest point held by the tree and reached by the referee (see the module docstring)."""
    bound = oracle.reach_bound() if isinstance(oracle, ReachBound) else None
    box = tree.box
    if bound is not None and not isinstance(bound, Ball):
        bound = Ball(np.asarray(bound[0], float), float(bound[1]))
    centre = bound.centre if bound is not None else 0.5 * (box.lo + box.hi)
    radius = bound.radius if bound is not None else 0.5 * float(np.linalg.norm(box.hi - box.lo))
    if tree.dim == 3:
        directions = spiral(RAYS)
    else:
        turns = np.linspace(0, 2 * math.pi, RAYS, endpoint=False)
        directions = np.stack([np.cos(turns), np.sin(turns)], axis=1)
    radii = radius * (np.arange(RAY_POINTS) + 0.5) / RAY_POINTS
    pts = (centre[None, None] + directions[:, None] * radii[None, :, None]).reshape(-1, tree.dim)
    inside = np.all((pts >= box.lo) & (pts <= box.hi), axis=1)
    said = tree.contains(pts, policy) & inside
    truth = np.zeros(len(pts), bool)
    truth[inside] = _judge(tree, referee, pts[inside])
    cell = float(tree.lattice.cell_size(np.array([tree.depth.max(initial=0)])).max())
    short = []
    for r, d in enumerate(directions):
        k = slice(r * RAY_POINTS, (r + 1) * RAY_POINTS)
        held = radii[said[k]].max(initial=0.0)
        reached = radii[truth[k]].max(initial=0.0)
        if reached - held > SHORT_CELLS * cell:
            short.append({"direction": np.round(d, 4).tolist(), "tree_m": round(float(held), 4),
                          "referee_m": round(float(reached), 4)})
    return {"rays": RAYS, "probes": int(inside.sum()), "centre": np.round(centre, 4).tolist(),
            "radius": round(float(radius), 4), "false_reachable": _rate(~truth[inside], said[inside]),
            "false_unreachable": _rate(truth[inside], ~said[inside]), "short": short}


def audit_twins(tree: VATree, referee: Oracle | Executor, pts: np.ndarray, said: np.ndarray,
                turn: tuple[np.ndarray, np.ndarray], policy: Policy) -> dict[str, Any]:
    """Each probe's twin turned ``TWIN_TURN`` about the free axis: how often the tree's verdicts disagree, and of the
    disagreeing pairs (at most ``TWIN_CHECKS``), how often the referee reaches the one the tree calls unreachable."""
    point, axis = turn
    c, s = math.cos(TWIN_TURN), math.sin(TWIN_TURN)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + s * k + (1 - c) * (k @ k)  # Rodrigues
    twins = (pts - point) @ rot.T + point
    inside = np.all((twins >= tree.box.lo) & (twins <= tree.box.hi), axis=1)
    twin_said = tree.contains(twins, policy)
    differ = np.nonzero(inside & (twin_said != said))[0]
    checked = differ[:TWIN_CHECKS]
    lying = np.where(said[checked, None], twins[checked], pts[checked])  # the one the tree calls unreachable
    reached = _judge(tree, referee, lying)
    return {"axis": np.round(axis, 6).tolist(), "point": np.round(point, 4).tolist(),
            "turn_deg": math.degrees(TWIN_TURN),
            "pairs": int(inside.sum()), "disagree": _rate(twin_said != said, inside),
            "checked": int(len(checked)), "unreachable_but_reached": int(reached.sum())}


def audit_index(tree: VATree, index: ReachIndex, referee: Oracle | Executor, samples: int,
                rng: np.random.Generator) -> dict[str, Any]:
    """The index against the referee on ``samples`` (vertex, direction) pairs (see the module docstring)."""
    assert tree.vertices.posture is not None
    rows = np.nonzero(tree.vertices.reachable)[0]
    if not rows.size:
        return {"pairs": 0}
    v = rng.choice(rows, size=samples)
    d = rng.integers(0, len(index.directions), size=samples)
    points = tree.lattice.points(tree.lattice.coords(tree.vertices.keys[v]))
    aims = index.directions[d]
    truth = referee.evaluate(Goals(points, {"orientation": aims}, seeds=tree.vertices.posture[v])).reachable
    said = index.reached[v, d]
    return {"pairs": int(samples), "directions": len(index.directions), "false_reached": _rate(~truth, said),
            "false_missed": _rate(truth, ~said), "share_by_index": float(said.mean()),
            "share_by_referee": float(truth.mean())}


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
    atlas: Atlas, samples: int = 300, policy: Policy = "vertex", seed: int = 0, restarts: int = 6,
    names: list[str] | None = None, executor_factory: Callable[[OracleSpec], Executor] | None = None,
) -> dict[str, Any]:
    """Audit every (or the named) strategy of an atlas; the referee runs in this process or on the executors made by
    executor_factory."""
    result = {}
    for name in names or list(atlas.trees):
        tree = atlas.trees[name]
        judge = referee(tree, restarts)
        # Executors rebuild the referee from its spec in their workers.
        runner = (executor_factory(judge.spec) if executor_factory and isinstance(judge, Specified)
                  else InlineExecutor(judge))
        try:
            result[name] = audit_tree(tree, runner, samples, policy, seed, atlas.indexes.get(name))
        finally:
            runner.close()
    return {"strategies": result, "samples_per_strategy": samples, "policy": policy, "seed": seed}


def lacking(atlas: Atlas) -> dict[str, list[str]]:
    """Warnings of the regions each strategy's tree lacks, by the atlas's last audit (``audit.json``, see
    :func:`reach.maps.store.save_audit`): every ray along which the tree stops short of the referee, or that the
    audit is
    of an earlier build. Empty for an atlas never audited; an unreadable audit file is one warning (key ``""``)."""
    try:
        audited = load_audit(atlas)
    except StoreError as exc:
        return {"": [str(exc)]}
    out: dict[str, list[str]] = {}
    for name, a in audited.items():
        if not a["current"]:
            out[name] = [f"the last audit ({a['when']}) is of an earlier build of this tree: run 'reach audit' again"]
            continue
        lines = [f"the tree stops {r['tree_m']} m out along {r['direction']}, where the referee reaches "
                 f"{r['referee_m']} m (reach audit, {a['when']}): a region the tree lacks (build deeper, or check "
                 "the strategy's box)" for r in a["short"]]
        if lines:
            out[name] = lines
    return out


def graph_summary(folder: Path, name: str, tree: VATree) -> dict[str, Any] | None:
    """A tree's motion graph (:mod:`reach.maps.graph`) as ``reach info`` says it: how many stored postures the
    reference's direct motion reaches, of how many, the edges, the build's CPU seconds; ``state`` is ``ok``,
    ``missing``, ``stale`` (made for another tree) or ``unreadable``; None for a tree that stores no posture."""
    if tree.stored() is None:
        return None
    graph, state = graph_of(Path(folder) / f"{name}.npz", tree)
    if graph is None:
        kind, _, why = state.partition(": ")
        return {"state": kind, "reason": why} if why else {"state": kind}
    return {"state": "ok", "file": f"{name}.graph.npz", "reached_from_reference": int(graph.home.sum()),
            "stored": len(graph.rows), "edges": len(graph.edges), "cpu_seconds": graph.meta.get("seconds"),
            "mirrored": bool(graph.meta.get("mirrored", False))}


def summary(atlas: Atlas) -> dict[str, Any]:
    """What ``reach info --json`` prints."""
    strategies = {name: tree_summary(tree, atlas.indexes.get(name)) for name, tree in atlas.trees.items()}
    for name, tree in atlas.trees.items():
        strategies[name]["motion_graph"] = graph_summary(atlas.path, name, tree)
    found = lacking(atlas)
    for name, lines in found.items():
        if name in strategies:
            strategies[name]["audit_warnings"] = lines
    return {
        "name": atlas.manifest.get("name"),
        "path": str(atlas.path),
        "strategies": strategies, "config_warnings": list(atlas.manifest.get("warnings", {}).get("config", [])),
        "audit_warnings": found.get("", []),
    }

