"""What an IK oracle's solver is given and what it answers.

An :class:`~oracles.ik.oracle.IKOracle` is a body, a strategy and a search
(the :class:`Room` a solver works in) holding one :class:`Solver`: the
batched Gauss-Newton engine, the interior-point programs (fatrop, IPOPT) or
the damped least squares, one file each in this package. The oracle asks
its solver for verdicts (:meth:`Solver.evaluate`), the solver drives its own
search (:class:`~oracles.ik.rounds.Rounds` one start at a time, or
:class:`~oracles.ik.waves.Waves` in batches) and reads the room it was
given; nothing here knows the oracle's class.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import pinocchio as pin

from oracles.bodies.body import Body
from oracles.ik.problem import ReachProblem
from oracles.ik.rounds import NO_CALL, Call
from oracles.ik.search import Search
from oracles.ik.strategy import Strategy
from oracles.protocol import Purpose, Verdicts


class Room(Protocol):
    """What a solver reads of its oracle: the body, the strategy and its problem, the search, the stats it counts.

    Attributes:
        strategy_params: The strategy's spec (body, effector, joints, tasks): names compiled programs.
    """

    body: Body
    strategy: Strategy
    problem: ReachProblem
    search: Search
    stats: dict[str, int]
    strategy_params: dict[str, Any]

    @property
    def data(self) -> pin.Data: ...

    def effector_positions(self, postures: np.ndarray) -> np.ndarray: ...

    def faults(self, postures: np.ndarray) -> list[list[str]]: ...


class Solver(Protocol):
    """An IK engine an oracle holds (see the module docstring).

    Attributes:
        name: The solver's name, as a spec's ``solver`` key gives it.
        oracle: The registry name of the oracle it makes (``casadi-ik``, ``dls``).
        thorough: Whether its search leaves its start's basin (random starts, a global step): it then looks for a
            strategy's home and for a ``reference: auto`` that projection did not find.
    """

    name: str
    oracle: str
    thorough: bool

    def options(self) -> dict[str, Any]:
        """The solver's own parameters, as a spec writes them."""
        ...

    def twin(self, room: Room, *, purpose: Purpose | None = None, compiled: bool = True,
             starts: int | None = None) -> Solver:
        """The same solver for another room (a variant, a probe), sharing its programs: tuned for ``purpose``;
        ``compiled=False``: never compiling, with programs of its own; ``starts``: the starts a goal where it takes
        a number of them."""
        ...

    def prepare(self) -> None:
        """Build what solving needs (programs, compiled code) now rather than on the first solve."""
        ...

    def solve(self, goal: np.ndarray, x0: np.ndarray, lower: bool = True, call: Call = NO_CALL) -> np.ndarray:
        """A posture q that tries to put the effector at ``goal`` from the start x0 (with the lower tasks, or the
        stack down to reach alone)."""
        ...

    def evaluate(self, points: np.ndarray, hints: np.ndarray | None, start: np.ndarray | None,
                 targets: np.ndarray | None) -> Verdicts:
        """The verdicts of goals (N, 3) [m] by this solver's search, seeded with hints, from the current posture
        ``start`` (as x) when given, each held to its targets (N, T) when given."""
        ...

    def hold_many(self, postures: np.ndarray, deadline: float = np.inf) -> np.ndarray:
        """Postures (F, nq) each held as one batch, a NaN row where none is."""
        ...

    def preference(self, posture: np.ndarray, goal: np.ndarray, call: Call = NO_CALL) -> float:
        """How much the lower tasks dislike a posture (lower is better; 0 when the solver cannot tell)."""
        ...

    def share(self, other: Solver) -> bool:
        """Take ``other``'s programs when one program serves both bodies; whether it did."""
        ...
