"""One program for every body of one shape: the body's numbers as the programs' parameters.

The truth is each body's own program, its numbers constants (the programs made for one body, as before): a program
built for another body and given this body's numbers must compute the same rows, Jacobians, objectives and
verdicts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from oracles.ik.oracle import NO_CALL
from oracles.ik.parameters import BodyParameters
from oracles.protocol import Goals, OracleSpec, Sharing

# Every task that can lift its numbers: the feet's contacts, the balance polygon and the pelvis, self-collision, the
# floor, coupling, the idle arm's hang, gaze and the posture's energy.
JOINTS = ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*", "right_clavicle_*", "lumbar_*",
          "thoracic_*", "neck_*", "root", "*_hip_*", "*_knee_*", "*_ankle_*", "left_shoulder_flexion",
          "left_shoulder_abduction", "left_elbow_flexion"]
TASKS = [{"type": "reach"}, {"type": "feet", "heels": "down"}, {"type": "balance", "margin": 0.02, "pelvis": 0.05},
         {"type": "self_collision"}, {"type": "floor"}, {"type": "coupling"}, {"type": "hang"},
         {"type": "gaze", "frame": "eyes"}, {"type": "posture"}]
SMALL = {"human": {"sex": "female", "percentile": 5}}
LARGE = {"human": {"sex": "male", "percentile": 95}}
# An ANSUR II subject whose upper-trunk capsule is a sphere where the percentile bodies' is a segment: another branch
# of the capsules' distance, which a lifted program must still compute.
SPHERE = {"human": {"ansur": {"sex": "male", "subject": 10586}}}
GOALS = np.array([[0.45, -0.20, 1.25], [0.85, -0.20, 1.00], [0.35, -0.15, 0.05], [0.30, -0.20, 2.15],
                  [0.05, -0.75, 1.20], [0.40, -0.20, 0.35], [1.30, -0.20, 1.00], [0.30, -0.20, 2.60]])


def oracle(body: dict, lift: bool, tasks: list | None = None):
    params = {"body": body, "effector": "right_hand", "joints": JOINTS, "tasks": tasks or TASKS, "restarts": 1,
              "seed": 0, "secondary": True, **({"body_parameters": True} if lift else {})}
    return OracleSpec("casadi-ik", params).create()


@pytest.fixture(scope="module")
def three():
    """The small body's lifted oracle; the large body's, sharing it; and the large body's own (constants)."""
    small, large, own = oracle(SMALL, True), oracle(LARGE, True), oracle(LARGE, False)
    assert isinstance(large, Sharing) and large.share_programs(small)
    return small, large, own


@pytest.fixture(scope="module")
def sphere(three):
    """The sphere-capsule subject's lifted oracle sharing the small body's programs, and its own (constants)."""
    lent, own = oracle(SPHERE, True), oracle(SPHERE, False)
    assert lent.share_programs(three[0])
    return three[0], lent, own


def test_a_shared_program_given_a_body_numbers_computes_what_its_own_program_does(three):
    same_rows(*three)


def test_a_capsule_that_is_a_sphere_at_one_body_and_a_segment_at_another_shares_the_program(sphere):
    small, lent, own = sphere
    mine, theirs = lent.solver.polish.formulation.numbers, small.solver.polish.formulation.numbers
    lengths = [float(mine.number(k)[0, 0]) for k in mine.names if k.startswith("task3.length2")]
    lengths_small = [float(theirs.number(k)[0, 0]) for k in theirs.names if k.startswith("task3.length2")]
    assert any(a == 0 and b > 0 for a, b in zip(lengths, lengths_small, strict=True))  # the case is there
    same_rows(small, lent, own)


def test_a_subject_whose_number_is_1_by_chance_shares_the_program(three):
    """ANSUR II man 11103's pelvis is 1.000 m high in the reference: a constant in a program of his own, a parameter
    in the one every other body shares (``BodyParameters.adopted``), computing what his own does."""
    small = three[0]
    chance = {"human": {"ansur": {"sex": "male", "subject": 11103}}}
    lent, own = oracle(chance, True), oracle(chance, False)
    assert lent.solver.polish.formulation.numbers.signature != small.solver.polish.formulation.numbers.signature
    assert lent.share_programs(small)
    same_rows(small, lent, own)


def same_rows(small, large, own):
    """The programs of ``large`` (lent by ``small``) against ``own`` (``large``'s body, constants) at random
    postures."""
    shared, mine = large.solver.batch_program(), own.solver.batch_program()
    assert shared._reach is small.solver.batch_program()._reach  # one program: the small body's, built once
    assert shared._reach is not mine._reach
    rng = np.random.default_rng(3)
    x = np.array([large.problem.random_x(rng) for _ in range(12)])
    x[:, :6] += rng.normal(0.0, 0.05, (12, 6))  # the root moved too
    base = np.concatenate([np.tile(GOALS[0], (12, 1)), x, np.zeros((12, 1)),
                           np.tile(large.solver.default_target, (12, 1))], axis=1)
    a = shared.evaluate(x, large.solver.with_body(base), lower=True)
    b = mine.evaluate(x, own.solver.with_body(base), lower=True)
    for name in ("g", "jg", "f", "grad", "hess", "lazy_violation"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-9, err_msg=name)
    np.testing.assert_array_equal(shared.rows.lower, mine.rows.lower)
    np.testing.assert_array_equal(shared.lazy_rows.lower, mine.lazy_rows.lower)
    np.testing.assert_array_equal(shared.lower_bound, own.problem.lower)  # the large body's bounds, not the small's
    objectives = large.solver.polish.programs.objectives, own.solver.polish.programs.objectives
    for f_shared, f_own in zip(*objectives, strict=True):
        for xi in x[:3]:
            assert float(f_shared(xi, large._params(GOALS[0], xi, NO_CALL))) == pytest.approx(
                float(f_own(xi, own._params(GOALS[0], xi, NO_CALL))), abs=1e-9)


def test_a_shared_program_answers_as_the_body_own_and_its_postures_pass_pinocchio(three):
    _, large, own = three
    a, b = large.evaluate(Goals.of(GOALS)), own.evaluate(Goals.of(GOALS))
    np.testing.assert_array_equal(a.reachable, b.reachable)
    assert 0 < a.reachable.sum() < len(GOALS)  # the goals tell something
    np.testing.assert_allclose(np.asarray(a.posture)[a.reachable], np.asarray(b.posture)[b.reachable], atol=1e-6)
    assert own.verify(GOALS[a.reachable], np.asarray(a.posture)[a.reachable]).all()  # the large body's own check


def test_programs_are_shared_only_by_bodies_and_strategies_of_one_shape():
    small = oracle(SMALL, True)
    assert not oracle(LARGE, False).share_programs(small)  # constants: its own programs
    fewer = oracle(LARGE, True, [t for t in TASKS if t["type"] != "gaze"])
    assert not fewer.share_programs(small)  # another strategy
    seated = oracle({"human": {"sex": "male", "percentile": 95, "posture": "seated"}}, True,
                    [{"type": "reach"}, {"type": "self_collision"}])
    assert not seated.share_programs(small)


def test_unlifted_numbers_are_constants_and_the_signature_ignores_lifted_values():
    a = BodyParameters({"p": np.array([0.1, 0.0, 1.0]), "R": np.eye(3)}, lift=False)
    assert a.symbols.numel() == 0 and a.sx("p").is_constant()
    b = BodyParameters({"p": np.array([0.3, 0.0, 1.0]), "R": np.eye(3)}, lift=True)
    c = BodyParameters({"p": np.array([0.2, 4e-17, 1.0]), "R": np.eye(3)}, lift=True)  # rounding: still a zero
    assert b.signature == c.signature == a.signature
    assert b.symbols.numel() == 1 and list(c.values) == [0.2]
    d = BodyParameters({"p": np.array([0.2, 0.1, 1.0]), "R": np.eye(3)}, lift=True)  # a zero became a number
    assert d.signature != b.signature
    fixed = BodyParameters({"q": np.array([0.3, 0.5])}, lift=True, fixed=frozenset({"q"}))
    assert fixed.symbols.numel() == 0 and fixed.sx("q").is_constant()


def test_a_number_trivial_by_chance_is_lifted_where_the_other_bodies_lift_it():
    """``adopted``: a body whose number is 1 where the others' is not takes their signature, that number a parameter;
    a body whose constant differs (a zero that is a number there) cannot."""
    typical = BodyParameters({"p": np.array([0.3, 0.0, 0.93]), "R": np.eye(3)}, lift=True)
    chance = BodyParameters({"p": np.array([0.2, 0.0, 1.0]), "R": np.eye(3)}, lift=True)
    assert chance.signature != typical.signature
    lent = chance.adopted(typical)
    assert lent is not None and lent.signature == typical.signature
    assert list(lent.values) == [0.2, 1.0] and lent.sx("p").shape == typical.sx("p").shape
    assert not lent.sx("p")[2].is_constant()
    assert typical.adopted(chance) is None  # 0.93 is no constant 1
    other = BodyParameters({"p": np.array([0.3, 0.1, 0.93]), "R": np.eye(3)}, lift=True)
    assert other.adopted(typical) is None  # a number where the typical body's is a constant zero
    assert typical.adopted(other) is not None  # ... the other way, a zero by chance: lifted
    assert BodyParameters({"p": np.array([0.3, 0.0, 0.93])}, lift=True).adopted(typical) is None  # other arrays


@pytest.mark.slow
def test_seated_drivers_share_their_belted_program():
    """The belt's length, the seat's boxes and the seated contacts are the body's too: a 5th-percentile woman's
    belted program, given a 95th-percentile man's numbers (each in a car seat fitted to them), is his own."""
    from reach.building.config import load_config

    config = load_config(Path(__file__).resolve().parents[1] / "configs" / "examples" / "driver.yaml")
    belted = next(s for s in config.strategies if s.name == "belted")

    def driver(sex, percentile, lift):
        body = {"human": {"sex": sex, "percentile": percentile, "posture": "seated", "seat": {"kind": "car"}}}
        return OracleSpec("casadi-ik", {**belted.oracle.params, "jit": False, "body": body,
                                        **({"body_parameters": True} if lift else {})}).create()

    small, large, own = driver("female", 5, True), driver("male", 95, True), driver("male", 95, False)
    assert large.solver.polish.formulation.numbers.lift and large.share_programs(small)
    same_rows(small, large, own)


def test_a_members_strategies_built_on_one_loaded_body_answer_as_each_built_alone():
    """``create_siblings``: the strategies after the first are built on its loaded body (not loaded again); each
    answers as the oracle its spec builds, and a strategy with ranges of its own (another body) is built from its
    spec."""
    from oracles.errors import OracleError
    from oracles.protocol import Sibling, create_siblings

    arm = {"body": SMALL, "effector": "right_hand", "tasks": [{"type": "reach"}, {"type": "self_collision"}],
           "joints": ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*"], "restarts": 1,
           "seed": 0}
    whole = {**arm, "joints": JOINTS, "tasks": TASKS}
    squat = {**whole, "ranges": {"*_knee_*": [0.0, 2.7]}}
    specs = [OracleSpec("casadi-ik", p) for p in (arm, whole, squat)]
    made, alone = create_siblings(specs), [s.create() for s in specs]
    assert isinstance(made[0], Sibling)
    assert made[1].body.model is made[0].body.model  # one loaded body
    assert made[2].body.model is not made[0].body.model  # its own ranges: its own body
    assert made[0].sibling(OracleSpec("sphere", {"radius": 1.0})) is None
    bad = OracleSpec("casadi-ik", {**arm, "colour": "red"})
    with pytest.raises(OracleError) as alone_error:
        bad.create()
    with pytest.raises(OracleError) as sibling_error:  # the error a spec's build gives
        create_siblings([specs[0], bad])
    assert str(sibling_error.value) == str(alone_error.value) and "colour" in str(alone_error.value)
    for mine, own in zip(made, alone, strict=True):
        assert mine.model_hash == own.model_hash
        a, b = mine.evaluate(Goals(GOALS[:4])), own.evaluate(Goals(GOALS[:4]))
        np.testing.assert_array_equal(a.reachable, b.reachable)
        np.testing.assert_array_equal(a.posture, b.posture)
