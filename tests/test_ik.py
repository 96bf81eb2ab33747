"""IK oracles: verdicts checked by independent forward kinematics, known points, priorities."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from helpers import ARM

from oracles.ik.oracle import Call, IKOracle
from oracles.ik.rounds import NO_CALL, starts
from oracles.ik.search import Search
from oracles.ik.solvers import SOLVERS
from oracles.ik.solvers.interior import InteriorPoint
from oracles.ik.solvers.single import SingleSolver
from oracles.protocol import Goals, OracleSpec
from reach.building.config import load_config
from reach.errors import ModelError, OracleError

ROOT = Path(__file__).resolve().parents[1]
HUMAN = {"human": {"sex": "male", "percentile": 50}}
UPPER = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "neck_*"]
WHOLE = [*UPPER, "root", "*_hip_*", "*_ankle_*"]
CROUCH = [*WHOLE, "*_knee_*"]
PLANTED = [{"type": "reach"}, {"type": "feet", "heels": "down"}, {"type": "balance", "margin": 0.02}]


@pytest.fixture(scope="module")
def arm():
    return IKOracle(HUMAN, "right_hand", ARM, search=Search(restarts=2))


@pytest.fixture(scope="module")
def whole():
    return IKOracle(HUMAN, "right_hand", WHOLE, PLANTED, search=Search(restarts=1))


@pytest.fixture(scope="module")
def crouch():
    return IKOracle(HUMAN, "right_hand", CROUCH, PLANTED, search=Search(restarts=1))


def _independent_fk(oracle, q: np.ndarray) -> dict[str, np.ndarray]:
    """Pinocchio forward kinematics, without any of the oracle's machinery."""
    model = oracle.body.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return {str(f.name): data.oMf[i].translation.copy() for i, f in enumerate(model.frames)}, pin.centerOfMass(model,
        data, q)


def _assert_reachable_verdicts_hold(oracle, points, verdicts):
    model, ref = oracle.body.model, oracle.body.q_ref
    frames_ref, _ = _independent_fk(oracle, ref)
    for goal, ok, q in zip(points, verdicts.reachable, verdicts.posture, strict=True):
        if not ok:
            continue
        frames, com = _independent_fk(oracle, q)
        assert np.linalg.norm(frames[oracle.strategy.effector] - goal) <= 0.005
        assert (np.all(q[7:] >= model.lowerPositionLimit[7:] - 1e-6)
                and np.all(q[7:] <= model.upperPositionLimit[7:] + 1e-6))
        for held in oracle.strategy.held_frames:
            assert np.linalg.norm(frames[held] - frames_ref[held]) <= 1e-4
        balance = oracle.strategy.task("balance")
        if balance is not None:
            assert np.all(balance.polygon[:, :2] @ com[:2] + balance.polygon[:, 2] <= 1e-5)


def test_every_reachable_arm_verdict_holds_under_independent_fk(arm):
    pts = np.random.default_rng(0).uniform([-0.4, -0.9, 0.6], [0.8, 0.4, 2.1], (40, 3))
    v = arm.evaluate(pts)
    assert 5 < v.reachable.sum() < 40
    _assert_reachable_verdicts_hold(arm, pts, v)
    # and unreachable ones are honestly far: their best attempt misses by more than the tolerance
    assert np.all(v.residual[~v.reachable] > 0.005)


def test_whole_body_postures_keep_feet_balance_and_limits(whole):
    pts = np.random.default_rng(1).uniform([-0.3, -0.8, 0.2], [0.9, 0.3, 2.0], (12, 3))
    v = whole.evaluate(pts)
    assert v.reachable.sum() >= 4
    _assert_reachable_verdicts_hold(whole, pts, v)


def test_known_points_for_the_arm(arm):
    v = arm.evaluate(np.array([
        [0.45, -0.2, 1.25],   # in front at chest height
        [0.0, -0.2, 2.5],     # 2.5 m up
        # behind the back, above the shoulder: over the head (fatrop and IPOPT with 8 restarts reach it too)
        [-0.4, -0.4, 1.46],
        [-0.2, 0.4, 1.46],    # behind the left shoulder
        [0.35, -0.15, 0.05],  # the floor in front of the feet
    ]))
    assert v.reachable.tolist() == [True, False, True, False, False]
    _assert_reachable_verdicts_hold(arm, np.array([[0.45, -0.2, 1.25], [-0.4, -0.4, 1.46]]),
                                    type(v)(v.reachable[[0, 2]], v.residual[[0, 2]], v.posture[[0, 2]]))


def test_floor_in_front_needs_crouch_not_arm(arm, crouch):
    floor = np.array([[0.35, -0.15, 0.05]])
    assert not arm.evaluate(floor).reachable[0]
    v = crouch.evaluate(floor)
    assert v.reachable[0]
    _assert_reachable_verdicts_hold(crouch, floor, v)


def test_prefilter_skips_the_solver_for_far_goals(arm):
    before = dict(arm.stats)
    v = arm.evaluate(np.array([[3.0, 0.0, 1.0]]))
    assert not v.reachable[0] and v.residual[0] > 2.0
    assert arm.stats["solves"] == before["solves"] and arm.stats["prefiltered"] == before["prefiltered"] + 1


def test_warm_start_hint_needs_one_solve():
    # fatrop's search: one start at a time, the next only when it fails (the batched engine runs all K together).
    arm = IKOracle(HUMAN, "right_hand", ARM, solver="fatrop", search=Search(restarts=2))
    goal = np.array([[0.4, -0.3, 1.1]])
    first = arm.evaluate(goal)
    before = arm.stats["solves"]
    again = arm.evaluate(Goals(goal + 0.01, seeds=first.posture))
    assert again.reachable[0] and arm.stats["solves"] == before + 1


def test_determinism():
    pts = np.random.default_rng(2).uniform([-0.2, -0.8, 0.8], [0.7, 0.2, 1.9], (8, 3))
    a = IKOracle(HUMAN, "right_hand", ARM, search=Search(seed=7)).evaluate(pts)
    b = IKOracle(HUMAN, "right_hand", ARM, search=Search(seed=7)).evaluate(pts)
    assert np.array_equal(a.reachable, b.reachable) and np.array_equal(a.posture, b.posture)


def test_gaze_aims_the_eyes_without_degrading_reach():
    goal = np.array([[0.5, -0.3, 1.0]])
    plain = IKOracle(HUMAN, "right_hand", UPPER, [{"type": "reach"}]).evaluate(goal)
    gazing = IKOracle(HUMAN, "right_hand", UPPER,
                      [{"type": "reach"}, {"type": "gaze", "frame": "eyes"}, {"type": "comfort"}])
    v = gazing.evaluate(goal)
    assert plain.reachable[0] and v.reachable[0]
    model = gazing.body.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, v.posture[0])
    eye = data.oMf[model.getFrameId("eyes")]
    to_goal = (goal[0] - eye.translation) / np.linalg.norm(goal[0] - eye.translation)
    # The line of sight rests 15 deg below the eyes' x axis (gaze's down; z up, so a turn about y).
    down = pin.utils.rotate("y", np.radians(15.0)) @ np.array([1.0, 0.0, 0.0])
    # the eyes turn the last 15 deg
    assert np.degrees(np.arccos(np.clip((eye.rotation @ down) @ to_goal, -1, 1))) < 15.0 + 2.0
    exact = IKOracle(HUMAN, "right_hand", UPPER,
                     [{"type": "reach"}, {"type": "gaze", "frame": "eyes", "cone": 0}, {"type": "comfort"}])
    w = exact.evaluate(goal)
    pin.framesForwardKinematics(model, data, w.posture[0])
    eye = data.oMf[model.getFrameId("eyes")]
    to_goal = (goal[0] - eye.translation) / np.linalg.norm(goal[0] - eye.translation)
    # cone 0: the line of sight aims
    assert np.degrees(np.arccos(np.clip((eye.rotation @ down) @ to_goal, -1, 1))) < 2.0
    level = IKOracle(HUMAN, "right_hand", UPPER,
                     [{"type": "reach"}, {"type": "gaze", "frame": "eyes", "cone": 0, "down": 0}, {"type": "comfort"}])
    pin.framesForwardKinematics(model, data, level.evaluate(goal).posture[0])
    eye = data.oMf[model.getFrameId("eyes")]
    to_goal = (goal[0] - eye.translation) / np.linalg.norm(goal[0] - eye.translation)
    assert np.degrees(np.arccos(np.clip(eye.rotation[:, 0] @ to_goal, -1, 1))) < 2.0  # down 0: the eyes' x axis itself
    # The reach task kept its verdict: lower stages may trade at most half the tolerance (ReachTask.held_bounds).
    assert v.residual[0] <= 0.5 * 0.005 + 1e-9


def test_dls_agrees_with_casadi_and_holds_under_fk():
    pts = np.random.default_rng(3).uniform([-0.4, -0.9, 0.6], [0.8, 0.4, 2.1], (40, 3))
    c = IKOracle(HUMAN, "right_hand", UPPER, [{"type": "reach"}], search=Search(restarts=2))
    d = IKOracle(HUMAN, "right_hand", UPPER, [{"type": "reach"}], search=Search(restarts=2), solver="dls")
    vc, vd = c.evaluate(pts), d.evaluate(pts)
    _assert_reachable_verdicts_hold(d, pts, vd)
    assert np.mean(vc.reachable == vd.reachable) >= 0.95


def test_ik_on_a_urdf_robot():
    body = {"urdf": str(ROOT / "configs" / "urdf" / "ur5.urdf")}
    oracle = IKOracle(body, "ee_link", ["*_joint"], search=Search(restarts=2))
    pts = np.array([[0.4, 0.2, 0.3], [0.0, 0.5, 0.6], [2.0, 0.0, 0.0]])
    v = oracle.evaluate(pts)
    assert v.reachable.tolist() == [True, True, False]
    _assert_reachable_verdicts_hold(oracle, pts, v)


def test_shipped_human_strategies_load():
    config = load_config(ROOT / "configs" / "human.yaml")
    names = {s.name for s in config.strategies}
    for side in ("right", "left"):
        assert {f"{side}_arm", f"{side}_upper_body", f"{side}_whole_body", f"{side}_crouch", f"{side}_tiptoe"} <= names
    assert "right_foot" in names


@pytest.mark.parametrize(
    ("joints", "tasks", "message"),
    [
        (["right_tail_*"], None, "no joint matches 'right_tail_\\*'"),
        (ARM, [{"type": "gaze"}], "needs a reach task"),
        (ARM, [{"type": "reach"}, {"type": "dance"}], r"tasks\[1\]: expected a mapping with type"),
        (ARM, [{"type": "reach", "speed": 2}], r"tasks\[0\]: unknown keys \['speed'\]"),
        (ARM, [{"type": "reach"}, {"type": "feet", "heels": "up"}], r"tasks\[1\]\.heels: expected 'down' or 'rise'"),
        (ARM, [{"type": "reach"}, {"type": "balance"}], "balance needs a support polygon"),
    ],
)
def test_strategy_errors_name_the_task(joints, tasks, message):
    with pytest.raises(ModelError, match=message):
        IKOracle(HUMAN, "right_hand", joints, tasks)


def test_unknown_effector_lists_frames():
    with pytest.raises(ModelError, match="no frame 'right_claw'"):
        OracleSpec("casadi-ik", {"body": HUMAN, "effector": "right_claw", "joints": ARM}).create()


def test_contacts_are_kept_only_where_an_active_joint_can_move_them():
    from oracles.bodies.body import human_body
    from oracles.ik.strategy import parse_strategy

    body = human_body()
    feet = [{"type": "reach"}, {"type": "feet", "heels": "down"}]
    legs = parse_strategy(body, "right_hand", [*ARM, "right_hip_*", "right_knee_*"], feet)
    assert legs.held_frames == ("right_foot",)  # the left foot cannot move: no constraint needed
    floating = parse_strategy(body, "right_hand", WHOLE, feet)
    assert floating.held_frames == ("right_foot", "left_foot")
    assert parse_strategy(body, "right_hand", ARM, feet).held_frames == ()


def test_give_up_skips_restarts_after_a_decisive_warm_solve():
    # Behind and across the body at shoulder height the arm's joint limits
    # end the volume about 0.3 m left of the shoulder; this goal is beyond.
    thorough = IKOracle(HUMAN, "right_hand", ARM, solver="fatrop", search=Search(restarts=2, give_up=None))
    # gives up after any failed decisive warm start (give_up 0; the default, 0.1, keeps the starts of a hint that ends
    # within 10 cm)
    hasty = IKOracle(HUMAN, "right_hand", ARM, solver="fatrop", search=Search(restarts=2, give_up=0.0))
    goal = (thorough.problem.anchor + [-0.1, 0.38, 0.0])[None]
    assert thorough.problem.prefilter(goal[0]) == 0.0  # the solver, not the pre-filter, decides
    best = thorough.evaluate(goal)
    assert not best.reachable[0] and best.residual[0] > 0.01
    assert thorough.stats["solves"] == 3  # reference and two restarts
    hint = best.posture  # its effector is within NEAR_HINT of the goal: a decisive warm start
    warm = hasty.evaluate(Goals(goal, seeds=hint))
    assert not warm.reachable[0] and hasty.stats["solves"] == 1
    thorough.evaluate(Goals(goal, seeds=hint))
    assert thorough.stats["solves"] == 3 + 4  # the hint, then every other start


def test_give_up_never_cuts_cold_starts_short():
    # From the reference posture this goal's first solve ends about 0.3 m
    # away; a random restart reaches it.
    hasty = IKOracle(HUMAN, "right_hand", ARM, search=Search(restarts=2))
    goal = (hasty.problem.anchor + [-0.2, 0.3, 0.3])[None]
    v = hasty.evaluate(goal)
    assert v.reachable[0] and hasty.stats["solves"] >= 2
    _assert_reachable_verdicts_hold(hasty, goal, v)


def test_fatrop_and_ipopt_agree_on_whole_body_verdicts():
    goals = np.random.default_rng(5).uniform([-0.8, -1.2, 0.0], [1.2, 0.6, 2.4], (16, 3))
    fatrop = IKOracle(HUMAN, "right_hand", WHOLE, PLANTED, solver="fatrop", search=Search(restarts=1)).evaluate(goals)
    ipopt = IKOracle(HUMAN, "right_hand", WHOLE, PLANTED, solver="ipopt", search=Search(restarts=1)).evaluate(goals)
    assert 4 <= fatrop.reachable.sum() <= 12  # a mix of both verdicts
    assert np.sum(fatrop.reachable != ipopt.reachable) <= 1


def test_unknown_solver_is_refused():
    with pytest.raises(OracleError, match="solver must be one of"):
        IKOracle(HUMAN, "right_hand", ARM, solver="snopt")


@pytest.mark.skipif(shutil.which("gcc") is None and not os.environ.get("CI"), reason="no gcc here (CI installs it)")
def test_jit_compiles_the_same_problem():
    goals = np.random.default_rng(6).uniform([-0.4, -1.0, 0.6], [0.9, 0.4, 2.1], (12, 3))
    compiled = IKOracle(HUMAN, "right_hand", UPPER, [{"type": "reach"}], jit=True)
    interpreted = IKOracle(HUMAN, "right_hand", UPPER, [{"type": "reach"}], jit=False)
    assert compiled.solver.jit and not interpreted.solver.jit
    a, b = compiled.evaluate(goals), interpreted.evaluate(goals)
    assert 3 <= a.reachable.sum() <= 10 and np.array_equal(a.reachable, b.reachable)
    _assert_reachable_verdicts_hold(compiled, goals, a)


@pytest.mark.skipif(shutil.which("gcc") is None and not os.environ.get("CI"), reason="no gcc here (CI installs it)")
def test_compiled_programs_are_cached_on_disk_and_shared(tmp_path, monkeypatch):
    monkeypatch.setenv("REACH_JIT_CACHE", str(tmp_path / "jit"))
    goals = np.array([[0.4, -0.3, 1.1], [0.2, -0.45, 1.0], [1.5, 0.0, 1.0]])
    first = IKOracle(HUMAN, "right_hand", ARM, [{"type": "reach"}, {"type": "posture"}], jit=True, solver="fatrop")
    a = first.evaluate(goals)
    libraries = sorted((tmp_path / "jit").glob("*.so"))
    assert len(libraries) == 2  # one per stage: reach, posture
    stamps = [lib.stat().st_mtime_ns for lib in libraries]
    second = IKOracle(HUMAN, "right_hand", ARM, [{"type": "reach"}, {"type": "posture"}], jit=True, solver="fatrop")
    b = second.evaluate(goals)
    assert (sorted((tmp_path / "jit").glob("*.so")) == libraries
            and [lib.stat().st_mtime_ns for lib in libraries] == stamps)
    assert np.array_equal(a.reachable, b.reachable) and np.array_equal(a.posture, b.posture)
    assert a.reachable.tolist() == [True, True, False]


def test_a_cached_program_is_loaded_without_writing_its_c_again(tmp_path, monkeypatch):
    """The cache was keyed by the hash of the generated C, so every process wrote every program's C
    (3.2 s of a fresh `reach query`'s 7 s) to find its library. Now the key is the expression graph's."""
    import casadi as ca

    from oracles.ik import jit

    monkeypatch.setenv("REACH_JIT_CACHE", str(tmp_path / "jit"))
    x = ca.SX.sym("x", 3)
    first = jit.compiled_functions([ca.Function("square", [x], [x * x])])[0]
    assert first(np.array([1.0, 2.0, 3.0])).full().ravel().tolist() == [1.0, 4.0, 9.0]

    def no_c(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise AssertionError("C written again")

    monkeypatch.setattr(ca.Function, "generate", no_c)
    monkeypatch.setattr(ca.Function, "generate_dependencies", no_c)
    again = jit.compiled_functions([ca.Function("square", [x], [x * x])])[0]  # rebuilt alike: the same graph
    assert again(np.array([2.0, 0.5, -1.0])).full().ravel().tolist() == [4.0, 0.25, 1.0]
    assert len(list((tmp_path / "jit").glob("*.so"))) == 1


def test_a_failing_compiler_falls_back_to_the_interpreter(tmp_path, monkeypatch):
    monkeypatch.setenv("REACH_JIT_CACHE", str(tmp_path / "jit"))
    monkeypatch.setattr("oracles.ik.jit.COMPILER", "false")  # runs, and fails
    oracle = IKOracle(HUMAN, "right_hand", ARM, jit="auto")
    with pytest.warns(UserWarning, match="jit compilation failed"):
        assert oracle.evaluate(np.array([[0.4, -0.3, 1.1]])).reachable[0]
    assert not oracle.solver.jit
    with pytest.raises(OracleError, match="jit compilation with"):
        IKOracle(HUMAN, "right_hand", ARM, jit=True).prepare()


def test_jit_without_a_compiler(monkeypatch):
    monkeypatch.setattr("oracles.ik.solvers.interior.COMPILER", "no-such-compiler")
    assert not IKOracle(HUMAN, "right_hand", ARM, jit="auto").solver.jit  # falls back to the interpreter
    with pytest.raises(OracleError, match="jit"):
        IKOracle(HUMAN, "right_hand", ARM, jit=True)
    with pytest.raises(OracleError, match="jit must be"):
        IKOracle(HUMAN, "right_hand", ARM, jit="yes")


def test_rescues_are_random_restarts_after_giving_up():
    thorough = IKOracle(HUMAN, "right_hand", ARM, solver="fatrop", search=Search(restarts=2, give_up=None))
    goal = (thorough.problem.anchor + [-0.1, 0.38, 0.0])[None]
    hint = thorough.evaluate(goal).posture  # as in test_give_up_...: a decisive, failing warm start
    rescuing = IKOracle(HUMAN, "right_hand", ARM, solver="fatrop", search=Search(restarts=2, rescues=1, give_up=0.0))
    assert not rescuing.evaluate(Goals(goal, seeds=hint)).reachable[0]
    assert rescuing.stats["solves"] == 2  # the hint, then one random restart (no reference start)
    # every failure counts as a near miss
    near_miss = IKOracle(HUMAN, "right_hand", ARM, solver="fatrop", search=Search(restarts=2, give_up=1.0))
    near_miss.evaluate(Goals(goal, seeds=hint))
    assert near_miss.stats["solves"] == 4  # the hint, the reference and both restarts


@pytest.mark.skipif(shutil.which("gcc") is None and not os.environ.get("CI"), reason="no gcc here (CI installs it)")
def test_jit_leaves_no_files_behind(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    oracle = IKOracle(HUMAN, "right_hand", ARM, jit=True)
    assert oracle.solver.jit and oracle.evaluate(np.array([[0.4, -0.3, 1.1]])).reachable[0]
    assert os.getcwd() == str(tmp_path) and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("params",
                         [{"rescues": -1}, {"restarts": -2}, {"give_up": -0.01}, {"settle": -0.01}, {"decisive": -0.1},
                                    {"restarts": 1.5}, {"prefer": "yes"}, {"max_seconds": float("nan")}])
def test_bad_search_parameters_are_refused_naming_the_key(params):
    key = next(iter(params))
    with pytest.raises(OracleError, match=rf"^{key} must be") as err:
        OracleSpec("casadi-ik", {"body": HUMAN, "effector": "right_hand", "joints": ARM, **params}).create()
    assert err.value.key == key


def test_refinement_starts_from_the_reference_unless_a_current_posture_is_given():
    oracle = IKOracle(HUMAN, "right_hand", ARM)
    refine = oracle.variant("refine", budget=0.5)
    goal = np.array([0.4, -0.3, 1.1])
    hint = oracle.evaluate(goal[None]).posture[0]
    x_hint = oracle.problem.x_of_q(hint)
    # builds: the neighbour's posture first
    assert np.allclose(starts(oracle.problem, oracle.search, goal, hint)[0], x_hint)
    first = starts(refine.problem, refine.search, goal, hint)
    # queries: reference, ready
    assert np.allclose(first[0], refine.problem.x_ref) and np.allclose(first[1], refine.problem.x_ready)
    elbow = refine.problem.x_names.index("right_elbow_flexion")
    assert refine.problem.x_ref[elbow] == 0.0 < refine.problem.x_ready[elbow]  # off the straight elbow
    # With a current posture (Goals.current), the hint (that posture) comes first, for continuity.
    assert np.allclose(starts(refine.problem, refine.search, goal, hint, Call(start=x_hint))[0], x_hint)


def test_seeded_refinement_tries_every_seed_and_refuses_a_wrong_shape():
    refine = IKOracle(HUMAN, "right_hand", ARM, solver="fatrop").variant("refine", budget=None)
    goal = np.array([[0.4, -0.3, 1.1]])
    nq = len(refine.posture_names)
    ref = refine.body.q_ref
    seeds = np.stack([ref, np.full(nq, np.nan), ref])[None]  # a NaN row is skipped
    v = refine.evaluate(Goals(goal, seeds=seeds))
    assert v.reachable[0] and refine.stats["solves"] == 4  # the reference, the ready posture and both seeds
    _assert_reachable_verdicts_hold(refine, goal, v)
    with pytest.raises(OracleError, match=r"seeds have shape \(1, 3\), expected \(1, 43\) or \(1, k, 43\)"):
        refine.evaluate(Goals(goal, seeds=ref[None, :3]))


def test_with_a_current_posture_the_reach_stage_moves_it_the_least(monkeypatch):
    import oracles.tasks.reach as reach_task

    # The demo atlas's crouch and two goals 1 cm apart low in front, where the
    # reach-only stage from the first answer wandered into another posture
    # (found as bench/posture.py's low pair 197 for the de_leva body; moved for
    # the ANSUR II body, and again when the stoop's twist rule and the pelvis's
    # bound aside came: of 80 pairs drawn low in front, one showed
    # the jump; in the others the term changed nothing, the jump absent).
    spec = load_config(ROOT / "configs" / "demo.yaml").strategy("right_crouch").oracle
    first, second = np.array([[0.5958, -0.1369, 0.6168]]), np.array([[0.6046, -0.1415, 0.6184]])

    def change(proximal: float, solver: str = "fatrop") -> float:
        monkeypatch.setattr(reach_task, "PROXIMAL", proximal)
        refine = OracleSpec(spec.name, {**spec.params, "jit": False, "solver": solver}).create().variant("refine",
            budget=None)
        a = refine.evaluate(first)
        b = refine.evaluate(Goals(second, current=a.posture[0]))
        assert a.reachable[0] and b.reachable[0]
        _assert_reachable_verdicts_hold(refine, second, b)
        return float(np.degrees(np.abs(b.posture[0, 7:] - a.posture[0, 7:]).max()))

    assert change(reach_task.PROXIMAL) < 5.0
    assert change(0.0) > 10.0  # without the term, fatrop's reach stage jumps: the jump the term removes
    # the batched engine holds it too (it starts from the current posture)
    assert change(reach_task.PROXIMAL, "batch") < 5.0


def test_a_settled_warm_start_solves_reach_alone_and_keeps_the_hints_choices(monkeypatch):
    tasks = [{"type": "reach"}, {"type": "posture"}]
    full = IKOracle(HUMAN, "right_hand", ARM, tasks, solver="fatrop", search=Search(restarts=0))
    settled = IKOracle(HUMAN, "right_hand", ARM, tasks, solver="fatrop", search=Search(restarts=0, settle=0.03))
    stages: list[int] = []
    real = InteriorPoint._stage

    def counted(self, k, *args):  # noqa: ANN001, ANN202
        stages.append(k)
        return real(self, k, *args)

    monkeypatch.setattr(InteriorPoint, "_stage", counted)
    goal = full.problem.anchor + [0.35, -0.1, -0.25]
    natural = full.evaluate(goal[None]).posture  # reach, then posture
    assert full.evaluate(goal[None]).reachable[0] and 1 in stages
    near, far = goal + [0.02, 0.0, 0.0], goal + [0.06, 0.0, 0.0]
    stages.clear()
    v = settled.evaluate(Goals(near[None], seeds=natural))
    assert v.reachable[0] and stages == [0]  # 2 cm from the hint: reach alone
    _assert_reachable_verdicts_hold(settled, near[None], v)
    # Reach alone, pulled towards the hint, moves the natural posture the last
    # centimetres: it stays close to it and about as liked as the full solve's
    # (measured over 6 steps of 2 cm: at most 4.4 deg and 0.9 % less liked;
    # before the pull and the settled program's smaller barrier, 16.6 deg and
    # 11 % for one of them).
    moved, liked = [], []
    for step in np.concatenate([np.eye(3), -np.eye(3)]) * 0.02:
        q = settled.evaluate(Goals((goal + step)[None], seeds=natural)).posture[0]
        moved.append(float(np.degrees(np.abs(q - natural[0]).max())))
        best = full.evaluate(Goals((goal + step)[None], seeds=natural)).posture[0]
        liked.append(full.preference(q, goal + step) / full.preference(best, goal + step))
    assert max(moved) < 6.0 and max(liked) < 1.03
    stages.clear()
    assert settled.evaluate(Goals(far[None], seeds=natural)).reachable[0] and 1 in stages  # 6 cm: every stage
    stages.clear()
    assert settled.evaluate(near[None]).reachable[0] and 1 in stages  # no hint: every stage


def test_a_settled_reach_stage_runs_its_own_program_with_a_smaller_barrier():
    tasks = [{"type": "reach"}, {"type": "posture"}]
    settled = IKOracle(HUMAN, "right_hand", ARM, tasks, solver="fatrop", search=Search(restarts=0, settle=0.03))
    settled.prepare()
    assert set(settled.solver.programs.settling) == {0}  # the plain program's twin; the cut one is built with the cuts
    for other in (IKOracle(HUMAN, "right_hand", ARM, tasks, solver="fatrop", search=Search(restarts=0)),
                  IKOracle(HUMAN, "right_hand", ARM, tasks, solver="ipopt", search=Search(restarts=0, settle=0.03))):
        other.prepare()
        assert other.solver.programs.settling == {}  # nothing settles, or the option is fatrop's
    goal = settled.problem.anchor + [0.35, -0.1, -0.25]
    natural = settled.evaluate(goal[None]).posture  # every stage: no hint
    real, used = settled.solver.programs.settling[0], []
    settled.solver.programs.settling[0] = lambda **kw: (used.append(1), real(**kw))[1]
    near = (goal + [0.0, 0.02, 0.0])[None]
    v = settled.evaluate(Goals(near, seeds=natural))
    assert used == [1] and v.reachable[0]
    _assert_reachable_verdicts_hold(settled, near, v)
    assert settled.evaluate(near).reachable[0] and used == [1]  # no hint: the plain programs


def test_verify_checks_a_posture_found_elsewhere_against_this_strategys_tasks():
    arm = IKOracle(HUMAN, "right_hand", ARM, [{"type": "reach"}, {"type": "self_collision"}])
    q = arm.reference_posture()
    here = arm.effector_positions(q[None])
    assert arm.verify(here, q[None]).all()  # the reference reaches its own hand position
    assert not arm.verify(here + [0.0, 0.0, 0.05], q[None]).any()  # 5 cm off: the tolerance is 5 mm
    # The arm swung across the body: the hand is where the posture puts it, but through the trunk.
    through = q.copy()
    through[arm.body.model.joints[arm.body.joint_id("right_shoulder_abduction")].idx_q] = -0.5
    assert not arm.verify(arm.effector_positions(through[None]), through[None]).any()


def test_the_lazy_hard_tasks_are_checked_only_when_asked_and_at_their_own_posture(monkeypatch):
    from oracles.tasks.self_collision import SelfCollisionTask

    oracle = IKOracle(HUMAN, "right_hand", ARM, [{"type": "reach"}, {"type": "self_collision"}])
    p, data = oracle.problem, oracle.body.model.createData()
    rng = np.random.default_rng(0)
    postures = [p.q_of_x(p.random_x(rng)) for _ in range(200)]
    verdicts = [p.check(q, np.zeros(3)).hard_ok for q in postures]  # each with its own data
    colliding, free = postures[verdicts.index(False)], postures[verdicts.index(True)]
    asked: list[int] = []
    real = SelfCollisionTask.holds
    monkeypatch.setattr(SelfCollisionTask, "holds", lambda self, num: (asked.append(1), real(self, num))[1])
    far = p.check(colliding, np.array([5.0, 0.0, 0.0]), data)
    assert not far.reachable and asked == []  # the goal is missed: no collision check
    later = p.check(free, np.zeros(3), data)  # data now holds the free posture
    assert far.hard_ok is False and later.hard_ok is True and len(asked) == 2


def test_a_settling_builds_variants_never_settle(monkeypatch):
    # A build settles; an answer from the character's current posture solves every stage, and the referee as always.
    builder = IKOracle(HUMAN, "right_hand", ARM, [{"type": "reach"}, {"type": "posture"}], solver="fatrop",
                       search=Search(restarts=0, settle=0.07))
    refine, referee = builder.variant("refine", budget=None), builder.variant("referee")
    assert builder.search.settle == 0.07 and refine.search.settle == 0.0 and referee.search.settle == 0.0
    stages: list[int] = []
    real = InteriorPoint._stage
    monkeypatch.setattr(InteriorPoint, "_stage", lambda self, k, *a: (stages.append(k), real(self, k, *a))[1])
    goal = builder.problem.anchor + [0.35, -0.1, -0.25]
    current = builder.evaluate(goal[None]).posture[0]
    stages.clear()
    v = refine.evaluate(Goals((goal + [0.0, 0.02, 0.0])[None], current=current))  # 2 cm from the current posture
    assert v.reachable[0] and 1 in stages  # the posture stage too


def test_a_compile_is_said_before_it_starts_and_when_it_ends(tmp_path, monkeypatch, capsys):
    """A first run compiles for minutes: each compile is logged (``reach.jit``) before it starts and when it ends, and
    the command line prints these lines on standard error; a library found in the cache says nothing."""
    import logging

    import casadi as ca

    from oracles.ik import jit
    from reach.tools import cli

    monkeypatch.setenv("REACH_JIT_CACHE", str(tmp_path / "jit"))
    cli._say_compiles()
    cli._say_compiles()  # once: a second call adds no second handler
    log = logging.getLogger("reach.jit")
    assert sum(getattr(h, "reach_cli", False) for h in log.handlers) == 1
    x = ca.SX.sym("x", 2)
    jit.compiled_functions([ca.Function("cube", [x], [x * x * x])])
    err = capsys.readouterr().err
    assert f"reach: compiling cube to machine code (once: kept in {tmp_path / 'jit'})" in err
    assert "reach: compiled cube in" in err
    jit.compiled_functions([ca.Function("cube", [x], [x * x * x])])
    assert "compil" not in capsys.readouterr().err


def test_programs_compiled_together_say_how_many_and_how_long_is_left(tmp_path, monkeypatch, caplog):
    """A first build compiles about 190 programs: those asked together are compiled by several compilers at once
    (``$REACH_JIT_JOBS``), said as one batch and then each with how many are done and about how long is left; each
    compiles once, and the results are the functions asked for."""
    import logging

    import casadi as ca

    from oracles.ik import jit

    monkeypatch.setenv("REACH_JIT_CACHE", str(tmp_path / "jit"))
    monkeypatch.setenv("REACH_JIT_JOBS", "2")
    x = ca.SX.sym("x", 2)
    functions = [ca.Function(f"power{k}", [x], [x**k]) for k in (2, 3, 4)]
    with caplog.at_level(logging.INFO, logger="reach.jit"):
        built = jit.compiled_functions(functions)
    said = [r.getMessage() for r in caplog.records]
    folder = tmp_path / "jit"
    assert said[0] == f"compiling 3 programs (power2 ... power4) to machine code, 2 at a time (once: kept in {folder})"
    assert [m.split(" (")[1].split(" about")[0] for m in said[1:3]] == ["1 of 3;", "2 of 3;"]
    assert all(" s left)" in m for m in said[1:3]) and "(3 of 3; all in" in said[3] and len(said) == 4
    assert [f(np.array([2.0, 3.0])).full().ravel().tolist() for f in built] == [[4, 9], [8, 27], [16, 81]]
    assert len(list((tmp_path / "jit").glob("*.so"))) == 3
    logged = [line.split("\t") for line in (folder / "compiles.log").read_text().splitlines()]
    assert (sorted(row[2] for row in logged) == sorted(p.stem for p in (tmp_path / "jit").glob("*.so"))
            and all(len(r) == 5 for r in logged))
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="reach.jit"):
        jit.compiled_functions(functions[:2] + [ca.Function("power5", [x], [x**5])])  # two cached, one new
    assert [r.getMessage().split(" to machine")[0] for r in caplog.records][:1] == ["compiling power5"]
    monkeypatch.setenv("REACH_JIT_JOBS", "many")
    with pytest.raises(RuntimeError, match="REACH_JIT_JOBS: expected a whole number"):
        jit.compiled_functions([ca.Function("power6", [x], [x**6])])


class PositionOnly(SingleSolver):
    """A solver added as a newcomer adds one: Gauss-Newton on the effector's position alone (tests only)."""

    name = "position_only"

    def solve(self, goal, x0, lower=True, call=NO_CALL):
        p, model, data = self.room.problem, self.room.body.model, self.room.data
        cols = [model.joints[j].idx_v for j in p.joint_ids]
        x = np.array(x0, float)
        for _ in range(50):
            q = p.q_of_x(x)
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)
            jac = pin.getFrameJacobian(model, data, p.effector_id, pin.LOCAL_WORLD_ALIGNED)[:3, cols]
            x = np.clip(x + np.linalg.pinv(jac) @ (goal - data.oMf[p.effector_id].translation), p.lower, p.upper)
        return p.q_of_x(x)


def test_a_new_solver_is_one_class_and_one_registry_line(monkeypatch):
    """Adding a solver is a file in oracles/ik/solvers/ and a line in SOLVERS: the oracle then searches with it (its
    answers checked by the verdict, as every solver's), its spec names it and rebuilds it, and a bad option is refused
    by name."""
    monkeypatch.setitem(SOLVERS, "position_only", "test_ik:PositionOnly")
    oracle = IKOracle(HUMAN, "right_hand", ARM, [{"type": "reach"}], search=Search(restarts=2), solver="position_only")
    goals = np.array([[0.4, -0.3, 1.1], [0.3, -0.5, 1.4], [1.5, 0.0, 1.0]])
    v = oracle.evaluate(goals)
    assert v.reachable.tolist() == [True, True, False]
    assert oracle.verify(goals, v.posture).tolist() == [True, True, False]
    assert oracle.spec.params["solver"] == "position_only" and oracle.spec.create().solver.name == "position_only"
    with pytest.raises(OracleError, match="takes no option damping"):
        IKOracle(HUMAN, "right_hand", ARM, solver="position_only", damping=0.1)
    with pytest.raises(OracleError, match="solver must be one of"):
        IKOracle(HUMAN, "right_hand", ARM, solver="newton")
