"""The selector (reach.answers.select): priorities, policies, refinement, errors, determinism, JSON answers."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from helpers import ARM, human_config

from oracles.bodies.body import human_body
from oracles.ik import waves
from reach.answers.answer import FAILED, REFINED, SKIPPED, UNAVAILABLE, Answer
from reach.answers.refine import SEEDS
from reach.answers.select import Selector
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.errors import InputError, ModelMismatch, UnknownEffector, UnknownPolicy
from reach.tools.cli import main


@pytest.fixture(scope="module")
def balls(nested_balls):
    # A small ball (priority 1) inside a large one (priority 2), both for the effector "point" (conftest.py).
    from reach.maps.atlas import load_atlas

    return load_atlas(nested_balls)


NATURAL_ARM = [{"name": "right_arm", "effector": "right_hand", "joints": ARM,
                "tasks": [{"type": "reach"}, {"type": "self_collision"}, {"type": "posture"}]}]


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    return build_atlas(parse_config(human_config(d_max=3, strategies=NATURAL_ARM), "arm", "arm"),
                       tmp_path_factory.mktemp("arm") / "arm")


def hand_of(answer, body) -> np.ndarray:
    """Independent forward kinematics of an answer's joint values."""
    q = body.q_ref.copy()
    q[:3], q[3:7] = answer.root["position"], answer.root["quaternion"]
    for name, value in answer.posture.items():
        q[body.model.joints[body.joint_id(name)].idx_q] = value
    return body.frame_positions(q, ["right_hand"])["right_hand"]


def test_first_strategy_by_priority_with_the_others_as_alternatives(balls):
    s = Selector(balls)
    inner, outer, none = s.select_many("point", np.array([[0.1, 0, 0], [0.7, 0, 0], [0.95, 0.95, 0]]))
    assert (inner.strategy, inner.alternatives) == ("near", ("far",))
    assert (outer.strategy, outer.alternatives) == ("far", ())
    assert none.strategy is None and not none.reachable and none.posture is None
    assert inner.refined == UNAVAILABLE and inner.residual is None  # analytic shapes store no postures


def test_single_goals_agree_with_the_batch(balls):
    goals = np.random.default_rng(1).uniform(-1, 1, (200, 3))
    s = Selector(balls)
    batch = s.select_many("point", goals)
    for g, b in zip(goals, batch, strict=True):
        one = s.select("point", g)
        assert (one.strategy, one.alternatives, one.reachable) == (b.strategy, b.alternatives, b.reachable)


def test_policies_are_nested(balls):
    goals = np.random.default_rng(2).uniform(-1, 1, (500, 3))
    reach = {p: np.array([a.reachable for a in Selector(balls, policy=p).select_many("point", goals)])
             for p in ("conservative", "vertex", "optimistic")}
    assert np.all(reach["conservative"] <= reach["vertex"]) and np.all(reach["vertex"] <= reach["optimistic"])


def test_errors_keep_their_fields(balls):
    s = Selector(balls)
    with pytest.raises(UnknownEffector, match="unknown effector 'hand'; this atlas has point") as err:
        s.select("hand", [0, 0, 0])
    assert err.value.name == "hand" and err.value.known == ["point"]
    with pytest.raises(InputError, match=r"goals: expected 3 coordinates \[m\] each, got shape \[1, 2\]") as bad:
        s.select("point", [0, 0])
    assert bad.value.field == "goals"
    with pytest.raises(UnknownPolicy, match="unknown policy 'maybe'"):
        Selector(balls, policy="maybe")  # type: ignore[arg-type]


def test_refined_postures_reach_the_exact_goal_under_independent_fk(arm):
    s = Selector(arm, budget=0.5).warm_up()
    body = human_body()
    goal = np.array([0.4, -0.3, 1.2])
    refined = s.select("right_hand", goal)
    stored = s.select("right_hand", goal, refine=False)
    assert refined.refined == REFINED and stored.refined == SKIPPED
    assert np.linalg.norm(hand_of(refined, body) - goal) <= 0.005 and refined.residual <= 0.005
    # The stored posture is the nearest reachable vertex's; its residual is the hand's true distance to the goal.
    assert abs(np.linalg.norm(hand_of(stored, body) - goal) - stored.residual) < 1e-9


def test_the_same_request_gives_the_same_answer(arm):
    goals = np.random.default_rng(3).uniform([0.1, -0.6, 0.8], [0.6, 0.0, 1.6], (6, 3))
    a = Selector(arm, budget=0.5).select_many("right_hand", goals)
    b = Selector(arm, budget=0.5).select_many("right_hand", goals)
    assert [x.to_dict() | {"seconds": 0} for x in a] == [y.to_dict() | {"seconds": 0} for y in b]


def test_answers_are_strict_json(arm):
    for answer in Selector(arm).select_many("right_hand", np.array([[0.4, -0.3, 1.2], [3.0, 0.0, 1.0]])):
        data = json.loads(answer.to_json(), parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
        assert data == json.loads(json.dumps(answer.to_dict()))


def test_a_tree_of_another_model_is_refused(arm):
    tree = arm.trees["right_arm"]
    saved = tree.meta["model_hash"]
    tree.meta["model_hash"] = "0123456789abcdef"
    try:
        with pytest.raises(ModelMismatch, match="was built for model 0123456789abcdef") as err:
            Selector(arm).warm_up()
        assert err.value.strategy == "right_arm" and err.value.current == saved
    finally:
        tree.meta["model_hash"] = saved


def test_a_tree_of_the_earlier_human_refines_with_that_body_and_says_so(arm):
    """A tree built before bodies came from ANSUR II measures (its human spec names no ``proportions``, its
    model hash is the stature-scaled body's) refines with the body it was built with, noted; the answer's posture puts
    that body's hand at the goal by Pinocchio's forward kinematics."""
    tree = arm.trees["right_arm"]
    old = human_body("male", percentile=50, proportions="de_leva")
    saved = tree.meta["model_hash"]
    tree.meta["model_hash"] = old.hash  # what the earlier version stored for {human: {sex: male, percentile: 50}}
    try:
        s = Selector(arm, budget=0.5)
        answer = s.select("right_hand", np.array([0.35, -0.3, 1.1]))
        assert answer.refined == REFINED and len(s.notes) == 1 and "proportions: de_leva" in s.notes[0]
        assert np.linalg.norm(hand_of(answer, old) - [0.35, -0.3, 1.1]) < 0.005
        tree.meta["model_hash"] = "0123456789abcdef"  # neither body's: refused
        with pytest.raises(ModelMismatch):
            Selector(arm).warm_up()
    finally:
        tree.meta["model_hash"] = saved


def test_answers_from_the_current_posture_are_continuous_along_a_line(arm):
    # Walk a line of goals 1 cm apart, each asked from the previous answer: no joint jumps.
    s = Selector(arm, budget=0.5)
    line = np.stack([np.linspace(0.25, 0.55, 31), np.full(31, -0.3), np.full(31, 1.2)], axis=1)
    previous = s.select("right_hand", line[0])
    worst = 0.0
    for goal in line[1:]:
        answer = s.select("right_hand", goal, start=previous.as_start())
        assert answer.refined == REFINED
        worst = max(worst, max(abs(answer.posture[k] - previous.posture[k]) for k in answer.posture))
        previous = answer
    assert np.degrees(worst) < 10.0


def test_the_same_request_from_a_posture_gives_the_same_answer(arm):
    s = Selector(arm, budget=0.5)
    start = {"right_shoulder_flexion": 0.6, "right_elbow_flexion": 0.8}
    a = s.select("right_hand", [0.4, -0.3, 1.2], start=start)
    b = Selector(arm, budget=0.5).select("right_hand", [0.4, -0.3, 1.2], start=start)
    assert a.posture == b.posture and a.refined == REFINED
    with pytest.raises(InputError, match=r"from: unknown joints \['right_tail'\]"):
        s.select("right_hand", [0.4, -0.3, 1.2], start={"right_tail": 1.0})


def test_a_strategy_whose_ik_misses_the_exact_goal_gives_way_to_the_next(tmp_path):
    # A coarse arm tree (optimistic policy: boundary cells hold) claims a goal
    # 10 cm beyond the arm's reach; its refinement fails, and the upper body,
    # next by priority, reaches it by leaning.
    upper = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*"]
    strategies = [{"name": "arm", "effector": "right_hand", "priority": 1, "joints": ARM,
                   "tasks": [{"type": "reach"}, {"type": "self_collision"}]},
                  {"name": "upper", "effector": "right_hand", "priority": 2, "joints": upper,
                   "tasks": [{"type": "reach"}, {"type": "self_collision"}]}]
    atlas = build_atlas(parse_config(human_config(d_max=2, strategies=strategies, name="coarse"), "coarse", "coarse"),
                        tmp_path / "coarse")
    body = human_body()
    shoulder = body.frame_positions(names=["right_shoulder"])["right_shoulder"]
    s = Selector(atlas, policy="optimistic", budget=2.0).warm_up()
    goal = shoulder + [0.75, 0.0, 0.0]
    stored = s.select("right_hand", goal, refine=False)
    assert stored.strategy == "arm" and stored.alternatives == ("upper",)  # what the trees say
    answer = s.select("right_hand", goal)
    assert answer.strategy == "upper" and answer.refined == REFINED and answer.alternatives == ()
    assert np.linalg.norm(hand_of(answer, body) - goal) <= 0.005
    # A goal the arm does reach keeps the arm.
    assert s.select("right_hand", shoulder + [0.45, 0.0, -0.1]).strategy == "arm"


def test_a_goal_no_refinement_reaches_is_never_a_bare_reachable(tmp_path, capsys):
    # The arm alone, coarse and optimistic: its tree holds a goal 10 cm beyond its reach, and no strategy is left.
    strategies = [{"name": "arm", "effector": "right_hand", "priority": 1, "joints": ARM,
                   "tasks": [{"type": "reach"}, {"type": "self_collision"}]}]
    atlas = build_atlas(parse_config(human_config(d_max=2, strategies=strategies, name="lone"), "lone", "lone"),
                        tmp_path / "lone")
    body = human_body()
    goal = body.frame_positions(names=["right_shoulder"])["right_shoulder"] + [0.75, 0.0, 0.0]
    s = Selector(atlas, policy="optimistic", budget=2.0).warm_up()
    stored = s.select("right_hand", goal, refine=False)
    # the tree's word, said how near
    assert stored.reachable and stored.refined == SKIPPED and stored.within == stored.residual > 0.005
    no = s.select("right_hand", goal)  # the default: unreachable, with the nearest point a stored posture reaches
    assert not no.reachable and no.strategy is None and no.refined == FAILED and no.posture is None
    near = no.nearest
    assert (near["strategy"] == "arm"
            and near["distance"] == pytest.approx(np.linalg.norm(np.array(near["point"]) - goal)))
    reached = hand_of(Answer("right_hand", tuple(goal), "arm", True, posture=near["posture"], root=near["root"]), body)
    assert np.linalg.norm(reached - near["point"]) < 1e-3  # independent FK: the posture reaches that point
    within = s.select("right_hand", goal, miss="within")
    assert (within.reachable and within.refined == FAILED and within.within == pytest.approx(near["distance"])
            and within.within > 0.005)
    assert np.linalg.norm(hand_of(within, body) - goal) == pytest.approx(within.within, abs=1e-6)
    reached_goal = s.select("right_hand", goal - [0.3, 0.0, 0.1])
    assert reached_goal.refined == REFINED and reached_goal.within is None  # solved at the goal: no `within`
    with pytest.raises(InputError, match="miss: expected one of unreachable, within"):
        s.select("right_hand", goal, miss="maybe")
    assert main(["query", str(tmp_path / "lone"), *map(str, goal), "--effector", "right_hand", "--policy",
                 "optimistic"]) == 0
    assert "not reachable: arm's tree holds it but no refinement reached it" in capsys.readouterr().out


@pytest.mark.slow
def test_a_strategy_at_its_joint_limits_hands_the_goal_to_the_next(tmp_path, capsys):
    # The upper body (pelvis fixed) reaches a goal low in front only by
    # pressing the shoulder down to the end of its range; the whole body
    # bends at the hips instead, clear of every limit (the paper's future
    # work, section 6: joint-level information drives the choice of strategy).
    upper = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*"]
    natural = [{"type": "reach"}, {"type": "self_collision"}, {"type": "posture"}]
    strategies = [
        {"name": "upper", "effector": "right_hand", "priority": 1, "joints": upper, "tasks": natural},
        {"name": "whole", "effector": "right_hand", "priority": 2, "joints": [*upper, "root", "*_hip_*", "*_ankle_*"],
         "tasks": [*natural, {"type": "feet", "heels": "down"}, {"type": "balance"}, {"type": "coupling"}]},
    ]
    atlas = build_atlas(parse_config(human_config(d_max=2, strategies=strategies, name="bend"), "bend", "bend"),
                        tmp_path / "bend")
    body = human_body()
    low, chest = [0.35, -0.2, 0.6], [0.35, -0.25, 1.1]
    plain = Selector(atlas, policy="optimistic", budget=2.0, handover=0.0).warm_up()
    first = plain.select("right_hand", low)
    assert first.strategy == "upper" and first.refined == REFINED  # the paper's plain priority
    strained = plain.oracle("upper").limits_near(body.configuration(first.posture, first.root), np.radians(5.0))
    assert strained  # the precondition: without it this test could not fail
    s = Selector(atlas, policy="optimistic", budget=2.0).warm_up()
    answer = s.select("right_hand", low)
    assert answer.strategy == "whole" and answer.alternatives == ("upper",) and answer.refined == REFINED
    assert answer.handover == {"from": "upper", "limits": strained} and first.handover is None
    assert json.loads(answer.to_json())["handover"] == {"from": "upper", "limits": strained}
    assert len(s.oracle("whole").limits_near(body.configuration(answer.posture, answer.root),
                                              np.radians(5.0))) < len(strained)
    assert np.linalg.norm(hand_of(answer, body) - low) <= 0.005
    assert s.select("right_hand", low).posture == answer.posture  # the same request, the same answer
    # A goal at chest height, which the upper body reaches clear of its limits, stays with it.
    assert s.select("right_hand", chest).strategy == "upper"
    with pytest.raises(InputError, match="handover"):
        Selector(atlas, handover=-1.0)
    # The command line says who handed the goal over, and --handover-deg 0 keeps the plain priority.
    query = ["query", str(tmp_path / "bend"), *map(str, low), "--effector", "right_hand", "--policy", "optimistic"]
    assert main(query) == 0
    out = capsys.readouterr().out
    assert "strategy whole" in out
    assert f"handed over by upper, whose posture came near these limits: {', '.join(strained)}" in out
    assert main([*query, "--handover-deg", "0"]) == 0
    out = capsys.readouterr().out
    assert "strategy upper" in out and "handed over" not in out
    assert (main([*query, "--handover-deg", "-5"]) == 2
            and "--handover-deg: expected 0 or more degrees" in capsys.readouterr().err)


def test_refinement_also_starts_from_the_best_liked_stored_posture_nearby(arm, monkeypatch):
    name, goal = "right_arm", np.array([0.45, -0.3, 1.2])
    tree = arm.trees[name]
    s = Selector(arm, budget=0.5)
    assert s.select("right_hand", goal).refined == REFINED  # builds the index and the oracle
    oracle = s.oracle(name)
    row = s.stored.nearest_row(name, goal.tolist())[0]  # the stored posture the answer starts from
    kd, rows = s.stored.lookup(name)[:2]  # type: ignore[index]
    _, near = kd.query(goal, k=SEEDS)
    postures = tree.vertices.posture
    saved = postures[row].copy()
    worse = saved.copy()
    worse[list(tree.vertices.posture_names).index("right_shoulder_abduction")] = 2.5  # the arm raised sideways
    postures[row] = worse
    try:
        best = s.refiner._best_liked(name, oracle, goal, worse)
        liked = {int(r): oracle.preference(postures[r], goal) for r in rows[near]}
        assert best is not None and oracle.preference(best, goal) == pytest.approx(min(liked.values()))
        # the nearest already the best liked: no extra start
        assert s.refiner._best_liked(name, oracle, goal, best) is None
        monkeypatch.setattr(type(oracle), "preference", lambda self, posture, goal: 0.0)  # an engine that cannot tell
        assert s.refiner._best_liked(name, oracle, goal, worse) is None
        monkeypatch.undo()
        seeded: list[tuple[int, ...]] = []
        real = type(oracle).evaluate
        monkeypatch.setattr(type(oracle), "evaluate", lambda self, goals: seeded.append(goals.seeds.shape)
                            or real(self, goals))
        answer = Selector(arm, budget=0.5).select("right_hand", goal)
        assert answer.refined == REFINED and seeded == [(1, 2, len(tree.vertices.posture_names))]
        assert np.linalg.norm(hand_of(answer, human_body()) - goal) <= 0.005
    finally:
        postures[row] = saved


def test_a_requests_orientation_is_scaled_before_it_is_normalised_and_bad_ones_name_the_field():
    """[1e200, 0, 0] overflowed to a zero direction (bad_request without workers, a worker's error with
    them); it is the x axis. A zero, infinite or NaN orientation is refused naming the field, in the loop."""
    from reach.answers.answer import orientation_of
    from reach.errors import InputError

    assert np.allclose(orientation_of({"direction": [1e200, 0, 0]}), [1, 0, 0])
    assert np.allclose(orientation_of({"quaternion": [0, 0, 0, 1e300]}), np.eye(3))
    for wire, field in (({"direction": [0, 0, 0]}, "orientation.direction"),
                        ({"direction": [float("inf"), 0, 0]}, "orientation.direction"),
                        ({"quaternion": [0, 0, 0, 0]}, "orientation.quaternion")):
        with pytest.raises(InputError) as info:
            orientation_of(wire)
        assert info.value.field == field


def test_a_from_root_quaternion_of_huge_components_is_refused_by_name():
    """root_qw = 1e300 overflowed where the quaternion is normalised (an `internal` reply)."""
    from reach.answers.start import check_start
    from reach.errors import InputError

    with pytest.raises(InputError, match="quaternion components must be within") as info:
        check_start({}, lambda name: None, [], {"root_qx": 0.0, "root_qy": 0.0, "root_qz": 0.0, "root_qw": 1e300})
    assert info.value.field == "from"


def test_a_refined_answer_does_not_depend_on_the_clock(tmp_path, monkeypatch):
    """The standard's "the same request, the same answer" under the server's 20 ms budget: the batched engine spends a
    budget of work (oracles.ik.budget.Meter), not of time. Cut by the clock, the same 30 demo goals asked twice on an
    idle machine gave 8 different arm postures. Here the same requests are answered again on a clock
    running ten times as fast, as a machine ten times as slow would see it (the clock's guard set aside): the answers
    are the same, goal by goal and in a batch. With a budget of time they would have had a tenth of their rounds; and
    the budget binds (a larger one answers some goals otherwise), so the test could fail."""
    config = human_config(d_max=3, strategies=NATURAL_ARM)
    config["oracle"] = {"name": "casadi-ik", "params": {"restarts": 1}}  # the batched engine, with its lower tasks
    atlas = build_atlas(parse_config(config, "arm", "arm"), tmp_path / "arm")
    goals = np.random.default_rng(5).uniform([0.1, -0.6, 0.8], [0.6, 0.0, 1.6], (8, 3))

    def answers(selector: Selector) -> list[dict]:
        one = [selector.select("right_hand", g).to_dict() | {"seconds": 0} for g in goals]
        return one + [a.to_dict() | {"seconds": 0} for a in selector.select_many("right_hand", goals)]

    first = answers(Selector(atlas).warm_up())
    assert sum(a["refined"] == REFINED for a in first) >= 8  # refined answers, whose rounds the budget counts
    ample = answers(Selector(atlas, budget=5.0).warm_up())
    assert any(a["posture"] != b["posture"] for a, b in zip(first, ample, strict=True))  # the budget binds
    monkeypatch.setattr(waves, "GUARD", 1e9)
    real = time.perf_counter
    monkeypatch.setattr(time, "perf_counter", lambda: 10.0 * real())
    assert answers(Selector(atlas).warm_up()) == first


def test_an_effector_named_by_another_frame_at_the_same_place_is_answered(arm):
    """The generated human's hand frame is also named ``right_grip`` (the README says so): a query for it is the
    ``right_hand`` query, with the same answer; a frame elsewhere on the hand (the thumb tip) stays unknown. (The
    fixture's fatrop counts its budget on the clock, README ``max_seconds``: at 2 s its solve ends by converging, so
    the two answers are the same beside other processes too; at 20 ms they differed once in four.)"""
    s = Selector(arm, budget=2.0)
    goal = np.array([0.45, -0.25, 1.2])
    a, b = s.select("right_grip", goal), s.select("right_hand", goal)
    assert a.reachable and a.strategy == b.strategy and a.posture == b.posture
    with pytest.raises(UnknownEffector, match="unknown effector 'right_pinch'; this atlas has right_hand"):
        s.select("right_pinch", goal)


def test_warming_up_one_effector_builds_its_strategies_alone(tmp_path, capsys):
    """A command about one effector (``reach motion``, ``reach prepare --effector``) builds that effector's solvers
    alone: a right hand's motion compiled the left side's programs too."""
    left = {**NATURAL_ARM[0], "name": "left_arm", "effector": "left_hand", "mirror_of": "right_arm",
            "joints": [j.replace("right_", "left_") for j in ARM]}
    arms = build_atlas(parse_config(human_config(d_max=2, strategies=[*NATURAL_ARM, left]), "arms", "arms"),
                       tmp_path / "arms")
    assert set(Selector(arms).warm_up("right_hand").oracles.built) == {"right_arm"}
    assert set(Selector(arms).warm_up().oracles.built) == {"right_arm", "left_arm"}
    assert main(["prepare", str(arms.path), "--effector", "left_hand"]) == 0
    assert "the refinement programs of 1 strategies ready (left_arm;" in capsys.readouterr().out
    assert main(["prepare", str(arms.path), "--effector", "nose"]) == 2
    assert "unknown effector 'nose'; this atlas has left_hand, right_hand" in capsys.readouterr().err


@pytest.mark.slow
def test_refined_answers_are_the_same_beside_two_cpu_bound_processes(tmp_path):
    """The same 50 refined requests get the same answers bit for bit, quiet and beside two CPU-bound processes: a
    refinement stops by the work it has done, not by the clock. The clock is a guard at 10 times the budget, which a
    budget of 2 s keeps out of reach here: at the server's 20 ms a whole-body refinement of this machine takes 37-83 ms
    quiet (the work is priced in a faster reference machine's seconds), and beside the two processes and the test run
    the guard was reached once in five runs; at 4 ms the answers differed."""
    import subprocess
    import sys

    whole = [{"name": "right_whole_body", "effector": "right_hand",
              "joints": [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "root", "*_hip_*", "*_ankle_*"],
              "tasks": [{"type": "reach"}, {"type": "feet", "heels": "down"}, {"type": "balance", "margin": 0.02},
                        {"type": "self_collision"}, {"type": "floor"}, {"type": "coupling"}, {"type": "posture"}]}]
    config = human_config(d_max=2, strategies=whole, name="whole")
    config["oracle"] = {"name": "casadi-ik", "params": {"restarts": 1, "seed": 0, "secondary": True}}  # batched
    atlas = build_atlas(parse_config(config, "whole", "whole"), tmp_path / "whole")
    rows, points, _ = atlas.maps["right_whole_body"].stored()
    rng = np.random.default_rng(0)
    goals = points[rng.choice(len(points), 50)] + rng.uniform(-0.05, 0.05, (50, 3))

    def answers() -> list[tuple]:
        selector = Selector(atlas, budget=2.0)
        return [(a.strategy, a.refined, a.residual, None if a.posture is None else tuple(a.posture.values()))
                for a in (selector.select("right_hand", g, True) for g in goals)]

    quiet = answers()
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        busy = answers()
    finally:
        for b in burners:
            b.kill()
            b.wait()
    assert busy == quiet
    assert sum(a[1] == REFINED for a in quiet) >= 25  # most of them refined: the answers compared are the solver's
