"""Atlases: one tree per strategy of a configuration, built and summarised.

``build_atlas`` runs Algorithm 1 for every strategy of a config and writes
the trees and the manifest. It checkpoints each strategy after every depth
(``OUT/.partial/<name>.npz``), so a killed build resumes where it stopped
(``resume=True``); finished trees whose fingerprint matches are kept.
A strategy with ``mirror_of`` is derived by mirroring when the body passes
the symmetry check (:mod:`reach.building.mirror`), unless ``mirror=False``. A
strategy built after a *sub-strategy* (same body and effector, a subset of
its joints; the crouch after the whole body) inherits that tree's reachable
vertices once its own oracle has verified their postures
(:class:`reach.building.tree.Inherited`), unless ``inherit=False``.
``summary`` is what ``reach info`` prints.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import platform
import time
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from oracles.protocol import (
    Described,
    KeepOut,
    Landmarked,
    Mirrorable,
    ModelHashed,
    Oracle,
    OracleSpec,
    ShapeHashed,
    Specified,
    Tunable,
    Verifying,
)
from reach.building.autobox import grown
from reach.building.checkpoint import load_state, save_state
from reach.building.config import Config, StrategySpec
from reach.building.executor import Executor, InlineExecutor
from reach.building.index import compute_index
from reach.building.mirror import MirrorOracle
from reach.building.tree import BuildState, Inherited, build_tree
from reach.building.twins import Twins
from reach.errors import ModelError, StoreError
from reach.maps.atlas import Atlas, build_lock, load_atlas, write_manifest
from reach.maps.box import Box
from reach.maps.graph import MotionGraph, build_graph, graph_of, graph_path, mirror_graph, save_graph
from reach.maps.index import ReachIndex, spiral
from reach.maps.index import summary as index_summary
from reach.maps.store import load_indexed, save_tree
from reach.maps.tree import FINAL, INNER, Lattice, VATree, faces_of

PARTIAL = ".partial"


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    # reach's own distribution is reach-volumes (PyPI's "reach" is another project); the manifest keeps the key reach
    for key, pkg in (("reach", "reach-volumes"), ("numpy", "numpy"), ("scipy", "scipy"), ("pin", "pin"),
                     ("casadi", "casadi"), ("pyzmq", "pyzmq")):
        try:
            out[key] = version(pkg)
        except PackageNotFoundError:
            pass
    return out


def fingerprint(config: Config, strategy: StrategySpec, oracle: Oracle) -> str:
    """Identifies what a strategy's tree depends on: its oracle (the build's, with the defaults it fills in), B0 and
    depths."""
    # The spec as the oracle completes it (its engine, its search): a tree built by another default engine is not
    # kept (the spec as written was, when the default solver became the batched engine).
    spec = oracle.spec.to_dict() if isinstance(oracle, Specified) else strategy.oracle.to_dict()
    parts: dict[str, Any] = {"oracle": spec, "box": config.box.to_dict(), "depth": [config.d_min, config.d_max],
                             "refine": config.refine.to_dict()}
    if strategy.directions:
        parts["directions"] = strategy.directions
    text = json.dumps(parts, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def sub_strategies(order: list[StrategySpec],
                   oracle_of: Callable[[StrategySpec], Oracle] | None = None) -> dict[str, str]:
    """For each strategy, the sub-strategy it inherits from, if any: built before it, on the same body (its shape:
    joint ranges may differ) and effector, with a subset of its active joints (the largest such subset; the earliest
    among equals).

    ``oracle_of`` gives a strategy's oracle (a build's own, made once); by default each is made here."""
    seen: dict[str, tuple[str, str, frozenset[str], tuple[str, ...]]] = {}
    for s in order:
        oracle = oracle_of(s) if oracle_of is not None else s.oracle.create()  # builds no solver
        if isinstance(oracle, Described) and isinstance(oracle, ModelHashed):
            # the same shape: a strategy with its own joint ranges still inherits (the verdict checks the ranges)
            shape = oracle.shape_hash if isinstance(oracle, ShapeHashed) else oracle.model_hash
            seen[s.name] = (shape, s.effector, frozenset(oracle.describe()["joints"]), tuple(oracle.posture_names))
    out: dict[str, str] = {}
    for k, s in enumerate(order):
        if s.name not in seen:
            continue
        body, effector, joints, names = seen[s.name]
        subs = [t.name for t in order[:k] if t.name in seen and seen[t.name][:2] == (body, effector)
                and seen[t.name][3] == names
                and seen[t.name][2] < joints]
        if subs:
            out[s.name] = max(subs, key=lambda n: (len(seen[n][2]), -subs.index(n)))
    return out


def _mirror_source(s: StrategySpec, built: dict[str, VATree], oracle_of: Callable[[str], Oracle],
                   log: Callable[[str], None]) -> tuple[VATree, Any] | None:
    """The source tree and posture mirror if s may be derived by mirroring, else None (with the reason logged)."""
    if s.mirror_of is None or s.mirror_of not in built:
        return None
    source = built[s.mirror_of]
    oracle = oracle_of(s.mirror_of)  # builds no solver
    if not isinstance(oracle, Mirrorable):
        log(f"{s.name}: built, not mirrored: its oracle has no body whose symmetry could be checked")
        return None
    try:
        mirror = oracle.mirror()
    except ModelError as exc:
        log(f"{s.name}: built, not mirrored: {exc}")
        return None
    return source, mirror


GROWS = 3  # box: auto: how many times B0 may grow after a build whose reachable vertices lie on its faces


def face_text(faces: dict[str, int]) -> str:
    """The warning for reachable vertices on faces of B0 (see :meth:`VATree.faces`)."""
    listed = ", ".join(f"{n} on {f}" for f, n in faces.items())
    return (f"reachable vertices lie on faces of the box ({listed}): the box cuts the volume there; enlarge it on "
            "those faces")


def build_atlas(
    config: Config, out: str | Path, *, executor_factory: Callable[[OracleSpec], Executor] | None = None,
    progress: bool = False, log: Callable[[str], None] | None = None,
    resume: bool = False,
    mirror: bool = True,
    inherit: bool = True,
) -> Atlas:
    """Build every strategy's tree of a config into the folder out.

    Args:
        config: The validated configuration.
        out: Output folder; created if needed.
        executor_factory: Called with an OracleSpec, returns an Executor;
            inline by default.
        progress: Show progress bars.
        log: Receives one line of text per strategy.
        resume: Keep finished trees and continue from checkpoints.
        mirror: Derive ``mirror_of`` strategies by mirroring when allowed.
        inherit: Let a strategy inherit a sub-strategy's reachable vertices (see :func:`sub_strategies`).
    """
    say = log or (lambda _line: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with build_lock(out):
        grows = 0
        while True:
            # box: auto: a build stops at the first depth whose reachable vertices lie on a face B0 may grow past
            # (_Cut), not after every strategy: 5 of configs/population.yaml's 40 members grew, and their first
            # builds were a quarter of the population's build time (docs/population.md)
            growing = config.limit is not None and grows < GROWS
            try:
                atlas = _build_locked(config, out, executor_factory, progress, say, resume, mirror, inherit, growing)
                cut, where = {f for w in atlas.manifest["warnings"]["faces"] for f in w["faces"]}, ""
            except _Cut as stopped:
                cut, where = stopped.faces, f" (found at depth {stopped.depth} of {stopped.strategy})"
            box = _grown(config, cut) if growing else None
            if box is None:
                return atlas
            say(f"box: auto: reachable vertices lie on {', '.join(sorted(cut))}{where}; B0 grows to min "
                f"{box.lo.tolist()} max {box.hi.tolist()} [m], and every strategy is built again")
            config, grows = config.with_box(box), grows + 1


class _Cut(Exception):  # noqa: N818 (a signal, not an error)
    """A build stopped at a depth whose reachable vertices lie on faces of B0 that box: auto may grow past."""

    def __init__(self, strategy: str, depth: int, faces: set[str]) -> None:
        super().__init__(f"{strategy}: reachable vertices on {sorted(faces)} at depth {depth}")
        self.strategy, self.depth, self.faces = strategy, depth, faces


def _grown(config: Config, cut: set[str]) -> Box | None:
    """B0 grown past the faces ``cut`` (a mirrored atlas's both y faces), or None when none can grow."""
    if any(s.mirror_of for s in config.strategies) and cut & {"y-", "y+"}:
        cut = cut | {"y-", "y+"}  # a mirrored atlas keeps its box symmetric about y = 0
    return grown(config.box, config.limit, cut) if cut and config.limit is not None else None


def _build_locked(
    config: Config, out: Path, executor_factory: Callable[[OracleSpec], Executor] | None, progress: bool,
    say: Callable[[str], None], resume: bool, mirror: bool, inherit: bool, growing: bool = False,
) -> Atlas:
    """build_atlas's work, with the folder locked; ``growing``: stopped (_Cut) at the first depth whose reachable
    vertices lie on a face B0 can grow past."""
    t0 = time.perf_counter()
    job = _AtlasBuild(config, out, executor_factory, progress, say, resume, growing)
    # Mirror sources first, so that their trees exist when their images are made.
    order = sorted(config.strategies, key=lambda s: s.mirror_of is not None)
    job.by_name = {s.name: s for s in order}
    job.subs = sub_strategies(order, job.oracle_of) if inherit else {}
    entries = [job.strategy(s, mirror) for s in order]
    _finish(config, out, entries, job.built, job.warnings, time.perf_counter() - t0,
            _landmarks(job.oracle_of(order[0])))
    return load_atlas(out)


def _landmarks(oracle: Oracle) -> dict[str, list[float]] | None:
    """Every frame of the strategies' body in its reference posture [m] (they share one body), for targets given on
    it where no oracle is made (a server's ``accommodation``); None for a body without named frames."""
    if not isinstance(oracle, Landmarked):
        return None
    return {name: [float(v) for v in p] for name, p in oracle.landmarks(None).items()}


@dataclasses.dataclass
class _AtlasBuild:
    """One build of an atlas's strategies, one after the other: what each needs of those before it."""

    config: Config
    out: Path
    executor_factory: Callable[[OracleSpec], Executor] | None
    progress: bool
    say: Callable[[str], None]
    resume: bool
    growing: bool = False  # stop (_Cut) at a depth whose reachable vertices lie on a face B0 can grow past
    by_name: dict[str, StrategySpec] = dataclasses.field(default_factory=dict)
    subs: dict[str, str] = dataclasses.field(default_factory=dict)  # a strategy -> the sub-strategy it inherits from
    built: dict[str, VATree] = dataclasses.field(default_factory=dict)
    warnings: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    made: dict[str, Oracle] = dataclasses.field(default_factory=dict)  # each strategy's oracle, made once
    prints: dict[str, str] = dataclasses.field(default_factory=dict)
    graphs: dict[str, MotionGraph | None] = dataclasses.field(default_factory=dict)

    def oracle_of(self, s: StrategySpec) -> Oracle:
        if s.name not in self.made:
            self.made[s.name] = s.oracle.create()
        return self.made[s.name]

    def strategy(self, s: StrategySpec, mirror: bool) -> dict[str, Any]:
        """Build (or keep, or mirror) one strategy's tree, its index and its motion graph; its manifest entry."""
        path, partial = self.out / f"{s.name}.npz", self.out / PARTIAL / f"{s.name}.npz"
        fp = fingerprint(self.config, s, self.oracle_of(s))
        if s.name in self.subs:  # the tree depends on its sub-strategy's too
            fp = hashlib.sha256(f"{fp} {self.prints[self.subs[s.name]]}".encode()).hexdigest()[:16]
        self.prints[s.name] = fp
        tree, index = self._tree(s, path, partial, fp, mirror)
        if s.directions and index is None and tree.vertices.posture is not None:
            tree, index = _index_one(self.config, s, tree, self.executor_factory, self.progress, self.oracle_of(s))
            i = tree.meta["index"]
            self.say(f"{s.name}: reachability index over {s.directions} directions: {i['goals']} goals solved, mean "
                     f"{i['mean']:.3f} at reachable vertices, {i['seconds']:.2f} s")
        save_tree(tree, path, index)
        partial.unlink(missing_ok=True)
        self.built[s.name] = tree
        if self.config.motion_graph:
            source = tree.meta["build"].get("mirrored_from")
            self.graphs[s.name] = _graph_one(s, tree, path, self.oracle_of(s), self.say,
                                             (self.graphs.get(source), self.built[source]) if source in self.built
                                             else None, self.executor_factory)
        faces = tree.faces()
        if faces:
            self.warnings.append({"strategy": s.name, "faces": faces})
            self.say(f"warning: {s.name}: {face_text(faces)}")
        return {"name": s.name, "effector": s.effector, "priority": s.priority, "file": path.name,
                "oracle": s.oracle.to_dict(), "fingerprint": fp, "digest": tree.meta["digest"]}

    def _tree(self, s: StrategySpec, path: Path, partial: Path, fp: str, mirror: bool) -> tuple[VATree, Any]:
        """The strategy's tree and index: kept from an earlier build (resume), mirrored from its source's, or
        built."""
        tree, index = _kept(s, path, fp, self.oracle_of(s), self.say) if self.resume and path.is_file() else (None,
                                                                                                            None)
        if tree is not None:
            return tree, index
        source = (_mirror_source(s, self.built, lambda name: self.oracle_of(self.by_name[name]), self.say) if mirror
                  else None)
        meta: dict[str, Any] = {"name": s.name, "atlas": self.config.name, "effector": s.effector,
                                "priority": s.priority, "oracle": s.oracle.to_dict(), "fingerprint": fp}
        if source is not None:
            return _mirrored(self.config, s, meta, source, self.oracle_of(s), self.say), None
        sub = self.subs.get(s.name)
        parent = (sub, self.built[sub]) if sub is not None and sub in self.built else None
        tree = _build_one(self.config, s, meta, partial, fp, self.executor_factory, self.progress, self.resume,
                          parent, self.oracle_of(s), self.growing)
        self.say(_built_text(s.name, tree, sub))
        return tree, None


def _finish(config: Config, out: Path, entries: list[dict[str, Any]], built: dict[str, VATree],
            warnings: list[dict[str, Any]], seconds: float, landmarks: dict[str, list[float]] | None = None) -> None:
    """The atlas's manifest written, by priority, and the folder of partial trees removed when empty."""
    entries.sort(key=lambda e: (e["priority"], e["name"]))
    manifest = {
        "name": config.name,
        "config": config.raw,
        "source": config.source,
        "strategies": entries,
        "model_hashes": sorted({t.meta["model_hash"] for t in built.values() if "model_hash" in t.meta}),
        "versions": package_versions(), "build_seconds": seconds,
        "warnings": {"config": list(config.notes), "faces": warnings},
    }
    if landmarks is not None:
        manifest["landmarks"] = landmarks
    write_manifest(out, manifest)
    if (out / PARTIAL).is_dir() and not any((out / PARTIAL).iterdir()):
        (out / PARTIAL).rmdir()


def _built_text(name: str, tree: VATree, sub: str | None) -> str:
    """What a build says of a tree it built."""
    b = tree.meta["build"]
    also = f", {b['inherited']} reachable vertices inherited from {sub}" if "inherited_from" in tree.meta else ""
    return (f"{name}: {b['oracle_calls']} oracle calls{also}, {len(tree)} nodes, inner volume "
            f"{tree.volume(INNER):.6g}, {b['seconds']:.2f} s")


def _kept(s: StrategySpec, path: Path, fp: str, oracle: Oracle,
          say: Callable[[str], None]) -> tuple[VATree | None, Any]:
    """A resumed build's finished tree and its index, when made for this spec (``fp``) and body; else (None, None),
    saying why it is rebuilt."""
    try:
        old, old_index = load_indexed(path)
    except StoreError as exc:
        say(f"{s.name}: rebuilding ({exc})")
        return None, None
    model = oracle.model_hash if isinstance(oracle, ModelHashed) else None
    # The spec names a generated human, not its URDF: a new version of the human has the same spec and another
    # model (its kept trees were refused by every answer: "rebuild the atlas").
    if model is not None and old.meta.get("model_hash", model) != model:
        say(f"{s.name}: rebuilding (its body's model changed since {path.name} was built: "
            f"{old.meta['model_hash']} -> {model})")
        return None, None
    if old.meta.get("fingerprint") != fp:
        # The strategy, its oracle, the body or a sub-strategy it inherits from changed.
        say(f"{s.name}: rebuilding (the config changed since {path.name} was built)")
        return None, None
    say(f"{s.name}: kept the finished tree")
    return old, old_index


def _mirrored(config: Config, s: StrategySpec, meta: dict[str, Any], source: Any, oracle: Oracle,
              say: Callable[[str], None]) -> VATree:
    """A mirrored strategy's tree, its verdicts looked up in its source's image: no oracle call."""
    tree = build_tree(MirrorOracle(*source), config.box, config.d_min, config.d_max,
                      meta={**meta, "mirrored_from": s.mirror_of}, keep_out=_keep_out(oracle))
    tree.meta["build"].update(mirrored_from=s.mirror_of, lookups=tree.meta["build"]["oracle_calls"], oracle_calls=0)
    if "model_hash" in source[0].meta:
        tree.meta["model_hash"] = source[0].meta["model_hash"]
    say(f"{s.name}: mirrored from {s.mirror_of} ({len(tree)} nodes, no oracle call)")
    return tree


def _graph_one(s: StrategySpec, tree: VATree, path: Path, oracle: Oracle, say: Callable[[str], None],
               source: tuple[MotionGraph | None, VATree] | None,
               executor_factory: Callable[[OracleSpec], Executor] | None) -> MotionGraph | None:
    """The tree's motion graph (:mod:`reach.maps.graph`): kept when made for this tree, mirrored from its source's for
    a mirrored tree, else made on the build's executor and saved beside it."""
    name, file = s.name, graph_path(path)
    kept, state = graph_of(path, tree)
    if kept is not None:
        return kept
    if state.startswith("unreadable"):
        say(f"{name}: remaking its motion graph ({state.removeprefix('unreadable: ')})")
    graph = mirror_graph(source[0], source[1], tree) if source is not None and source[0] is not None else None
    if graph is None and tree.stored() is not None:
        ex: Executor = executor_factory(s.oracle) if executor_factory else InlineExecutor(oracle)
        try:
            graph = build_graph(tree, oracle, apply=ex.apply)
        finally:
            ex.close()
    if graph is None:
        file.unlink(missing_ok=True)
        return None
    save_graph(graph, file)
    how = "mirrored" if graph.meta.get("mirrored") else f"{graph.meta['samples']} postures checked"
    say(f"{name}: motion graph: {int(graph.home.sum())} of {len(graph.rows)} stored postures reached by a direct "
        f"motion from the reference, {len(graph.edges)} motions between them ({how}, {graph.meta['seconds']:.2f} "
        "CPU s)")
    return graph


def _build_one(
    config: Config, s: StrategySpec, meta: dict[str, Any], partial: Path, fp: str,
    executor_factory: Callable[[OracleSpec], Executor] | None, progress: bool, resume: bool,
    parent: tuple[str, VATree] | None = None,
    oracle: Oracle | None = None,
    growing: bool = False,
) -> VATree:
    state = load_state(partial, fp) if resume and partial.is_file() else None
    lattice = Lattice(config.box, config.d_max)

    def level(st: BuildState) -> None:
        save_state(st, partial, fp)
        cut = set(faces_of(lattice, st.vertices.keys[st.vertices.reachable])) if growing else set()
        if cut and _grown(config, cut) is not None:
            raise _Cut(s.name, st.depth - 1, cut)

    ex: Executor = executor_factory(s.oracle) if executor_factory else InlineExecutor(oracle or s.oracle,
        config.chunk_size)
    try:
        if isinstance(ex.oracle, ModelHashed):
            meta["model_hash"] = ex.oracle.model_hash
        inherit = None
        if parent is not None and isinstance(ex.oracle, Verifying):
            inherit = Inherited(parent[0], parent[1].vertices, ex.oracle.verify)
            meta["inherited_from"] = parent[0]
        return build_tree(
            s.oracle, config.box, config.d_min, config.d_max, executor=ex, progress=s.name if progress else False,
            meta=meta, state=state,
            on_level=level, refine=config.refine, keep_out=_keep_out(ex.oracle),
            inherit=inherit, twins=Twins.of(ex.oracle) if config.twins else None,
        )
    finally:
        ex.close()


def _index_one(config: Config, s: StrategySpec, tree: VATree,
               executor_factory: Callable[[OracleSpec], Executor] | None, progress: bool,
               oracle: Oracle) -> tuple[VATree, ReachIndex]:
    """The tree, its meta counting the index's cost, and its reachability index (see :mod:`reach.maps.index`), solved
    by the strategy's ``index`` variant."""
    assert isinstance(oracle, Tunable)  # the config checked it
    variant = oracle.variant("index")
    ex: Executor = (executor_factory(variant.spec) if executor_factory and isinstance(variant, Specified)
                    else InlineExecutor(variant, config.chunk_size))
    bar = None
    if progress:
        # tqdm only when progress is drawn
        from tqdm import tqdm

        bar = tqdm(unit="goal", leave=False, dynamic_ncols=True, desc=f"{s.name} index")
    t0 = time.perf_counter()
    try:
        index, solved = compute_index(tree, ex, spiral(s.directions), None if bar is None else bar.update)
    finally:
        ex.close()
        if bar is not None:
            bar.close()
    reachable = tree.vertices.reachable
    meta = {**tree.meta, "index": {"directions": s.directions, "goals": solved, "seconds": time.perf_counter() - t0,
                                   "mean": float(index.share[reachable].mean()) if reachable.any() else 0.0}}
    return dataclasses.replace(tree, meta=meta), index


def _keep_out(oracle: object) -> np.ndarray | None:
    """The oracle's keep-out capsules (see :class:`oracles.protocol.KeepOut`), or None."""
    return oracle.keep_out() if isinstance(oracle, KeepOut) else None


def tree_summary(tree: VATree, index: ReachIndex | None = None) -> dict[str, Any]:
    """The per-strategy block of ``reach info --json``."""
    ext, reach = tree.extent(), tree.reachable_extent()
    build = tree.meta.get("build", {})
    return {
        "nodes": {str(d): counts for d, counts in tree.node_counts().items()},
        "oracle_calls": tree.oracle_calls, "lattice_vertices": tree.lattice.vertex_count,
        "volume": {"inner": tree.volume(INNER), "boundary": tree.volume(FINAL)},
        "extent": {"min": ext[0].tolist(), "max": ext[1].tolist()} if ext else None,
        "reachable_extent": {"min": reach[0].tolist(), "max": reach[1].tolist()} if reach else None,
        "on_faces": tree.faces(),
        "effector": tree.meta.get("effector"),
        "priority": tree.meta.get("priority"),
        "box": tree.box.to_dict(),
        "depth": {"min": tree.d_min, "max": tree.d_max},
        "resolution": tree.lattice.resolution.tolist(),
        "build_seconds": build.get("seconds"), "mirrored_from": build.get("mirrored_from"),
        "inherited_from": tree.meta.get("inherited_from"),
        "inherited_vertices": int(build.get("inherited", 0)),
        "turned_vertices": int(build.get("turned", 0)),
        "index": index_summary(tree, index),
    }
