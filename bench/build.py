"""Atlas build benchmarks; prints JSON lines.

* Per strategy of a config (default configs/demo.yaml): oracle calls,
  vertices per second and wall time, on local processes (all cores); oracle
  calls against the full lattice and against the vertices of the final
  cells (the lower limit for any method resolving the surface at D_max).
* The Dask speed-up: one strategy built on a LocalCluster of 1 and of 2
  workers.

Run: ``.venv/bin/python bench/build.py [--config configs/default.yaml] [--skip-dask]``,
or ``bench/build.py --atlas out/default`` for the figures of an atlas already built.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from reach.building.atlas import build_atlas
from reach.building.config import load_config, parse_config
from reach.building.documents import read_yaml
from reach.building.executor import DaskExecutor, ProcessExecutor
from reach.maps.atlas import load_atlas
from reach.maps.tree import FINAL, VATree

ROOT = Path(__file__).resolve().parents[1]


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def emit_trees(config: str, trees: dict[str, VATree]) -> None:
    for name, tree in trees.items():
        b = tree.meta["build"]
        final = np.unique(tree.lattice.node_vertex_keys(tree.corner[tree.kind == FINAL], tree.d_max)).size
        emit(
            bench="build", config=config, strategy=name, d_max=tree.d_max, oracle_calls=b["oracle_calls"],
            mirrored_from=b.get("mirrored_from"), seconds=round(b["seconds"], 2),
            vertices_per_s=round(b["oracle_calls"] / b["seconds"], 1) if b["seconds"] and b["oracle_calls"]
            and not b.get("mirrored_from") else None,
            full_lattice=tree.lattice.vertex_count, final_cell_vertices=int(final),
            calls_over_full=round(b.get("lookups", b["oracle_calls"]) / tree.lattice.vertex_count, 4),
            calls_over_final=round(b.get("lookups", b["oracle_calls"]) / max(final, 1), 3),
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "demo.yaml"))
    parser.add_argument("--atlas", help="report on this atlas folder instead of building --config")
    parser.add_argument("--skip-dask", action="store_true")
    # Heavy enough that start-up (processes, jit) does not hide the speed-up.
    parser.add_argument("--dask-strategy", default="right_whole_body")
    parser.add_argument("--dask-depth", type=int, default=5)
    args = parser.parse_args()
    workers = os.cpu_count() or 1
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         cores=workers)
    if args.atlas:
        # Figures of an atlas built earlier (e.g. by `reach build`), read from its trees and manifest.
        atlas = load_atlas(args.atlas)
        name = str(atlas.manifest.get("name", args.atlas))
        emit_trees(name, atlas.trees)
        emit(bench="atlas", config=name, wall_s=round(float(atlas.manifest.get("build_seconds", float("nan"))), 1),
             from_manifest=True)
    else:
        config = load_config(args.config)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            built = build_atlas(config, Path(tmp) / "atlas",
                                executor_factory=lambda s: ProcessExecutor(s, workers, config.chunk_size))
            total = time.perf_counter() - t0
            emit_trees(config.name, built.trees)
            emit(bench="atlas", config=config.name, workers=workers, wall_s=round(total, 1))
    if args.skip_dask:
        return
    from distributed import Client, LocalCluster

    data = read_yaml(Path(args.config))
    data["depth"] = {"min": min(2, args.dask_depth), "max": args.dask_depth}
    data["strategies"] = [s for s in data["strategies"] if s["name"] == args.dask_strategy]
    one = parse_config(data, "dask", "dask")
    times = {}
    for n in (1, 2):
        with (tempfile.TemporaryDirectory() as tmp,
              LocalCluster(n_workers=n, threads_per_worker=1, dashboard_address=None) as cluster,
              Client(cluster) as client):
            t0 = time.perf_counter()
            build_atlas(one, Path(tmp) / "a", executor_factory=lambda s, c=client: DaskExecutor(s, c, one.chunk_size))
            times[n] = time.perf_counter() - t0
    emit(bench="dask", strategy=args.dask_strategy, d_max=args.dask_depth, one_worker_s=round(times[1], 2),
         two_workers_s=round(times[2], 2), speedup=round(times[1] / times[2], 2))


if __name__ == "__main__":
    main()
