"""Executors: who runs the oracle on a batch of points.

The builder hands an executor one batch per depth; the executor splits it
into chunks and returns the verdicts in order. Executors never see the tree.
Workers build their own oracle once from its :class:`~oracles.protocol.OracleSpec`,
so heavy solver objects are never pickled per task.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Protocol

import numpy as np

from oracles.protocol import Oracle, OracleSpec, Verdicts, check_verdicts

Progress = Callable[[int], None]


def chunks(n: int, size: int) -> Iterator[slice]:
    """Consecutive slices of at most size rows covering range(n)."""
    for start in range(0, n, size):
        yield slice(start, min(start + size, n))


class Executor(Protocol):
    """Runs an oracle on batches."""

    dim: int
    posture_names: tuple[str, ...]

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None, progress: Progress | None = None) -> Verdicts:
        """Verdicts for every point, in order; calls progress(n) as chunks finish."""
        ...

    def close(self) -> None: ...


class InlineExecutor:
    """Runs every chunk in this process, one after the other."""

    def __init__(self, oracle: Oracle | OracleSpec, chunk_size: int = 2048) -> None:
        self.oracle = oracle.create() if isinstance(oracle, OracleSpec) else oracle
        self.dim = self.oracle.dim
        self.posture_names = tuple(self.oracle.posture_names)
        self.chunk_size = chunk_size

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None, progress: Progress | None = None) -> Verdicts:
        parts = []
        for sl in chunks(points.shape[0], self.chunk_size):
            v = self.oracle.evaluate(points[sl], None if hints is None else hints[sl])
            parts.append(check_verdicts(v, sl.stop - sl.start, len(self.posture_names)))
            if progress:
                progress(sl.stop - sl.start)
        return Verdicts.concatenate(parts)

    def close(self) -> None:
        pass


# One oracle per worker process, built on first use from its spec.
_WORKER_ORACLES: dict[str, Oracle] = {}


def _worker_evaluate(spec: OracleSpec, key: str, points: np.ndarray, hints: np.ndarray | None) -> Verdicts:
    oracle = _WORKER_ORACLES.get(key)
    if oracle is None:
        oracle = _WORKER_ORACLES[key] = spec.create()
    return oracle.evaluate(points, hints)


class ProcessExecutor:
    """Runs chunks on a pool of local processes."""

    def __init__(self, spec: OracleSpec, workers: int, chunk_size: int = 512) -> None:
        import json

        local = spec.create()
        self.oracle = local  # for metadata (model hash); work runs in the pool
        self.spec = spec
        self.key = json.dumps(spec.to_dict(), sort_keys=True)
        self.dim = local.dim
        self.posture_names = tuple(local.posture_names)
        self.chunk_size = chunk_size
        self.pool = ProcessPoolExecutor(max_workers=workers)

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None, progress: Progress | None = None) -> Verdicts:
        slices = list(chunks(points.shape[0], self.chunk_size))
        futures = [
            self.pool.submit(_worker_evaluate, self.spec, self.key, points[sl], None if hints is None else hints[sl])
            for sl in slices
        ]
        parts = []
        for sl, fut in zip(slices, futures, strict=True):
            parts.append(check_verdicts(fut.result(), sl.stop - sl.start, len(self.posture_names)))
            if progress:
                progress(sl.stop - sl.start)
        return Verdicts.concatenate(parts)

    def close(self) -> None:
        self.pool.shutdown()
