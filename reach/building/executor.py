"""Executors: who runs the oracle on a batch of points.

The builder hands an executor one batch per depth; the executor splits it
into chunks and returns the verdicts in order. Executors never see the tree.
Workers build their own oracle once from its :class:`~oracles.protocol.OracleSpec`,
so heavy solver objects are never pickled per task.
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import sys
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Protocol

import numpy as np

from oracles.protocol import Goals, Oracle, OracleSpec, Verdicts, check_verdicts

Progress = Callable[[int], None]
Task = Callable[[Oracle, np.ndarray], Any]  # work on a worker's oracle (Executor.apply)
CHUNK_SIZE = 2048  # points per task a build sends an executor (the default of build.chunk_size)


def chunks(n: int, size: int) -> Iterator[slice]:
    """Consecutive slices of at most size rows covering range(n)."""
    for start in range(0, n, size):
        yield slice(start, min(start + size, n))


class Executor(Protocol):
    """Runs an oracle on batches.

    Attributes:
        oracle: An oracle of the executor's spec in this process, for what
            the caller may ask of it (capabilities such as ``model_hash``);
            pooled executors run the batches on their workers' own oracles.
    """

    oracle: Oracle
    dim: int
    posture_names: tuple[str, ...]

    def evaluate(self, goals: Goals, progress: Progress | None = None) -> Verdicts:
        """Verdicts for every goal (:class:`oracles.protocol.Goals`), in order; calls progress(n) as chunks finish."""
        ...

    def apply(self, fn: Task, items: np.ndarray) -> list[Any]:
        """``fn(oracle, chunk)`` for consecutive chunks of ``items`` (rows), each on a worker's own oracle of the
        executor's spec, the results in order (``fn`` a module-level function, so that it pickles)."""
        ...

    def close(self) -> None: ...


class InlineExecutor:
    """Runs every chunk in this process, one after the other."""

    def __init__(self, oracle: Oracle | OracleSpec, chunk_size: int = CHUNK_SIZE) -> None:
        self.oracle = oracle.create() if isinstance(oracle, OracleSpec) else oracle
        self.dim = self.oracle.dim
        self.posture_names = tuple(self.oracle.posture_names)
        self.chunk_size = chunk_size

    def evaluate(self, goals: Goals, progress: Progress | None = None) -> Verdicts:
        parts = []
        for sl in chunks(len(goals), self.chunk_size):
            v = self.oracle.evaluate(goals.take(sl))
            parts.append(check_verdicts(v, sl.stop - sl.start, len(self.posture_names)))
            if progress:
                progress(sl.stop - sl.start)
        return Verdicts.concatenate(parts)

    def apply(self, fn: Task, items: np.ndarray) -> list[Any]:
        return [fn(self.oracle, items[sl]) for sl in chunks(len(items), self.chunk_size)]

    def close(self) -> None:
        pass


PR_SET_PDEATHSIG = 1  # Linux prctl option: the signal a process gets when its parent dies


def die_with_parent() -> None:
    """Worker initializer: the kernel ends this worker when its parent (a build, a server) dies, even by
    SIGKILL, so that a killed parent leaves no process behind (Linux; elsewhere a no-op)."""
    if not sys.platform.startswith("linux"):
        return

    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the parent died before the request took effect
        os._exit(1)


def build_worker() -> None:
    """A build's pool worker: dies with its parent; Ctrl-C (which reaches the whole group) is the
    parent's to handle, and SIGTERM ends the worker at once (a group's SIGTERM stops the build, not only its parent)."""
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the parent's handler, inherited by fork, would only fail the chunk


# One oracle per worker process, built on first use from its spec: the cache
# lives in each worker process (a pool process or a Dask worker), never in
# the process that builds the tree. The lock serialises threads of one worker.
_WORKER_ORACLES: dict[str, Oracle] = {}
_WORKER_LOCK = threading.Lock()


def _worker_oracle(spec: OracleSpec, key: str) -> Oracle:
    oracle = _WORKER_ORACLES.get(key)
    if oracle is None:
        oracle = _WORKER_ORACLES[key] = spec.create()
    return oracle


def _worker_evaluate(spec: OracleSpec, key: str, goals: Goals) -> Verdicts:
    with _WORKER_LOCK:
        return _worker_oracle(spec, key).evaluate(goals)


def _worker_apply(spec: OracleSpec, key: str, fn: Task, items: np.ndarray) -> Any:
    with _WORKER_LOCK:
        return fn(_worker_oracle(spec, key), items)


class _Pooled(ABC):
    """Shared plumbing of executors that send chunks to workers by spec."""

    workers: int = 1

    def __init__(self, spec: OracleSpec, chunk_size: int) -> None:
        local = spec.create()  # cheap: oracles build their solvers on the first evaluate
        self.oracle = local
        self.spec = spec
        self.key = json.dumps(spec.to_dict(), sort_keys=True)
        self.dim = local.dim
        self.posture_names = tuple(local.posture_names)
        self.chunk_size = chunk_size

    @abstractmethod
    def submit(self, goals: Goals) -> tuple[list[slice], list[Any]]:
        """Send a batch's chunks to the workers: the slices and their futures, in order."""

    @abstractmethod
    def submit_tasks(self, fn: Task, items: np.ndarray) -> list[Any]:
        """Send ``fn`` on each chunk of ``items`` to the workers: their futures, in order."""

    def apply(self, fn: Task, items: np.ndarray) -> list[Any]:
        return [f.result() for f in self.submit_tasks(fn, items)]

    def slices(self, n: int) -> list[slice]:
        """Chunks of at most chunk_size, and at least four per worker when the batch allows."""
        size = max(1, min(self.chunk_size, -(-n // (4 * max(self.workers, 1)))))
        return list(chunks(n, size))

    def evaluate(self, goals: Goals, progress: Progress | None = None) -> Verdicts:
        slices, futures = self.submit(goals)
        parts = []
        for sl, fut in zip(slices, futures, strict=True):
            parts.append(check_verdicts(fut.result(), sl.stop - sl.start, len(self.posture_names)))
            if progress:
                progress(sl.stop - sl.start)
        return Verdicts.concatenate(parts)


class ProcessExecutor(_Pooled):
    """Runs chunks on a pool of local processes (``--workers N``)."""

    def __init__(self, spec: OracleSpec, workers: int | None = None, chunk_size: int = CHUNK_SIZE) -> None:
        super().__init__(spec, chunk_size)
        self.workers = workers or os.cpu_count() or 1
        self.pool = ProcessPoolExecutor(max_workers=self.workers, initializer=build_worker)

    def submit(self, goals: Goals) -> tuple[list[slice], list[Any]]:
        slices = self.slices(len(goals))
        return slices, [self.pool.submit(_worker_evaluate, self.spec, self.key, goals.take(sl)) for sl in slices]

    def submit_tasks(self, fn: Task, items: np.ndarray) -> list[Any]:
        return [self.pool.submit(_worker_apply, self.spec, self.key, fn, items[sl]) for sl in self.slices(len(items))]

    def close(self) -> None:
        # After a normal batch nothing is pending; after an interrupt the chunks not yet started are dropped
        # (the checkpoints keep what was done) instead of computed.
        self.pool.shutdown(cancel_futures=True)


class DaskExecutor(_Pooled):
    """Runs chunks on a Dask cluster through a ``distributed.Client``.

    Each task carries the oracle's small spec; every worker process builds the
    oracle once and keeps it for the following chunks.
    """

    def __init__(self, spec: OracleSpec, client: Any, chunk_size: int = CHUNK_SIZE) -> None:
        super().__init__(spec, chunk_size)
        self.client = client
        self.workers = max(1, len(client.scheduler_info().get("workers", {})))

    def submit(self, goals: Goals) -> tuple[list[slice], list[Any]]:
        slices = self.slices(len(goals))
        futures = self.client.map(_worker_evaluate, [self.spec] * len(slices), [self.key] * len(slices),
                                  [goals.take(sl) for sl in slices], pure=False)
        return slices, futures

    def submit_tasks(self, fn: Task, items: np.ndarray) -> list[Any]:
        parts = [items[sl] for sl in self.slices(len(items))]
        return list(self.client.map(_worker_apply, [self.spec] * len(parts), [self.key] * len(parts),
                                    [fn] * len(parts), parts, pure=False))

    def close(self) -> None:
        pass  # the client belongs to whoever made it
