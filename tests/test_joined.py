"""Several oracles' calls run joined (oracles/ik/joined.py): a population's members, one program with each member's
numbers, their batches of starts iterated as one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import oracles.ik.batch as batch
from oracles.protocol import Goals, OracleSpec, evaluate_together
from reach.building.config import load_config

ROOT = Path(__file__).resolve().parents[1]
# Two ANSUR II members far apart in size (their floating bases' bounds differ, so the joined batch has bounds by row).
MEMBERS = ({"sex": "female", "subject": 28740}, {"sex": "male", "subject": 11373})
GOALS = np.array([[0.45, -0.20, 1.25], [0.35, -0.15, 1.90], [0.85, -0.20, 1.00], [0.40, -0.20, 0.35],
                  [0.30, -0.20, 2.15], [0.05, -0.75, 1.20], [0.35, -0.15, 0.05]])


def _oracles(strategy: str) -> list:
    spec = load_config(ROOT / "configs" / "population.yaml").strategy(strategy).oracle
    made = [OracleSpec(spec.name, {**spec.params, "jit": False, "body_parameters": True,
                                   "body": {"human": {"ansur": m}}}).create() for m in MEMBERS]
    assert made[1].share_programs(made[0])
    return made


@pytest.mark.parametrize("strategy", ["right_arm", "right_whole_body"])
def test_members_solved_joined_get_the_verdicts_each_gets_alone(strategy, monkeypatch):
    """Each member's verdicts and postures joined are those its own call gives (the postures to 1e-9 rad or m: a row's
    steps depend on its own posture and numbers alone, not on the batch's other rows), every reached posture passing
    that member's own Pinocchio check; and the joined calls ran fewer batches than the calls alone."""
    alone_oracles, joined_oracles = _oracles(strategy), _oracles(strategy)
    runs = []
    run = batch.Starts.run
    monkeypatch.setattr(batch.Starts, "run", lambda self: runs.append(len(self.x0)) or run(self))
    alone = [o.evaluate(Goals(GOALS)) for o in alone_oracles]
    count_alone = len(runs)
    joined = evaluate_together(joined_oracles, [Goals(GOALS), Goals(GOALS)])
    count_joined = len(runs) - count_alone
    assert 0 < count_joined < count_alone
    if strategy == "right_whole_body":  # the members' root heights differ: bounds by row
        lows = [o.problem.lower for o in joined_oracles]
        assert not np.array_equal(*lows)
    for a, j, oracle in zip(alone, joined, joined_oracles, strict=True):
        assert np.array_equal(a.reachable, j.reachable)
        assert 0 < np.sum(j.reachable) < len(GOALS)
        np.testing.assert_allclose(j.posture, a.posture, rtol=0, atol=1e-9)
        assert np.all(oracle.verify(GOALS[j.reachable], np.asarray(j.posture)[j.reachable]))


def test_an_oracle_that_cannot_join_is_asked_alone():
    """Oracles of another engine (damped least squares), or a single oracle, answer through their own evaluate."""
    spec = load_config(ROOT / "configs" / "population.yaml").strategy("right_arm").oracle
    dls = [OracleSpec("dls", {k: v for k, v in spec.params.items() if k in ("body", "effector", "joints", "tasks")}
                      | {"body": {"human": {"ansur": m}}}).create() for m in MEMBERS]
    together = evaluate_together(dls, [Goals(GOALS[:2]), Goals(GOALS[2:])])
    assert [len(v.reachable) for v in together] == [2, 5]
    for v, o, g in zip(together, dls, (GOALS[:2], GOALS[2:]), strict=True):
        assert np.array_equal(v.reachable, o.evaluate(Goals(g)).reachable)
