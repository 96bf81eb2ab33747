"""Benchmarks of the VATree core; prints JSON lines.

* ``query``: classify/contains throughput on one core, batched.
* ``calls``: oracle calls of the VATree build against the full lattice
  (2**D_max + 1)**3 and against the vertices of the final cells (the lower
  limit: any method that resolves the surface at D_max must evaluate them).

Run: ``.venv/bin/python bench/tree.py`` (pin one core with ``taskset -c 0``).
"""

from __future__ import annotations

import json
import platform
import time

import numpy as np

from oracles.shapes import sphere
from reach.building.tree import build_tree
from reach.maps.box import Box
from reach.maps.tree import FINAL


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def bench_query(repeats: int = 7, n: int = 2_000_000) -> None:
    tree = build_tree(sphere(radius=1.0), Box([-1, -1, -1], [1, 1, 1]), 2, 8)
    pts = np.random.default_rng(0).uniform(-1.05, 1.05, size=(n, 3))
    tree.classify(pts[:1])  # builds the lookup table once, as a server does at load
    for policy in ("classify", "conservative", "vertex"):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            tree.classify(pts) if policy == "classify" else tree.contains(pts, policy)  # type: ignore[arg-type]
            times.append(time.perf_counter() - t0)
        med = float(np.median(times))
        emit(bench="query", op=policy, d_max=8, points=n, median_s=round(med, 4), points_per_s=round(n / med))


def bench_calls() -> None:
    for d_max in (5, 6, 7, 8):
        t0 = time.perf_counter()
        tree = build_tree(sphere(radius=1.0), Box([-1, -1, -1], [1, 1, 1]), 2, d_max)
        seconds = time.perf_counter() - t0
        final = tree.kind == FINAL
        lower = np.unique(tree.lattice.node_vertex_keys(tree.corner[final], d_max)).size
        full = tree.lattice.vertex_count
        emit(
            bench="calls", d_max=d_max, oracle_calls=tree.oracle_calls, full_lattice=full, final_cell_vertices=lower,
            ratio_to_full=round(tree.oracle_calls / full, 4), ratio_to_final=round(tree.oracle_calls / lower, 3),
            build_s=round(seconds, 3),
        )


if __name__ == "__main__":
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine())
    bench_query()
    bench_calls()
