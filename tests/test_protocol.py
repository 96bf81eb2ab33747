"""The oracle protocol (oracles.protocol): a third-party oracle works everywhere a built-in one does.

The plug-in is an analytic two-link arm with postures (tests/helpers.py),
registered through the ``reach.oracles`` entry point. Its volume is a
spherical shell, so every answer has an exact truth.
"""

from __future__ import annotations

import threading
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest
from helpers import ARM, HUMAN, TwoLinkArm

from oracles import registry
from oracles.protocol import (
    Described,
    EffectorPositions,
    Mirrorable,
    ModelHashed,
    OracleSpec,
    Preparable,
    ReachBound,
    Specified,
    Tunable,
    Verdicts,
    Verifying,
    check_verdicts,
)
from reach.answers.answer import REFINED
from reach.answers.audit import audit
from reach.answers.select import Selector
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.errors import OracleError
from reach.maps.tree import INNER
from reach.serving.client import Client
from reach.serving.server import Server

SHOULDER = np.array([0.0, 0.0, 1.0])
UPPER, FORE = 0.3, 0.25


@pytest.fixture
def plugin(monkeypatch):
    ep = EntryPoint(name="two-link-arm", value="helpers:two_link_arm", group=registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(registry, "entry_points", lambda group: [ep] if group == registry.ENTRY_POINT_GROUP else [])


@pytest.fixture
def arm_atlas(plugin, tmp_path):
    config = parse_config({
        "name": "plugin", "box": "auto" if False else {"min": [-0.6, -0.6, 0.4], "max": [0.6, 0.6, 1.6]},
        "depth": {"min": 2, "max": 5}, "oracle": {"name": "two-link-arm", "params": {"upper": UPPER, "fore": FORE}},
        "strategies": [{"name": "arm", "effector": "hand"}],
    }, "plugin", "plugin")
    return build_atlas(config, tmp_path / "plugin")


def shell(points: np.ndarray) -> np.ndarray:
    r = np.linalg.norm(points - SHOULDER, axis=1)
    return (r >= UPPER - FORE) & (r <= UPPER + FORE)


def test_the_plugin_declares_the_optional_capabilities(plugin):
    arm = OracleSpec("two-link-arm", {}).create()
    for capability in (Specified, EffectorPositions, ReachBound, Tunable):
        assert isinstance(arm, capability), capability.__name__
    assert not isinstance(arm, ModelHashed) and not isinstance(arm, Mirrorable)


def test_builtin_body_oracles_declare_every_capability():
    oracle = OracleSpec("casadi-ik", {"body": HUMAN, "effector": "right_hand", "joints": ARM}).create()
    for capability in (Specified, ModelHashed, EffectorPositions, ReachBound, Tunable, Preparable, Mirrorable,
                       Described, Verifying):
        assert isinstance(oracle, capability), capability.__name__
    refine = oracle.variant("refine", budget=0.01)
    assert refine.spec.params["max_seconds"] == 0.01 and refine.spec.params["jit"] is False
    referee = oracle.variant("referee", restarts=9)
    assert referee.spec.params["restarts"] == 9 and referee.spec.params["solver"] == "ipopt"
    with pytest.raises(OracleError, match="unknown oracle purpose 'fast'"):
        oracle.variant("fast")  # type: ignore[arg-type]
    built, polish = oracle.solver.polish, refine.solver.polish
    assert not built.programs.stages and not polish.programs.stages  # none of this built a solver
    # A variant shares the body, the problem and the program cache; only the search and engine options differ.
    assert refine.body is oracle.body and refine.problem is oracle.problem and polish._cache is built._cache
    assert oracle.search.max_seconds is None and oracle.spec.params["jit"] is False  # the original is untouched


def test_a_plugin_tree_matches_its_exact_shell(arm_atlas):
    tree = arm_atlas.trees["arm"]
    v = tree.vertices
    pts = tree.lattice.points(tree.lattice.coords(v.keys))
    assert np.array_equal(v.reachable, shell(pts))
    assert v.posture is not None and v.posture.shape == (len(v), 3)
    exact = 4 / 3 * np.pi * ((UPPER + FORE) ** 3 - (UPPER - FORE) ** 3)
    assert tree.volume(INNER) <= exact <= tree.volume(INNER) + tree.volume(3)


def test_a_plugin_answers_with_postures_that_reach(arm_atlas):
    selector = Selector(arm_atlas).warm_up()
    goals = SHOULDER + np.array([[0.3, 0.1, 0.0], [0.0, -0.2, 0.3], [0.05, 0.0, 0.0], [0.6, 0.0, 0.0]])
    answers = selector.select_many("hand", goals)
    assert [a.reachable for a in answers] == [True, True, False, False]
    arm = TwoLinkArm(UPPER, FORE)
    for a, g in zip(answers[:2], goals[:2], strict=True):
        assert a.refined == REFINED and a.residual <= 1e-6
        q = np.array([a.posture[n] for n in TwoLinkArm.posture_names])
        assert np.linalg.norm(arm.effector_positions(q[None])[0] - g) <= 1e-6  # independent forward kinematics
    assert selector.oracle("arm").refining  # the refine variant answered


def test_a_plugin_is_audited_exactly(arm_atlas):
    result = audit(arm_atlas, samples=300)["strategies"]["arm"]
    assert result["probes"] == 300
    # The plugin's referee is exact: every error is a boundary cell's, and the inner cells never lie.
    assert result["by_type"]["inner"]["false_reachable"]["errors"] == 0
    assert result["by_type"]["outer"]["false_unreachable"]["errors"] == 0


def test_a_plugin_is_served(arm_atlas):
    server = Server(arm_atlas.path, "tcp://127.0.0.1:*", None)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        with Client(server.endpoint, timeout=5000) as client:
            reply = client.query("hand", (SHOULDER + [0.3, 0.1, 0.0]).tolist())
        assert reply["reachable"] and reply["strategy"] == "arm" and set(reply["posture"]) == {"yaw", "pitch", "elbow"}
        assert reply["refined"] == REFINED
    finally:
        server.stop()
        thread.join(timeout=5)


def test_a_thousand_refined_goals_across_four_strategies_cost_a_few_evaluate_calls_each(plugin, tmp_path, monkeypatch):
    """The selector refines a batch's goals in one evaluate call per strategy and pass (first
    choice, then fallback), not one per goal; the answers are those of one goal at a time, and every reachable
    one is reached by the arm's own forward kinematics."""
    shoulders = [[0.0, 0.0, 1.0], [0.0, 0.35, 1.0], [0.0, -0.35, 1.0], [0.3, 0.0, 1.2]]
    config = parse_config({
        "name": "four", "box": {"min": [-0.6, -0.9, 0.4], "max": [0.9, 0.9, 1.8]}, "depth": {"min": 2, "max": 4},
        "oracle": {"name": "two-link-arm", "params": {"upper": UPPER, "fore": FORE}},
        "strategies": [{"name": f"arm{k}", "effector": "hand", "priority": k,
                        "oracle": {"name": "two-link-arm", "params": {"upper": UPPER, "fore": FORE, "shoulder": s}}}
                       for k, s in enumerate(shoulders)],
    }, "four", "four")
    atlas = build_atlas(config, tmp_path / "four")
    goals = np.random.default_rng(3).uniform([-0.6, -0.9, 0.4], [0.9, 0.9, 1.8], (1000, 3))
    selector = Selector(atlas).warm_up()
    calls: list[tuple[float, ...]] = []
    real = TwoLinkArm.evaluate
    monkeypatch.setattr(TwoLinkArm, "evaluate", lambda self, g: calls.append(tuple(self.shoulder)) or real(self, g))
    answers = selector.select_many("hand", goals)
    refined = [a for a in answers if a.refined == REFINED]
    assert len(refined) >= 300  # the four shells hold hundreds of these goals
    per_strategy = {k: calls.count(tuple(map(float, s))) for k, s in enumerate(shoulders)}
    assert sum(per_strategy.values()) == len(calls) and max(per_strategy.values()) <= 4, per_strategy
    for a, g in zip(answers, goals, strict=True):
        if a.reachable:
            k = int(a.strategy[3:])
            q = np.array([a.posture[n] for n in TwoLinkArm.posture_names])
            assert np.linalg.norm(TwoLinkArm(UPPER, FORE,
                                             tuple(shoulders[k])).effector_positions(q[None])[0] - g) <= 1e-6
    calls.clear()
    # one goal at a time: the same answers, a call per refinement
    for a, g in zip(answers[:60], goals[:60], strict=True):
        one = selector.select("hand", g)
        assert (one.strategy, one.reachable, one.refined) == (a.strategy, a.reachable, a.refined)
    assert len(calls) >= sum(a.refined == REFINED for a in answers[:60])


def test_box_auto_uses_the_plugins_reach_bound(plugin):
    config = parse_config({
        "box": "auto", "depth": {"min": 1, "max": 2}, "oracle": {"name": "two-link-arm", "params": {}},
        "strategies": [{"name": "arm", "effector": "hand"}],
    })
    assert np.allclose(config.box.lo, SHOULDER - (UPPER + FORE) - 0.05) or config.box.lo[2] == 0.0
    assert np.allclose(config.box.hi, SHOULDER + UPPER + FORE + 0.05)


def test_check_verdicts_names_the_shapes():
    with pytest.raises(OracleError, match="declares 2 posture names but returned no postures"):
        check_verdicts(Verdicts(np.ones(3, bool), np.zeros(3), None), 3, 2)
    with pytest.raises(OracleError, match=r"returned postures \(3, 1\), expected \(3, 2\)"):
        check_verdicts(Verdicts(np.ones(3, bool), np.zeros(3), np.zeros((3, 1))), 3, 2)


def test_the_document_holds_the_table_of_operations():
    from reach.serving import protocol as P

    doc = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text()
    start = doc.index("<!-- operations: generated by `python -m reach.serving.protocol` -->\n")
    block = doc[doc.index("\n", start) + 1 : doc.index("\n<!-- end operations -->")]
    assert block == P.operations_table()
    from reach.serving.handlers import HANDLERS, Handler

    for op in P.OPERATIONS.values():  # each operation also has its own section, and a handler that answers it
        assert f"### `{op.name}`" in doc
        handler = HANDLERS[op.name]
        assert isinstance(handler, Handler) and type(handler).answer is not Handler.answer, op.name
        # an operation the workers answer is handed over, and answered from their frames
        assert not op.worker or type(handler).finish is not Handler.finish, op.name
    assert set(HANDLERS) == set(P.OPERATIONS)


def test_every_declared_field_is_checked_and_named_in_the_error():
    from reach.errors import ProtocolError
    from reach.serving import protocol as P

    ok = P.parse_request(b'{"op": "cells", "id": 1}')
    assert ok.args == {"strategy": None, "level": 4} and ok.id == 1
    q = P.parse_request(b'{"op": "query", "effector": "right_hand", "goal": [0.4, 0.2, 1.0]}')
    assert q["single"] and q["goals"] == [[0.4, 0.2, 1.0]] and q["from"] is None
    for payload, field in ((b'{"op": "cells", "level": 9}', "level"),
                           (b'{"op": "query", "goal": [0, 0, 0]}', "effector"),
                           (b'{"op": "query", "effector": "h", "goal": [1, 2, 3, 4]}', "goal"),
                           (b'{"op": "query", "effector": "h", "goals": [[1, 2, 3], [1, 2]]}', "goals"),
                           (b'{"op": "query", "effector": "h", "goal": [1, 2, 3], "deadline": 0}', "deadline"),
                           (b'{"op": "hello", "tag": ""}', "tag")):
        with pytest.raises(ProtocolError, match=f"^'{field}' ") as err:
            P.parse_request(payload)
        assert err.value.code == P.BAD_REQUEST
