"""A batch's refinements made ahead, in passes of one evaluate call per strategy (the oracle's engine then solves a
pass's goals together).

Each goal's first choice; then, for the goals it failed, the next strategy by priority (again, while some fail); then,
for goals answered with a joint near its limit, the next strategies until one comes nearer fewer limits (the
handover). The selector then answers each goal from what was made, as it answers one goal alone.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from reach.answers.answer import FAILED, REFINED, TIMEOUT
from reach.answers.refine import Prefetched, Refiner
from reach.answers.stored import StoredPostures

Nearest = tuple[int, np.ndarray]  # a goal's nearest stored row and the point its posture reaches [m]
Item = tuple[int, str, Nearest | None]  # a goal's index, a strategy, its nearest stored row there


class Passes:
    """The passes of one selector's batches.

    Args:
        refiner: The selector's refinement.
        stored: The selector's stored postures.
        limits: The joint limits a strategy's posture comes within a margin [rad] of.
        handover: [rad] the handover's margin (0: answers near a limit are not handed over).
    """

    def __init__(self, refiner: Refiner, stored: StoredPostures,
                 limits: Callable[[str, np.ndarray, float], list[str]], handover: float) -> None:
        self.refiner, self.stored, self.handover = refiner, stored, handover
        self._limits = limits

    def limits(self, name: str, q: np.ndarray) -> list[str]:
        return self._limits(name, q, self.handover)

    def run(self, g: np.ndarray, names: list[str], hits: np.ndarray, nearest: dict[int, Nearest | None],
            aims: list[np.ndarray | None], deadline: float | None) -> tuple[list[Prefetched], np.ndarray]:
        """Every refinement the answers of a batch of goals (N, d) will ask for, given which strategies' trees hold
        each (``hits``, (S, N), by priority) and each goal's nearest stored row in its first. Returns each goal's
        refinements by strategy, and which goals the deadline left unrefined (their turn came after it)."""
        n = len(g)
        done: list[Prefetched] = [{} for _ in range(n)]
        late = np.zeros(n, bool)
        held = [[name for j, name in enumerate(names) if hits[j, i]] for i in range(n)]
        first = [(i, held[i][0], nearest[i]) for i in range(n) if held[i] and nearest.get(i) is not None]
        self._pass(g, first, aims, deadline, done, late)
        pending = self._left(first, held, done)
        while pending:
            items = self._next(g, pending)
            self._pass(g, items, aims, deadline, done, None)
            for i, name, _ in items:
                rest, below = pending[i]
                rest.pop(0)
                if self._settled(*done[i][name], name, below):
                    rest.clear()  # answered, or out of time: no further strategy is tried
            pending = {i: p for i, p in pending.items() if p[0]}
        return done, late

    def _settled(self, q: np.ndarray, residual: float | None, outcome: str, name: str, below: int | None) -> bool:
        """Whether a goal's refinement by a strategy ends its passes: out of time, or reached (with fewer than
        ``below`` limits near, for a handover)."""
        return outcome == TIMEOUT or (outcome == REFINED and (below is None or len(self.limits(name, q)) < below))

    def _left(self, first: list[Item], held: list[list[str]],
              done: list[Prefetched]) -> dict[int, tuple[list[str], int | None]]:
        """What is left to try after the first choice: the other strategies, and the limits to beat (None: a
        fallback)."""
        pending: dict[int, tuple[list[str], int | None]] = {}
        for i, name, _ in first:
            if name not in done[i]:
                continue  # its turn came after the deadline
            q, _, outcome = done[i][name]
            if outcome == FAILED:
                pending[i] = (held[i][1:], None)
            elif outcome == REFINED and self.handover and len(held[i]) > 1 and (limits := self.limits(name, q)):
                pending[i] = (held[i][1:], len(limits))
        return pending

    def _next(self, g: np.ndarray, pending: dict[int, tuple[list[str], int | None]]) -> list[Item]:
        """Each pending goal's next strategy with a stored posture (one without is passed over, as one goal's answer
        passes it)."""
        items = []
        for i, (rest, _) in pending.items():
            while rest and (row := self.stored.nearest_row(rest[0], g[i].tolist())) is None:
                rest.pop(0)
            if rest:
                items.append((i, rest[0], row))
        return items

    def _pass(self, g: np.ndarray, items: list[Item], aims: list[np.ndarray | None], deadline: float | None,
              done: list[Prefetched], late: np.ndarray | None) -> None:
        """One pass: (goal, strategy, nearest stored row) items refined in one call per strategy. Past the deadline a
        first pass (``late`` given) marks its goals late; a later pass records them ``timeout``."""
        for name in dict.fromkeys(name for _, name, _ in items):
            mine = [(i, row) for i, other, row in items if other == name and row is not None]
            if mine and late is not None and deadline is not None and time.perf_counter() > deadline:
                late[[i for i, _ in mine]] = True
            elif mine:
                self._refine(g, name, mine, aims, deadline, done)

    def _refine(self, g: np.ndarray, name: str, mine: list[tuple[int, Nearest]], aims: list[np.ndarray | None],
                deadline: float | None, done: list[Prefetched]) -> None:
        """One strategy's goals of a pass refined in one call, each from its nearest stored posture."""
        idx = np.array([i for i, _ in mine])
        stored = self.stored.maps[name].postures(np.array([row for _, (row, _) in mine]))
        gaps = [float(np.linalg.norm(g[i] - reached)) for i, (_, reached) in mine]
        found = self.refiner.refine_many(name, g[idx], stored, [gap if np.isfinite(gap) else None for gap in gaps],
                                         [aims[i] for i in idx], deadline)
        for i, refined in zip(idx, found, strict=True):
            done[i][name] = refined
