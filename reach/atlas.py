"""Atlases: one tree per strategy of a configuration, built and summarised.

``build_atlas`` runs Algorithm 1 for every strategy of a config and writes
the trees and the manifest; ``summary`` is what ``reach info`` prints.
"""

from __future__ import annotations

import platform
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from reach.build import build_tree
from reach.config import Config
from reach.executor import Executor, InlineExecutor
from reach.store import Atlas, load_atlas, save_tree, write_manifest
from reach.tree import FINAL, INNER, VATree


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("reach", "numpy", "scipy", "pin", "casadi", "pyzmq"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    return out


def build_atlas(
    config: Config,
    out: str | Path,
    *,
    executor_factory: Any = None,
    progress: bool = False,
    log: Any = None,
) -> Atlas:
    """Build every strategy's tree of a config into the folder out.

    Args:
        config: The validated configuration.
        out: Output folder; created if needed.
        executor_factory: Called with an OracleSpec, returns an Executor;
            inline by default.
        progress: Show progress bars.
        log: Optional callable receiving one line of text per strategy.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    t0 = time.perf_counter()
    for s in config.strategies:
        ex: Executor = executor_factory(s.oracle) if executor_factory else InlineExecutor(s.oracle, config.chunk_size)
        try:
            meta = {"name": s.name, "effector": s.effector, "priority": s.priority, "oracle": s.oracle.to_dict()}
            body = getattr(getattr(ex, "oracle", None), "body", None)
            if body is not None:
                meta["model_hash"] = body.hash
            tree = build_tree(s.oracle, config.box, config.d_min, config.d_max, executor=ex, progress=progress, meta=meta)
        finally:
            ex.close()
        save_tree(tree, out / f"{s.name}.npz")
        if log:
            b = tree.meta["build"]
            log(f"{s.name}: {b['oracle_calls']} oracle calls, {len(tree)} nodes, inner volume {tree.volume(INNER):.6g}, {b['seconds']:.2f} s")
        entries.append({"name": s.name, "effector": s.effector, "priority": s.priority, "file": f"{s.name}.npz", "oracle": s.oracle.to_dict()})
    manifest = {
        "name": config.name,
        "config": config.raw,
        "source": config.source,
        "strategies": entries,
        "versions": package_versions(),
        "build_seconds": time.perf_counter() - t0,
    }
    write_manifest(out, manifest)
    return load_atlas(out)


def tree_summary(tree: VATree) -> dict[str, Any]:
    """The per-strategy block of ``reach info --json``."""
    ext = tree.extent()
    build = tree.meta.get("build", {})
    return {
        "nodes": {str(d): counts for d, counts in tree.node_counts().items()},
        "oracle_calls": tree.oracle_calls,
        "lattice_vertices": tree.lattice.vertex_count,
        "volume": {"inner": tree.volume(INNER), "boundary": tree.volume(FINAL)},
        "extent": {"min": ext[0].tolist(), "max": ext[1].tolist()} if ext else None,
        "effector": tree.meta.get("effector"),
        "priority": tree.meta.get("priority"),
        "box": tree.box.to_dict(),
        "depth": {"min": tree.d_min, "max": tree.d_max},
        "resolution": tree.lattice.resolution.tolist(),
        "build_seconds": build.get("seconds"),
    }


def summary(atlas: Atlas) -> dict[str, Any]:
    """What ``reach info --json`` prints."""
    return {
        "name": atlas.manifest.get("name"),
        "path": str(atlas.path),
        "strategies": {name: tree_summary(tree) for name, tree in atlas.trees.items()},
    }
