"""The reach problem formulated in CasADi: its symbols, the parameter vector and the body's numbers in it.

What the interior-point programs (:mod:`oracles.ik.solvers.interior`) and the batched function
(:mod:`oracles.ik.solvers.batched`) are built from: the goal (3), the start (nx), the start's weight, the tasks'
targets and, lifted, the body's numbers (:mod:`oracles.ik.parameters`), so that every body of one shape shares one
program.
"""

from __future__ import annotations

import copy
from typing import Any

import casadi as ca
import numpy as np

from oracles.bodies.kinematics import Stacked, SymbolicKinematics
from oracles.ik.parameters import BodyParameters
from oracles.ik.rounds import Call
from oracles.ik.solvers.protocol import Room
from oracles.tasks import Symbolic


class Formulation:
    """The reach problem of one room in CasADi (see the module docstring).

    Args:
        room: The oracle's body, strategy and search.
        body_parameters: The body's numbers as parameters of the programs, when every task can take them.
    """

    def __init__(self, room: Room, body_parameters: bool) -> None:
        self.room, self.body_parameters = room, body_parameters
        self._numbers: tuple[Any, BodyParameters] | None = None  # (the problem they were read from, the numbers)

    def twin(self, room: Room) -> Formulation:
        """This formulation for another room (a variant's): the body's numbers are read again only where its problem
        is another (a new reference posture, a probe's own), not for every refinement's variant."""
        out = copy.copy(self)
        out.room = room
        return out

    def symbols(self) -> tuple[Symbolic, ca.SX]:
        """The programs' symbols and their parameter vector: goal (3), start (nx), start weight, the tasks' targets,
        and, lifted, the body's numbers (:mod:`oracles.ik.parameters`)."""
        p, strategy, model = self.room.problem, self.room.strategy, self.room.body.model
        goal, start, weight = ca.SX.sym("goal", 3), ca.SX.sym("start", p.nx), ca.SX.sym("start_weight", 1)
        target = ca.SX.sym("target", strategy.target_size)
        if not self.lifted:
            sym = Symbolic(SymbolicKinematics(model, p.q_sym), p.x_sym, goal, p.x_ref, p.upper - p.lower,
                           tuple(p.x_names), p.lower, start, weight, strategy.target_dict(target))
            return sym, ca.vertcat(goal, start, weight, target)
        numbers = self.numbers
        kin = SymbolicKinematics(model, p.q_expression(numbers.sx("q_ref")), numbers)
        sym = Symbolic(kin, p.x_sym, goal, numbers.vector("x_ref"), numbers.vector("span"), tuple(p.x_names),
                       numbers.vector("lower"), start, weight, strategy.target_dict(target), numbers,
                       {id(t): f"task{k}." for k, t in enumerate(strategy.tasks)})
        return sym, ca.vertcat(goal, start, weight, target, numbers.symbols)

    @property
    def lifted(self) -> bool:
        """Whether the programs take the body's numbers as parameters: ``body_parameters``, and every task of the
        strategy can (:attr:`Task.parametric`)."""
        return self.body_parameters and all(t.parametric for t in self.room.strategy.tasks)

    @property
    def numbers(self) -> BodyParameters:
        """The body's numbers as the programs take them (lifted when :attr:`lifted`; only lifted programs read them)."""
        room = self.room
        if self._numbers is None or self._numbers[0] is not room.problem:
            tasks = {f"task{k}.{name}": v for k, t in enumerate(room.strategy.tasks) for name, v in t.numbers().items()}
            # The tasks' numbers lifted whole: their zeros are a body's (a capsule a sphere at one member, a segment
            # at the next: 3 of 20 ANSUR II members had another program).
            numbers = BodyParameters(room.body.arrays + Stacked({**room.problem.arrays(), **tasks}), self.lifted,
                                     fixed=frozenset({"root_ref"}), dense=frozenset(tasks))
            self._numbers = (room.problem, numbers)
        return self._numbers[1]

    def program_key(self, options: dict[str, Any]) -> tuple[Any, ...] | None:
        """What two oracles' programs depend on when the body's numbers are parameters (None when they are not): the
        body's signature and joints, the strategy but its body, the solver's ``options``."""
        if not self.lifted:
            return None
        strategy = {k: v for k, v in self.room.strategy_params.items() if k != "body"}
        # jit changes how the programs run, not what they are (the caches below key it apart): `jit: auto` and `true`
        # name the same compiled library; the search's rescues change neither
        engine = {k: v for k, v in options.items() if k not in ("jit", "blocked_starts", "spread")}
        return self.numbers.signature, self.room.body.structure, repr(strategy), repr(sorted(engine.items()))

    def shares_programs(self, options: dict[str, Any], other: Formulation, their_options: dict[str, Any]) -> bool:
        """Whether one program serves this body and ``other``'s (:meth:`program_key`), this body's numbers lifted where
        ``other``'s are when only their constants differ (:meth:`BodyParameters.adopted`)."""
        mine, theirs = self.program_key(options), other.program_key(their_options)
        if mine is None or theirs is None or mine[1:] != theirs[1:]:
            return False
        if mine[0] != theirs[0]:
            adopted = self.numbers.adopted(other.numbers)
            if adopted is None:
                return False
            self._numbers = (self.room.problem, adopted)
        return True

    def with_body(self, params: np.ndarray) -> np.ndarray:
        """Parameters (B, k) or (k,) of the goal, start and targets, with the body's lifted numbers after them."""
        if not self.lifted:
            return params  # a program of this body's own: its numbers are constants in it
        values = self.numbers.values
        if params.ndim == 1:
            return np.concatenate([params, values])
        return np.concatenate([params, np.tile(values, (len(params), 1))], axis=1)

    def params(self, goal: np.ndarray, x: np.ndarray, call: Call, pull: bool = False) -> np.ndarray:
        """The programs' parameters: the goal, the current posture (x itself without one) and its weight (0 unless
        pulled), the goal's task targets (``Strategy.target_rows``; the tasks' defaults without)."""
        start = call.start if call.start is not None else x
        target = call.target if call.target is not None else self.default_target
        return self.with_body(np.concatenate([goal, start, [0.0 if call.start is None and not pull else 1.0], target]))

    @property
    def default_target(self) -> np.ndarray:
        """The target parameters of a goal that carries none (each task's default)."""
        return self.room.strategy.target_rows({}, 1)[0]
