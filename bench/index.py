"""The reachability index's cost and error; prints JSON lines.

For each strategy with an index in the atlases given:

* cost: the index's goals solved and seconds, against the position-only
  tree's oracle calls and seconds, and against N times them (what solving
  every direction at every vertex of the build would cost);
* error, on a seeded sample of reachable vertices, against a dense
  reference: the share of ``--dense`` spiral directions (default 200, as
  capability maps use) that the audit's thorough referee reaches (IPOPT, every
  start, ``--restarts`` random ones, from the vertex's stored posture); the
  mean and largest absolute difference of the index from it, and the same
  with the index's own N directions (so that the discretisation and the
  search's misses are told apart): per direction, reached by the index but
  not by the referee (a neighbour's agreement inherited wrongly) and the
  reverse (a quick solve that missed).

Run: ``.venv/bin/python bench/index.py ATLAS [--sample 40] [--dense 200]``
(e.g. an atlas of ``configs/examples/arm7_table.yaml``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform

import numpy as np

from oracles.protocol import Goals, OracleSpec
from reach.building.executor import ProcessExecutor
from reach.maps.atlas import load_atlas
from reach.maps.index import spiral


def reached(ex: ProcessExecutor, points: np.ndarray, postures: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(m, n) whether the referee reaches each point with each direction, from the point's stored posture."""
    m, n = len(points), len(directions)
    verdicts = ex.evaluate(Goals(np.repeat(points, n, axis=0), {"orientation": np.tile(directions, (m, 1))},
                                 seeds=np.repeat(postures, n, axis=0)))
    return verdicts.reachable.reshape(m, n)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlases", nargs="+")
    parser.add_argument("--sample", type=int, default=40, help="reachable vertices compared with the dense reference")
    parser.add_argument("--dense", type=int, default=200, help="directions of the dense reference")
    parser.add_argument("--restarts", type=int, default=4, help="the referee's random starts")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    machine = {"machine": platform.processor() or platform.machine(), "cores": os.cpu_count()}
    for path in args.atlases:
        atlas = load_atlas(path)
        for name, tree in atlas.trees.items():
            if name not in atlas.indexes:
                continue
            reach_index = atlas.indexes[name]
            b, i = tree.meta["build"], tree.meta["index"]
            n = len(reach_index.directions)
            cost = {"atlas": atlas.manifest["name"], "strategy": name, "directions": n,
                    "tree_calls": b["oracle_calls"], "tree_seconds": round(b["seconds"], 1),
                    "index_goals": i["goals"], "index_seconds": round(i["seconds"], 1),
                    "goals_over_n_calls": round(i["goals"] / (n * b["oracle_calls"]), 3),
                    "seconds_over_tree": round(i["seconds"] / b["seconds"], 2), "mean_index": round(i["mean"], 4),
                    **machine}
            print(json.dumps(cost), flush=True)
            rows = np.nonzero(tree.vertices.reachable)[0]
            rng = np.random.default_rng(args.seed)
            sample = np.sort(rng.choice(rows, size=min(args.sample, rows.size), replace=False))
            points = tree.lattice.points(tree.lattice.coords(tree.vertices.keys[sample]))
            postures = tree.vertices.posture[sample]  # type: ignore[index]
            referee = OracleSpec.from_dict(tree.meta["oracle"]).create().variant("referee",
                restarts=args.restarts)  # type: ignore[attr-defined]
            ex = ProcessExecutor(referee.spec, workers=args.workers)
            try:
                own = reached(ex, points, postures, reach_index.directions)
                dense = reached(ex, points, postures, spiral(args.dense))
            finally:
                ex.close()
            index = reach_index.reached[sample]
            share, ref = index.mean(axis=1), dense.mean(axis=1)
            print(json.dumps({"atlas": atlas.manifest["name"], "strategy": name, "sample": len(sample),
                              "dense": args.dense, "error_vs_dense_mean": round(float(np.abs(share - ref).mean()), 4),
                              "error_vs_dense_max": round(float(np.abs(share - ref).max()), 4),
                              "bias_vs_dense": round(float((share - ref).mean()), 4),
                              "error_vs_own_mean": round(float(np.abs(share - own.mean(axis=1)).mean()), 4),
                              "index_not_referee": int((index & ~own).sum()),
                              "referee_not_index": int((~index & own).sum()), "pairs": int(own.size),
                              **machine}), flush=True)


if __name__ == "__main__":
    main()
