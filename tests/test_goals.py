"""One goal type: a new kind of goal is a task that declares its per-goal target, and nothing else.

The task below exists only here: it keeps the right elbow at or below a height that each goal carries
(``Goals.targets["elbow_below"]``). Registering it and sending goals with that target needs no change to
the protocol, the oracles, the engines or the executors: this file is the whole of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import pinocchio as pin
import pytest
from helpers import ARM, HUMAN

from oracles.ik.oracle import IKOracle
from oracles.protocol import Goals
from oracles.tasks import TASKS, Constraint, HardTask, Numeric, Reference, Row, Scope, Symbolic
from reach.building.executor import InlineExecutor
from reach.errors import OracleError

ELBOW = "right_elbow_flexion"
SLACK = 1e-4  # [m] the verdict's allowance above the height, as the other hard tasks'
GOALS = np.array([[0.3, -0.35, 1.0], [0.4, -0.3, 1.15], [0.3, -0.45, 0.95]])


@dataclass
class ElbowBelowTask(HardTask):
    """The right elbow at or below each goal's height [m] (world z); a goal without one: no limit."""

    type: ClassVar[str] = "elbow_below"
    summary: ClassVar[str] = "a test's: the elbow below each goal's height"
    target_key: ClassVar[str | None] = "elbow_below"
    target_size: ClassVar[int] = 1
    _id: int = field(default=-1, init=False, repr=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> ElbowBelowTask:
        return cls()

    def targets(self, raw: np.ndarray | None, n: int) -> np.ndarray:
        if raw is None:
            return np.full((n, 1), 10.0)  # far above any elbow: the row never binds
        if raw.shape != (n,):
            raise ValueError(f"expected one height per goal, ({n},), got {raw.shape}")
        return raw.reshape(n, 1)

    def bind(self, reference: Reference) -> None:
        self._id = reference.body.frame_id(ELBOW)

    def constraints(self, sym: Symbolic) -> list[Constraint]:
        return [Constraint(sym.targets[self.type][0] - sym.kin.frame(ELBOW)[1][2], 0.0, np.inf)]

    def rows(self, num: Numeric) -> list[Row]:
        return []  # dls is not tried here

    def holds(self, num: Numeric) -> bool:
        limit = num.targets.get(self.type)
        return limit is None or num.frame(self._id).translation[2] <= float(limit[0]) + SLACK


@pytest.fixture()
def registered(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(TASKS, ElbowBelowTask.type, ElbowBelowTask)


def _elbow_heights(oracle: IKOracle, postures: np.ndarray) -> np.ndarray:
    model, data = oracle.body.model, oracle.body.model.createData()
    out = []
    for q in postures:
        pin.framesForwardKinematics(model, data, q)
        out.append(data.oMf[model.getFrameId(ELBOW)].translation[2])
    return np.array(out)


@pytest.mark.parametrize("solver", ["fatrop", "batch"])
def test_a_goal_kind_declared_by_a_test_task_is_held_by_both_engines(registered: None, solver: str) -> None:
    oracle = IKOracle.from_params(body=HUMAN, effector="right_hand", joints=ARM,
                                  tasks=[{"type": "reach"}, {"type": "elbow_below"}],
                                  solver=solver)
    free = oracle.evaluate(Goals(GOALS))
    assert free.reachable.all()
    # Each goal asks its elbow 1.5 cm below where the free solve put it (the arm can lower it about 2 cm with the
    # hand at these goals): the engines must find another posture, and a goal's limit is its own.
    limit = _elbow_heights(oracle, free.posture) - 0.015
    held = InlineExecutor(oracle).evaluate(Goals(GOALS, {"elbow_below": limit}))
    assert held.reachable.all()
    hand = oracle.effector_positions(held.posture)
    elbows = _elbow_heights(oracle, held.posture)
    for k in np.nonzero(held.reachable)[0]:  # every "reachable" verdict, by Pinocchio's forward kinematics
        assert np.linalg.norm(hand[k] - GOALS[k]) <= 0.005
        assert elbows[k] <= limit[k] + SLACK
    # An elbow limit no arm can meet (below the hip) leaves the goal unreachable.
    assert not oracle.evaluate(Goals(GOALS[:1], {"elbow_below": np.array([0.5])})).reachable[0]


def test_a_target_no_task_takes_or_of_the_wrong_shape_is_refused_by_its_key(registered: None) -> None:
    plain = IKOracle(HUMAN, "right_hand", ARM)
    with pytest.raises(OracleError, match="no task of this strategy takes a goal's 'elbow_below'; add a task {type: "
                                          "elbow_below") as err:
        plain.evaluate(Goals(GOALS, {"elbow_below": np.zeros(3)}))
    assert err.value.key == "elbow_below"
    with pytest.raises(OracleError, match="add a task {type: orientation"):
        plain.evaluate(Goals(GOALS, {"orientation": np.tile([0.0, 0.0, -1.0], (3, 1))}))
    task = IKOracle(HUMAN, "right_hand", ARM, [{"type": "reach"}, {"type": "elbow_below"}])
    with pytest.raises(OracleError, match=r"expected one height per goal, \(3,\), got \(2,\)"):
        task.evaluate(Goals(GOALS, {"elbow_below": np.zeros(2)}))


def test_goals_split_keep_each_goals_own_targets_and_seeds() -> None:
    seeds = np.arange(3 * 2 * 4, dtype=float).reshape(3, 2, 4)
    g = Goals(GOALS, {"elbow_below": np.array([1.0, 2.0, 3.0])}, np.zeros(4), seeds)
    part = g.take(np.array([2, 0]))
    assert np.array_equal(part.points, GOALS[[2, 0]]) and np.array_equal(part.seeds, seeds[[2, 0]])
    assert np.array_equal(part.targets["elbow_below"], [3.0, 1.0]) and part.current is g.current
    assert len(g.take(np.array([False, True, True]))) == 2 and Goals.of(g) is g
    with pytest.raises(OracleError, match=r"points must have shape \(N, 3\), got \(3, 2\)"):
        Goals.of(Goals(GOALS[:, :2]))  # a Goals of the wrong shape is checked too
    with pytest.raises(OracleError, match=r"points must have shape \(N, 3\)"):
        Goals.of(np.zeros((2, 2)))
    with pytest.raises(OracleError, match="this oracle holds no goal's 'orientation'"):
        Goals.points_of(Goals(GOALS, {"orientation": np.zeros((3, 3))}), 3)
