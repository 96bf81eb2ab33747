"""Executors (reach.building.executor): every executor gives the same verdicts, chunks cover batches, malformed verdicts
are refused."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import human_config, same_tree

from oracles.protocol import Goals, OracleSpec, Verdicts
from oracles.shapes import sphere
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.building.executor import DaskExecutor, InlineExecutor, ProcessExecutor, chunks
from reach.errors import OracleError


@pytest.mark.slow
def test_every_executor_gives_the_same_tree(tmp_path):
    from distributed import Client, LocalCluster

    config = parse_config(human_config(d_max=2), "arm", "arm")
    inline = build_atlas(config, tmp_path / "inline",
                         executor_factory=lambda s: InlineExecutor(s, 7)).trees["right_arm"]
    procs = build_atlas(config, tmp_path / "procs",
                        executor_factory=lambda s: ProcessExecutor(s, 2, 13)).trees["right_arm"]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        dask = build_atlas(config, tmp_path / "dask",
                           executor_factory=lambda s: DaskExecutor(s, client, 11)).trees["right_arm"]
    same_tree(inline, procs)
    same_tree(inline, dask)
    assert inline.oracle_calls == len(inline.vertices) > 50
    # and the same motion graph, its motions checked on each executor's workers (Executor.apply)
    from reach.maps.graph import load_graph

    graphs = [load_graph(tmp_path / kind / "right_arm.graph.npz") for kind in ("inline", "procs", "dask")]
    assert graphs[0].meta["samples"] > 0 and len(graphs[0].edges) > 0
    for g in graphs[1:]:
        assert np.array_equal(g.home, graphs[0].home) and np.array_equal(g.edges, graphs[0].edges)


def test_chunks_cover_a_batch_in_order():
    assert [(c.start, c.stop) for c in chunks(10, 4)] == [(0, 4), (4, 8), (8, 10)]
    assert list(chunks(0, 4)) == []


def test_inline_and_process_executors_agree_pointwise_with_the_oracle():
    spec = OracleSpec("sphere", {"center": [0.1, 0.0, -0.2], "radius": 0.7})
    pts = np.random.default_rng(0).uniform(-1, 1, (101, 3))
    truth = np.linalg.norm(pts - [0.1, 0.0, -0.2], axis=1) <= 0.7
    progress: list[int] = []
    inline = InlineExecutor(spec, chunk_size=17)
    assert np.array_equal(inline.evaluate(Goals(pts), progress.append).reachable, truth)
    assert sum(progress) == 101 and len(progress) == 6
    pool = ProcessExecutor(spec, workers=2, chunk_size=17)
    try:
        assert pool.slices(101)[0].stop <= 13  # at least four chunks per worker when the batch allows
        assert np.array_equal(pool.evaluate(Goals(pts)).reachable, truth)
    finally:
        pool.close()


class Misshapen:
    """An oracle that returns one verdict too few."""

    dim = 3
    posture_names = ()

    def evaluate(self, goals):  # noqa: ANN001
        return Verdicts(np.ones(len(goals) - 1, bool), np.zeros(len(goals) - 1), None)


def test_malformed_verdicts_are_refused_with_the_shapes():
    with pytest.raises(OracleError, match=r"expected \(3,\)"):
        InlineExecutor(Misshapen()).evaluate(Goals(np.zeros((3, 3))))


def test_executors_expose_a_local_oracle_built_without_solving():
    ex = InlineExecutor(sphere(radius=1.0))
    assert ex.dim == 3 and ex.posture_names == () and ex.oracle.evaluate(np.zeros((1, 3))).reachable[0]
