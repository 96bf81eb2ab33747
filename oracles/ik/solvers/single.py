"""What every solver that solves one goal from one start at a time shares: its search is the rounds."""

from __future__ import annotations

import copy
import time
from typing import Any

import numpy as np

from oracles.ik.rounds import NO_CALL, Call, Rounds
from oracles.ik.solvers.protocol import Room, Solver
from oracles.protocol import Purpose, Verdicts


class SingleSolver:
    """A solver of one goal from one start (:meth:`solve`); its search is :class:`~oracles.ik.rounds.Rounds`.

    Args:
        room: The oracle's body, strategy and search (see :class:`~oracles.ik.solvers.protocol.Room`).
    """

    name = ""
    oracle = "casadi-ik"
    thorough = True

    def __init__(self, room: Room) -> None:
        self.room = room

    def options(self) -> dict[str, Any]:
        return {}

    def twin(self, room: Room, *, purpose: Purpose | None = None, compiled: bool = True,
             starts: int | None = None) -> Solver:
        out = copy.copy(self)
        out.room = room
        return out

    def prepare(self) -> None:
        """Nothing to build."""

    def solve(self, goal: np.ndarray, x0: np.ndarray, lower: bool = True, call: Call = NO_CALL) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__} must solve a goal")

    def solve_many(self, goals: np.ndarray, x0: np.ndarray, lower: np.ndarray | None = None, call: Call = NO_CALL,
                   targets: np.ndarray | None = None) -> np.ndarray:
        """Postures (N, nq) for goals (N, 3) from starts (N, nx), with the lower tasks where lower (N,) is true,
        each goal with its targets (N, T) when given. Past ``call.deadline`` no further solve starts: the first
        k <= N postures (k >= 1) are returned."""
        flags = np.ones(len(goals), bool) if lower is None else lower
        calls = [call] * len(goals) if targets is None else [call._replace(target=t) for t in targets]
        out: list[np.ndarray] = []
        for g, x, f, c in zip(goals, x0, flags, calls, strict=True):
            if out and time.perf_counter() > call.deadline:
                break
            out.append(self.solve(g, x, bool(f), c))
        return np.array(out)

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                 targets: np.ndarray | None) -> Verdicts:
        room = self.room
        return Rounds(room, self, room.data, points, hints, start, targets, room.body.q_ref).run()

    def hold_many(self, postures: np.ndarray, deadline: float = np.inf) -> np.ndarray:
        """None held as a batch: the caller holds them one at a time (:meth:`IKOracle.hold`), each from its
        neighbour's correction (held here too, a rejected batch cost the motion twice)."""
        return np.full(np.shape(postures), np.nan)

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float:
        return 0.0

    def share(self, other: Solver) -> bool:
        return False
