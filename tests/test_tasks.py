"""Tasks (oracles.tasks): the registry, each task's CasADi expression against Pinocchio, its dls Jacobian against
finite differences, its verdict check, and the README's table."""

from __future__ import annotations

import re
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from helpers import ARM

from oracles.bodies.body import human_body
from oracles.bodies.kinematics import SymbolicKinematics
from oracles.ik.problem import ReachProblem
from oracles.ik.search import Search
from oracles.ik.strategy import parse_strategy
from oracles.protocol import Goals
from oracles.tasks import TASKS, HardTask, Numeric, SoftTask, Symbolic, table
from oracles.tasks.base import perpendicular_basis
from reach.errors import TaskError

ROOT = Path(__file__).resolve().parents[1]
WHOLE = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "neck_*", "root", "*_hip_*", "*_ankle_*", "*_knee_*"]
ALL = [{"type": "reach"}, {"type": "feet", "heels": "down"}, {"type": "balance", "margin": 0.01}, {"type": "gaze"},
       {"type": "comfort"}]


@pytest.fixture(scope="module")
def problem():
    body = human_body()
    return ReachProblem(body, parse_strategy(body, "right_hand", WHOLE, ALL))


def numeric(problem, q, goal, data=None):
    model = problem.body.model
    data = data or model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    cols = np.array(list(range(6)) + [model.joints[j].idx_v for j in problem.joint_ids])
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    return Numeric(model, data, q, goal, jacobian=lambda fid: pin.getFrameJacobian(model, data, fid, lwa)[:, cols],
                   joint_jacobian=lambda j: pin.getJointJacobian(model, data, j, lwa)[:, cols], columns=cols,
                   joint_columns=np.arange(6, cols.size),
                   joint_q=np.array([model.joints[j].idx_q for j in problem.joint_ids]), x_ref=problem.x_ref)


def random_x(problem, seed):
    rng = np.random.default_rng(seed)
    x = problem.x_ref + rng.normal(scale=0.05, size=problem.nx)
    return np.clip(x, problem.lower, problem.upper)


def test_the_readme_table_is_the_registered_tasks():
    assert table() in (ROOT / "README.md").read_text()


def test_every_task_is_registered_under_its_own_type():
    for name, cls in TASKS.items():
        assert cls.type == name and cls.summary and issubclass(cls, (HardTask, SoftTask))
        assert "type" in cls.allowed_keys() and (not issubclass(cls, SoftTask) or "priority" in cls.allowed_keys())


def test_soft_objectives_in_casadi_match_pinocchio(problem):
    s = problem.strategy
    goal_v = np.array([0.5, -0.3, 1.1])
    goal = ca.SX.sym("goal", 3)
    sym = Symbolic(SymbolicKinematics(problem.body.model, problem.q_sym), problem.x_sym, goal, problem.x_ref,
                   problem.upper - problem.lower)
    for seed in range(3):
        x = random_x(problem, seed)
        q = problem.q_of_x(x)
        num = numeric(problem, q, goal_v)
        values = {t.type: float(ca.Function("f", [problem.x_sym, goal], [t.objective(sym)])(x, goal_v)) for t in s.soft}
        assert values["reach"] == pytest.approx(s.reach.residual(num) ** 2, rel=1e-9, abs=1e-12)
        eye = num.frame(problem.body.frame_id("eyes"))
        to_goal = goal_v - eye.translation
        # The line of sight: the eyes' x axis turned 15 deg down about their y axis (z up).
        sight = eye.rotation @ pin.utils.rotate("y", np.radians(15.0)) @ np.array([1.0, 0.0, 0.0])
        assert values["gaze"] == pytest.approx(1 - sight @ to_goal / (np.linalg.norm(to_goal) + 1e-9), abs=1e-9)
        span = problem.upper - problem.lower
        assert values["comfort"] == pytest.approx(np.mean(((x - problem.x_ref) / span) ** 2), rel=1e-9)


def test_the_reach_stage_measures_the_distance_alone_when_it_pulls_towards_a_current_posture(problem):
    from oracles.tasks.reach import PROXIMAL

    goal_v = np.array([0.5, -0.3, 1.1])
    goal, start, weight = ca.SX.sym("goal", 3), ca.SX.sym("start", problem.nx), ca.SX.sym("w", 1)
    span = problem.upper - problem.lower
    sym = Symbolic(SymbolicKinematics(problem.body.model, problem.q_sym), problem.x_sym, goal, problem.x_ref, span,
                   tuple(problem.x_names), problem.lower, start, weight)
    reach = problem.strategy.reach
    f = ca.Function("f", [problem.x_sym, goal, start, weight], [reach.objective(sym), reach.measure(sym)])
    x, current = random_x(problem, 1), random_x(problem, 2)
    distance = reach.residual(numeric(problem, problem.q_of_x(x), goal_v))
    objective, measure = (float(v) for v in f(x, goal_v, current, 1.0))
    # The optimum later stages hold (and the verdict's attained) is the squared distance, without the pull.
    assert measure == pytest.approx(distance**2, rel=1e-9)
    assert objective - measure == pytest.approx(PROXIMAL * np.sum(((x - current) / span) ** 2), rel=1e-9)
    assert float(f(x, goal_v, current, 0.0)[0]) == pytest.approx(measure, rel=1e-12)  # builds: no current posture


def test_hard_constraints_in_casadi_hold_at_the_reference_and_agree_with_the_checks(problem):
    goal = ca.SX.sym("goal", 3)
    sym = Symbolic(SymbolicKinematics(problem.body.model, problem.q_sym), problem.x_sym, goal, problem.x_ref,
                   problem.upper - problem.lower)
    for task in problem.strategy.hard:
        rows = task.constraints(sym)
        g = ca.Function("g", [problem.x_sym, goal], [ca.vertcat(*[r.expr for r in rows])])
        lo = np.concatenate([np.full(r.expr.numel(), r.lower) for r in rows])
        hi = np.concatenate([np.full(r.expr.numel(), r.upper) for r in rows])
        at_ref = np.asarray(g(problem.x_ref, np.zeros(3))).ravel()
        assert np.all(at_ref >= lo - 1e-9) and np.all(at_ref <= hi + 1e-9), task.type
        assert task.holds(numeric(problem, problem.body.q_ref, np.zeros(3))), task.type
        # Lifting the whole body 5 cm breaks the feet (and no other) constraint, in CasADi and in the check alike.
        lifted = problem.x_ref.copy()
        lifted[2] += 0.05
        g_lift = np.asarray(g(lifted, np.zeros(3))).ravel()
        broken = bool(np.any(g_lift < lo - 1e-6) or np.any(g_lift > hi + 1e-6))
        assert broken == (task.type == "feet")
        assert task.holds(numeric(problem, problem.q_of_x(lifted), np.zeros(3))) == (not broken), task.type


def test_dls_jacobians_match_finite_differences(problem):
    goal = np.array([0.5, -0.3, 1.1])
    model = problem.body.model
    x = random_x(problem, 7)
    q = problem.q_of_x(x)
    num = numeric(problem, q, goal)
    reach_row = problem.strategy.reach.level(num)
    eps = 1e-6
    fid = problem.body.frame_id("right_hand")
    for k in range(num.columns.size):
        v = np.zeros(model.nv)
        v[num.columns[k]] = eps
        data = model.createData()
        pin.framesForwardKinematics(model, data, pin.integrate(model, q, v))
        fd = (data.oMf[fid].translation - num.frame(fid).translation) / eps
        # The reach row's error is goal - hand, so its Jacobian is the hand's.
        assert np.allclose(reach_row.jacobian[:, k], fd, atol=1e-4), k
    feet = problem.strategy.task("feet")
    rows = feet.rows(num)
    fd_rows = []
    for k in range(num.columns.size):
        v = np.zeros(model.nv)
        v[num.columns[k]] = eps
        moved = numeric(problem, pin.integrate(model, q, v), goal)
        # Each position row's error is ref - current: its derivative is minus the Jacobian column.
        fd_rows.append(-(feet.rows(moved)[0].error - rows[0].error) / eps)
    assert np.allclose(rows[0].jacobian, np.array(fd_rows).T, atol=1e-4)


def test_perpendicular_basis_is_orthonormal_and_normal_to_the_axis():
    for axis in (np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]),
                 np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])):
        b = perpendicular_basis(axis)
        assert np.allclose(b @ b.T, np.eye(2)) and np.allclose(b @ axis, 0.0)


@pytest.mark.parametrize(
    ("tasks", "message"),
    [
        ([{"type": "reach"}, {"type": "gaze", "frame": 3}], r"tasks\[1\]\.frame: expected a frame name, got 3"),
        ([{"type": "reach"}, {"type": "gaze", "frame": "third_eye"}],
         r"tasks\[1\]\.frame: human: no frame 'third_eye'"),
        ([{"type": "reach"}, {"type": "gaze", "cone": 90}], r"tasks\[1\]\.cone: expected a number in \[0.0, 60.0\], "
                                                            r"got 90"),
        ([{"type": "reach"}, {"type": "gaze", "down": "low"}], r"tasks\[1\]\.down: expected a number in \[-45.0, "
                                                               r"60.0\], got 'low'"),
        ([{"type": "reach"}, {"type": "reach"}], r"tasks\[1\]: a second reach task"),
        ([{"type": "reach", "tolerance": 2}], r"tasks\[0\]\.tolerance: expected a number in \[1e-06, 1.0\], got 2"),
        ([{"type": "reach", "priority": "high"}], r"tasks\[0\]\.priority: expected a number"),
        ([{"type": "reach"}, {"type": "contacts", "fixed": "right_foot"}], r"tasks\[1\]\.fixed: expected a list of "
            r"frame names"),
        ([{"type": "reach"}, {"type": "balance", "support": ["right_foot", "left_foot"]}], r"tasks\[1\]: balance "
            r"needs a support polygon"),
        ([{"type": "reach"}, {"type": "coupling", "rules": [{"joint": "*_hip_flexion"}]}], r"tasks\[1\]\.rules\[0\]: "
            r"expected \{joint: name"),
        ([{"type": "reach"}, {"type": "coupling", "rules": [{"joint": "tail", "by": "x", "limit": 1, "slope": 0}]}],
         r"tasks\[1\]\.rules\[0\]\.joint: no joint matches 'tail'"),
        ([{"type": "reach"}, {"type": "self_collision", "exclude": ["right_hand"]}], r"tasks\[1\]\.exclude: expected "
            r"a list of \[capsule, capsule\] pairs"),
        ([{"type": "reach"}, {"type": "self_collision", "exclude": [["right_hand", "tail"]]}],
         r"tasks\[1\]\.exclude: no capsule matches 'tail'"),
        ([{"type": "reach"}, {"type": "self_collision", "only": ["wing"]}], r"tasks\[1\]\.only: no capsule matches "
            r"'wing'"),
        ([{"type": "reach"}, {"type": "floor", "exclude": "feet"}], r"tasks\[1\]\.exclude: expected a list of "
            r"capsule names"),
        ([{"type": "reach"}, {"type": "posture", "weights": {"*_elbow_*": -1}}], r"tasks\[1\]\.weights\.\*_elbow_\*: "
            r"expected a number in \[0.0, 1000.0\]"),
        ([{"type": "reach"}, {"type": "hang", "frames": ["left_shoulder"]}], r"tasks\[1\]\.frames: expected at least "
            r"two frames"),
        ([{"type": "reach"}, {"type": "hang", "frames": ["left_shoulder", "paw"]}], r"tasks\[1\]\.frames: human: no "
            r"frame 'paw'"),
        ([{"type": "reach"}, {"type": "hang", "cone": 120}], r"tasks\[1\]\.cone: expected a number in \[0.0, 90.0\], "
                                                             r"got 120"),
    ],
)
def test_task_errors_name_the_key(tasks, message):
    with pytest.raises(TaskError, match=message) as err:
        parse_strategy(human_body(), "right_hand", WHOLE, tasks)
    assert re.match(r"tasks(\[\d\])?", err.value.key)


def test_priorities_order_the_soft_tasks_and_a_zero_weight_drops_comfort():
    body = human_body()
    s = parse_strategy(body, "right_hand", WHOLE,
                       [{"type": "comfort", "priority": 0}, {"type": "gaze"}, {"type": "reach"}])
    assert [t.type for t in s.soft] == ["comfort", "reach", "gaze"]
    s = parse_strategy(body, "right_hand", WHOLE, [{"type": "reach"}, {"type": "comfort", "weight": 0}])
    assert [t.type for t in s.tasks] == ["reach"]


def test_rising_heels_are_hinged_and_kept_above_the_floor():
    body = human_body()
    tiptoe = parse_strategy(body, "right_hand", WHOLE,
                            [{"type": "reach"}, {"type": "feet", "heels": "rise"}, {"type": "balance"}])
    problem = ReachProblem(body, tiptoe)
    feet = problem.strategy.task("feet")
    assert [c.mode for c in feet.contacts] == ["hinge", "hinge"] and feet.above_floor == ("right_heel", "left_heel")
    balance = problem.strategy.task("balance")
    assert set(balance.polygon_frames) == {f"{s}_{p}" for s in ("right", "left")
                                           for p in ("ball_inner", "ball_outer", "toe_inner", "toe_outer")}


def test_the_hamstrings_couple_hip_flexion_to_the_knee():
    body = human_body()
    s = parse_strategy(body, "right_hand", WHOLE, [{"type": "reach"}, {"type": "coupling"}])
    problem = ReachProblem(body, s)
    coupling = s.task("coupling")
    assert {r.joint for r in coupling.rules} == {"right_hip_flexion", "left_hip_flexion", "right_shoulder_abduction"}
    hip, knee = (body.model.joints[body.joint_id(n)].idx_q for n in ("right_hip_flexion", "right_knee_flexion"))

    def holds(hip_deg: float, knee_deg: float) -> bool:
        q = body.q_ref.copy()
        q[hip], q[knee] = np.radians(hip_deg), np.radians(knee_deg)
        return coupling.holds(numeric(problem, q, np.zeros(3)))

    # Straight-leg raise about 80 deg (Magee 2014); with the knee bent 90 deg the full 120 deg.
    assert holds(79.0, 0.0) and not holds(81.0, 0.0)
    assert holds(119.0, 90.0) and not holds(110.0, 60.0) and holds(105.0, 60.0)


def test_the_shoulder_coupling_keeps_one_of_the_two_postures_that_point_the_humerus_alike():
    body = human_body()
    s = parse_strategy(body, "right_hand", ARM, [{"type": "reach"}, {"type": "coupling"}])
    problem = ReachProblem(body, s)
    coupling = s.task("coupling")
    # The arm alone: the hip rules have nothing to move and are left out.
    assert [(r.joints, r.by) for r in coupling.rules] == [(("right_shoulder_abduction",), "right_shoulder_flexion")]
    idx = {n: body.model.joints[body.joint_id(n)].idx_q for n in ("right_shoulder_flexion", "right_shoulder_abduction")}

    def posture(flexion: float, abduction: float) -> np.ndarray:
        q = body.q_ref.copy()
        q[idx["right_shoulder_flexion"]], q[idx["right_shoulder_abduction"]] = np.radians([flexion, abduction])
        return q

    def holds(flexion: float, abduction: float) -> bool:
        return coupling.holds(numeric(problem, posture(flexion, abduction), np.zeros(3)))

    def elbow(q: np.ndarray) -> np.ndarray:
        data = body.model.createData()
        pin.forwardKinematics(body.model, data, q)
        return data.oMi[body.joint_id("right_elbow_flexion")].translation.copy()

    # Flexion f with abduction a and f - 180 with 180 - a put the elbow at the
    # same point (Pinocchio): the rule keeps the flexed arm, not the extended one swung past the side.
    for f, a in ((120.0, 40.0), (150.0, 10.0), (130.0, 60.0)):
        assert np.allclose(elbow(posture(f, a)), elbow(posture(f - 180.0, 180.0 - a)), atol=1e-9)
        assert holds(f, a) and not holds(f - 180.0, 180.0 - a)
    # Near the overhead pole both stay (the arm raised by flexion or by abduction: Codman's paradox).
    assert holds(170.0, 60.0) and holds(-10.0, 120.0)
    # Every flexed arm keeps its full abduction; the clinical ends stay; an extended arm is abducted less.
    assert holds(0.0, 179.0) and holds(179.0, 179.0) and holds(-60.0, -30.0) and holds(-60.0, 59.0)
    assert holds(-45.0, 89.0) and not holds(-45.0, 91.0) and not holds(-57.0, 140.0)


def test_hip_and_lumbar_flexion_share_a_limit_with_the_knees_straight():
    body = human_body()
    s = parse_strategy(body, "right_hand", WHOLE, [{"type": "reach"}, {"type": "coupling"}])
    problem = ReachProblem(body, s)
    coupling = s.task("coupling")
    summed = [r for r in coupling.rules if len(r.joints) == 2]
    assert {r.joints for r in summed} == {(f"{side}_hip_flexion", "lumbar_flexion") for side in ("right", "left")}
    twist = [r for r in coupling.rules if len(r.joints) == 4]
    assert len(twist) == 8 and {r.signs for r in twist} == {(1.0, 1.0, a, b) for a in (1.0, -1.0) for b in (1.0, -1.0)}
    idx = {n: body.model.joints[body.joint_id(n)].idx_q
           for n in ("right_hip_flexion", "lumbar_flexion", "right_knee_flexion", "lumbar_lateral",
                     "thoracic_rotation")}

    def holds(hip: float, lumbar: float, knee: float, lateral: float = 0.0, turn: float = 0.0) -> bool:
        q = body.q_ref.copy()
        for name, deg in (("right_hip_flexion", hip), ("lumbar_flexion", lumbar), ("right_knee_flexion", knee),
                          ("lumbar_lateral", lateral), ("thoracic_rotation", turn)):
            q[idx[name]] = np.radians(deg)
        return coupling.holds(numeric(problem, q, np.zeros(3)))

    # Knees straight: 100 deg between them, however split; bent 90 deg: each joint's own range.
    assert (holds(80.0, 19.0, 0.0) and holds(40.0, 59.0, 0.0) and not holds(80.0, 22.0, 0.0)
            and not holds(50.0, 55.0, 0.0))
    assert holds(119.0, 59.0, 90.0) and not holds(100.0, 50.0, 45.0) and holds(90.0, 50.0, 45.0)
    # A full stoop leaves 10 deg of side-bend and twist together, of either sign; upright, their own ranges; the knees
    # slacken it as they do the stoop.
    assert holds(80.0, 20.0, 0.0, 4.0, -5.0) and not holds(80.0, 20.0, 0.0, -6.0, 5.0)
    assert holds(0.0, 0.0, 0.0, 34.0, -44.0) and holds(80.0, 20.0, 60.0, -30.0, 30.0)
    # The same rule by hand, on a list of joints, and its errors.
    rule = {"joint": ["*_hip_flexion", "lumbar_flexion"], "by": "*_knee_flexion", "limit": 1.0, "slope": 0.5}
    mine = parse_strategy(body, "right_hand", WHOLE,
                          [{"type": "reach"}, {"type": "coupling", "rules": [rule]}]).task("coupling")
    assert sorted(r.joints
                  for r in mine.rules) == [("left_hip_flexion", "lumbar_flexion"),
                                           ("right_hip_flexion", "lumbar_flexion")]
    with pytest.raises(TaskError, match=r"rules\[0\]\.joint: .*no joint 'tail'"):
        parse_strategy(body, "right_hand", WHOLE,
                       [{"type": "reach"},
                        {"type": "coupling", "rules": [{**rule, "joint": ["*_hip_flexion", "tail"]}]}])
    with pytest.raises(TaskError, match=r"rules\[0\]: expected"):
        parse_strategy(body, "right_hand", WHOLE,
                       [{"type": "reach"}, {"type": "coupling", "rules": [{**rule, "joint": []}]}])


def test_limits_near_counts_range_ends_and_coupled_limits_but_not_the_ends_the_body_rests_at():
    body = human_body()
    problem = ReachProblem(body, parse_strategy(body, "right_hand", WHOLE, [{"type": "reach"}, {"type": "coupling"}]))
    idx = {n: body.model.joints[body.joint_id(n)].idx_q
           for n in ("lumbar_flexion", "right_knee_flexion", "right_hip_flexion", "neck_flexion")}
    margin = np.radians(5.0)
    # At the reference the knees stand straight, at the end of their range: that is rest, not strain.
    assert body.model.lowerPositionLimit[idx["right_knee_flexion"]] == body.q_ref[idx["right_knee_flexion"]]
    assert problem.limits_near(body.q_ref, margin) == []

    def near(**deg: float) -> list[str]:
        q = body.q_ref.copy()
        for name, value in deg.items():
            q[idx[name]] = np.radians(value)
        return problem.limits_near(q, margin)

    # The lumbar spine's own range is 60 deg of flexion (anthropometry.py).
    assert near(lumbar_flexion=57.0) == ["lumbar_flexion (upper)"] and near(lumbar_flexion=54.0) == []
    assert near(neck_flexion=-44.0) == ["neck_flexion (lower)"]
    # Hamstrings: 80 deg of hip flexion with the knee straight, more with it bent.
    assert near(right_hip_flexion=77.0) == ["right_hip_flexion"]
    assert near(right_hip_flexion=77.0, right_knee_flexion=30.0) == []
    # Hip and lumbar flexion share 100 deg with the knees straight.
    assert near(right_hip_flexion=45.0, lumbar_flexion=52.0) == ["right_hip_flexion + lumbar_flexion"]


@pytest.mark.slow
def test_a_crouch_reaches_lower_than_the_straight_legged_whole_body():
    from oracles.ik.oracle import IKOracle

    straight = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "root", "*_hip_*", "*_ankle_*"]
    tasks = [{"type": "reach"}, {"type": "feet"}, {"type": "balance"}, {"type": "floor"}, {"type": "coupling"}]
    body = {"human": {"sex": "male", "percentile": 50}}
    whole = IKOracle(body, "right_hand", straight, tasks, search=Search(restarts=4, give_up=None))
    crouch = IKOracle(body, "right_hand", [*straight, "*_knee_*"], tasks, search=Search(restarts=4, give_up=None))
    # In front of the feet: the straight-legged stoop ends with the fist's
    # grip centre about 12 cm above the floor (the open hand's fingertips,
    # 13 cm past the grip, at it); bending the knees lays the fist on the floor.
    low = np.array([[0.35, -0.2, 0.04], [0.45, -0.2, 0.04]])
    assert not whole.evaluate(low).reachable.any()
    assert crouch.evaluate(low).reachable.all()
    assert whole.evaluate(low + [0.0, 0.0, 0.10]).reachable.all()


def test_the_coupling_holds_in_the_solvers_postures():
    from oracles.ik.oracle import IKOracle

    straight = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "root", "*_hip_*", "*_ankle_*"]
    tasks = [{"type": "reach"}, {"type": "feet"}, {"type": "balance"}, {"type": "coupling"}]
    oracle = IKOracle({"human": {"sex": "male", "percentile": 50}}, "right_hand", straight, tasks,
                      search=Search(restarts=2))
    hip = oracle.body.model.joints[oracle.body.joint_id("right_hip_flexion")].idx_q
    goals = np.array([[0.35, -0.2, 0.35], [0.45, -0.2, 0.5], [0.3, -0.3, 0.6]])
    v = oracle.evaluate(goals)
    assert v.reachable.any()
    for q, ok in zip(v.posture, v.reachable, strict=True):
        if ok:
            assert q[hip] <= np.radians(80.0) + 1e-6  # knees straight: the hamstrings' limit


def test_collision_and_floor_rows_match_finite_differences():
    body = human_body()
    s = parse_strategy(body, "right_hand", WHOLE,
                       [{"type": "reach"}, {"type": "self_collision", "margin": 0.2}, {"type": "floor"}])
    problem = ReachProblem(body, s)
    model = body.model
    q = problem.q_of_x(random_x(problem, 3))
    num = numeric(problem, q, np.zeros(3))
    task = s.task("self_collision")
    rows = task.rows(num)  # a 0.2 m margin makes many pairs active
    assert len(rows) > 5
    eps = 1e-6
    from oracles.bodies.collision import nearest_points

    def gaps(qq):
        data = model.createData()
        pin.forwardKinematics(model, data, qq)
        out = []
        for p in task.pairs:
            a, b = body.collision.world(data, p.first)
            c, d = body.collision.world(data, p.second)
            out.append(nearest_points(a, b, c, d)[2])
        return np.array(out)

    base = gaps(q)
    active = [k for k, p in enumerate(task.pairs)
              if base[k] - body.collision.placed[p.first].radius - body.collision.placed[p.second].radius
              < p.clearance + 0.005]
    fd = np.zeros((len(active), num.columns.size))
    for k in range(num.columns.size):
        v = np.zeros(model.nv)
        v[num.columns[k]] = eps
        fd[:, k] = (gaps(pin.integrate(model, q, v))[active] - base[active]) / eps
    assert np.allclose(np.vstack([r.jacobian for r in rows]), fd, atol=1e-4)
    floor = s.task("floor")
    low = q.copy()
    low[2] -= 0.45  # sink the body so that some segment nears the floor
    frows = floor.rows(numeric(problem, low, np.zeros(3)))
    assert frows and all(r.error[0] >= 0 for r in frows)
    # The floor is lazy but for the hand (the effector's capsule, constraint rows): the other
    # segments' cuts are their near end points' heights, linearised (against finite differences).
    assert [body.collision.placed[i].name for i in floor.eager] == ["right_hand"]
    lazy = [i for i in floor.capsules if i not in floor.eager]
    cuts = floor.cuts(numeric(problem, low, np.zeros(3)), 0.05)
    assert cuts

    def ends(qq):
        data = _placed(model, qq)
        return np.array([e[2] for i in lazy for e in body.collision.world(data, i)])

    radii = np.repeat([body.collision.placed[i].radius for i in lazy], 2)
    near = np.nonzero(ends(low) - radii < 0.05)[0]
    base = ends(low)[near]
    assert np.allclose([c.gap for c in cuts], base) and np.allclose([c.need for c in cuts], radii[near])
    for k in range(num.columns.size):
        v = np.zeros(model.nv)
        v[num.columns[k]] = eps
        moved = ends(pin.integrate(model, low, v))[near]
        assert np.allclose([c.jacobian[k] for c in cuts], (moved - base) / eps, atol=1e-4), k


def _placed(model, q):
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    return data


IDLE_ARM = ["left_shoulder_flexion", "left_shoulder_abduction", "left_elbow_flexion"]


def test_the_idle_arm_hangs_by_default_and_only_when_it_moves():
    body = human_body()
    hang = parse_strategy(body, "right_hand", [*WHOLE, *IDLE_ARM], [{"type": "reach"}, {"type": "hang"}]).task("hang")
    assert hang.chains == (("left_shoulder", "left_elbow_flexion", "left_wrist_flexion"),)
    # The arm that reaches, or an idle arm whose joints are locked, is no chain: the task is dropped.
    assert [t.type for t in parse_strategy(body, "right_hand", WHOLE,
                                           [{"type": "reach"}, {"type": "hang"}]).tasks] == ["reach"]


def test_a_robot_hangs_only_the_frames_it_names():
    from oracles.bodies.body import urdf_body

    ur5 = urdf_body(ROOT / "configs" / "urdf" / "ur5.urdf")
    joints = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
    with pytest.raises(TaskError, match=r"tasks\[1\]\.frames: .*no human arm .* give the chain's frames"):
        parse_strategy(ur5, "ee_link", joints, [{"type": "reach"}, {"type": "hang"}])
    hang = parse_strategy(ur5, "ee_link", joints,
                          [{"type": "reach"},
                           {"type": "hang", "frames": ["upper_arm_link", "forearm_link"]}]).task("hang")
    assert hang.chains == (("upper_arm_link", "forearm_link"),)


def test_the_hang_row_agrees_with_casadi_pinocchio_and_finite_differences():
    body = human_body()
    s = parse_strategy(body, "right_hand", [*WHOLE, *IDLE_ARM], [{"type": "reach"}, {"type": "hang", "cone": 30}])
    problem = ReachProblem(body, s)
    task, model = s.task("hang"), body.model
    goal = ca.SX.sym("goal", 3)
    sym = Symbolic(SymbolicKinematics(model, problem.q_sym), problem.x_sym, goal, problem.x_ref,
                   problem.upper - problem.lower)
    g = ca.Function("g", [problem.x_sym], [ca.vertcat(*[c.expr for c in task.constraints(sym)])])
    flexion = problem.x_names.index("left_shoulder_flexion")
    for angle, holds in ((0.0, True), (25.0, True), (35.0, False), (-35.0, False), (150.0, False)):
        x = problem.x_ref.copy()
        x[flexion] = np.radians(angle)  # the elbow straight: the whole arm at this angle from straight down
        q = problem.q_of_x(x)
        num = numeric(problem, q, np.zeros(3))
        # Independently: the upper arm's angle from straight down, by Pinocchio's frames.
        data = model.createData()
        pin.framesForwardKinematics(model, data, q)
        d = (data.oMf[body.frame_id("left_elbow_flexion")].translation
             - data.oMf[body.frame_id("left_shoulder")].translation)
        assert np.degrees(np.arccos(-d[2] / np.linalg.norm(d))) == pytest.approx(abs(angle), abs=1.0)
        assert task.holds(num) == holds
        assert bool(np.all(np.asarray(g(x)).ravel() >= -1e-9)) == holds
    x = problem.x_ref.copy()
    x[flexion] = np.radians(29.0)  # near the 30 deg cone: the rows are active
    q = problem.q_of_x(x)
    rows = task.rows(numeric(problem, q, np.zeros(3)))
    assert rows
    jac = np.asarray(ca.Function("j", [problem.x_sym], [ca.jacobian(g(problem.x_sym), problem.x_sym)])(x))
    assert np.allclose(rows[0].jacobian[0, 6:], jac[0, 6:], atol=1e-6)


@pytest.mark.slow
def test_a_low_reach_keeps_the_idle_arm_hanging():
    from oracles.ik.oracle import IKOracle

    joints = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "root", "*_hip_*", "*_ankle_*", *IDLE_ARM]
    tasks = [{"type": "reach"}, {"type": "feet"}, {"type": "balance", "margin": 0.02}, {"type": "floor"},
             {"type": "coupling"}, {"type": "hang"}]
    oracle = IKOracle({"human": {"sex": "male", "percentile": 50}}, "right_hand", joints, tasks,
                      search=Search(restarts=2))
    model = oracle.body.model
    # The lower edge of the straight-legged stoop in front, where the free
    # arm was thrown behind the back as a counterweight.
    goals = np.array([[0.4, -0.08, 0.16], [0.4, -0.08, 0.17], [0.35, -0.15, 0.12]])
    v = oracle.evaluate(goals)
    assert v.reachable.any()
    for q, ok in zip(v.posture, v.reachable, strict=True):
        if ok:
            data = model.createData()
            pin.framesForwardKinematics(model, data, q)
            z = [data.oMf[oracle.body.frame_id(n)].translation[2]
                 for n in ("left_shoulder", "left_elbow_flexion", "left_wrist_flexion")]
            assert z[0] > z[1] > z[2]


def test_a_current_posture_of_the_wrong_size_is_refused():
    from oracles.ik.oracle import IKOracle
    from reach.errors import OracleError

    oracle = IKOracle({"human": {"sex": "male", "percentile": 50}}, "right_hand", ARM)
    with pytest.raises(OracleError, match=r"current posture has shape \(3,\), expected \(43,\)"):
        oracle.evaluate(Goals(np.array([[0.4, -0.3, 1.2]]), current=np.zeros(3)))


@pytest.mark.slow
def test_balance_with_the_pelvis_keeps_the_pelvis_over_the_feet():
    """``balance: {pelvis: true}``: the lowest straight-legged reach in front of the right foot shifted the pelvis
    21 cm aside, past the feet; with the option the pelvis stays over the sole corners' hull, and with ``pelvis: 0.05``
    also within 5 cm aside (checked by Pinocchio's forward kinematics and scipy's hull, apart from the task's own
    code), and both engines agree."""
    from scipy.spatial import Delaunay

    from oracles.protocol import OracleSpec

    straight = [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "root", "*_hip_*", "*_ankle_*"]
    body = {"human": {"sex": "male", "percentile": 50}}
    goal = np.array([[0.35, -0.15, 0.17]])  # 3 cm above the lowest the stoop reaches there (0.14 m)
    for solver, pelvis in (("fatrop", True), ("batch", True), ("fatrop", 0.05), ("batch", 0.05)):
        tasks = [{"type": "reach"}, {"type": "feet"}, {"type": "balance", "pelvis": pelvis}, {"type": "floor"},
                 {"type": "coupling"}]
        oracle = OracleSpec("casadi-ik", {"body": body, "effector": "right_hand", "joints": straight, "tasks": tasks,
                                          "solver": solver, "restarts": 4}).create()
        v = oracle.evaluate(goal)
        assert v.reachable[0], (solver, pelvis)
        q = v.posture[0]
        model = oracle.body.model
        data = model.createData()
        pin.framesForwardKinematics(model, data, oracle.body.q_ref)
        corners = [f"{s}_{e}_{c}" for s in ("right", "left") for e in ("heel", "toe") for c in ("inner", "outer")]
        hull = Delaunay(np.array([data.oMf[model.getFrameId(n)].translation[:2] for n in corners]))
        standing = data.oMi[1].translation.copy()
        pin.framesForwardKinematics(model, data, q)
        assert hull.find_simplex(data.oMi[1].translation[:2]) >= 0, (solver, data.oMi[1].translation)
        if pelvis is not True:
            assert abs(data.oMi[1].translation[1] - standing[1]) <= pelvis + 1e-4, (solver, data.oMi[1].translation)
        assert np.linalg.norm(data.oMf[model.getFrameId("right_hand")].translation - goal[0]) < 0.006


def test_within_bounds_agree_in_casadi_pinocchio_and_finite_differences():
    body = human_body()
    frames = ["left_elbow_flexion", "left_fingertip"]
    s = parse_strategy(body, "right_hand", [*WHOLE, *IDLE_ARM],
                       [{"type": "reach"}, {"type": "within", "frames": frames, "max": [None, 0.25, None],
                                            "min": [None, None, 0.3]}])
    problem = ReachProblem(body, s)
    task, model = s.task("within"), body.model
    assert [(b.frame, b.axis, b.value, b.sign) for b in task.bounds] == [
        ("left_elbow_flexion", 2, 0.3, 1.0), ("left_elbow_flexion", 1, 0.25, -1.0),
        ("left_fingertip", 2, 0.3, 1.0), ("left_fingertip", 1, 0.25, -1.0)]
    sym = Symbolic(SymbolicKinematics(model, problem.q_sym), problem.x_sym, ca.SX.sym("goal", 3), problem.x_ref,
                   problem.upper - problem.lower)
    g = ca.Function("g", [problem.x_sym], [ca.vertcat(*[c.expr for c in task.constraints(sym)])])
    abduction = problem.x_names.index("left_shoulder_abduction")
    for angle in (0.0, 10.0, 20.0, 30.0, 45.0):
        x = problem.x_ref.copy()
        x[abduction] = np.radians(angle)  # the arm swung out to the left: y grows
        q = problem.q_of_x(x)
        # Independently: the frames' positions by Pinocchio against the bounds as written.
        data = model.createData()
        pin.framesForwardKinematics(model, data, q)
        p = [data.oMf[body.frame_id(n)].translation for n in frames]
        inside = all(pt[1] <= 0.25 and pt[2] >= 0.3 for pt in p)
        assert task.holds(numeric(problem, q, np.zeros(3))) == inside, angle
        assert bool(np.all(np.asarray(g(x)).ravel() >= -1e-9)) == inside, angle
    assert not task.holds(numeric(problem, problem.q_of_x(x), np.zeros(3)))  # 45 deg out: the fingertip past 0.25
    rows = task.rows(numeric(problem, problem.q_of_x(x), np.zeros(3)))
    assert rows and all(r.error[0] > 0 for r in rows)
    jac = np.asarray(ca.Function("j", [problem.x_sym], [ca.jacobian(g(problem.x_sym), problem.x_sym)])(x))
    active = [i for i, v in enumerate(np.asarray(g(x)).ravel()) if v < 0.005]
    assert len(active) == len(rows)
    for row, i in zip(rows, active, strict=True):
        assert np.allclose(row.jacobian[0, 6:], jac[i, 6:], atol=1e-6)


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        ({"max": [None, 0.25, None]}, r"tasks\[1\]\.frames: expected the frames"),
        ({"frames": ["left_fingertip"]}, r"tasks\[1\]\.max: expected at least one bound"),
        ({"frames": ["left_fingertip"], "max": [0.25]}, r"tasks\[1\]\.max: expected \[x, y, z\] in metres"),
        ({"frames": ["left_fingertip"], "min": [None, "side", None]}, r"tasks\[1\]\.min: expected \[x, y, z\]"),
        ({"frames": ["left_fingertip"], "min": [0, 0.3, 0], "max": [1, 0.2, 1]}, r"tasks\[1\]\.min: min y = 0.3 m "
                                                                                  r"is above max y = 0.2 m"),
        ({"frames": ["paw"], "max": [None, 0.25, None]}, r"tasks\[1\]\.frames: human: no frame 'paw'"),
    ],
)
def test_within_errors_name_the_key(raw, message):
    with pytest.raises(TaskError, match=message):
        parse_strategy(human_body(), "right_hand", ARM, [{"type": "reach"}, {"type": "within", **raw}])


def test_within_refuses_a_frame_the_strategy_does_not_move():
    with pytest.raises(TaskError, match=r"tasks\[1\]\.frames: left_fingertip: no joint of the strategy moves"):
        parse_strategy(human_body(), "right_hand", ARM,
                       [{"type": "reach"}, {"type": "within", "frames": ["left_fingertip"], "max": [None, 0.25, None]}])


def test_hang_takes_several_chains_and_names_the_bad_one():
    body = human_body()
    legs = [["right_knee_flexion", "right_hip_flexion"], ["left_knee_flexion", "left_hip_flexion"]]
    s = parse_strategy(body, "right_hand", [*WHOLE, "*_knee_*"], [{"type": "reach"},
                                                                   {"type": "hang", "frames": legs, "cone": 90}])
    assert s.task("hang").chains == tuple(tuple(c) for c in legs)
    with pytest.raises(TaskError, match=r"tasks\[1\]\.frames\[1\]: expected at least two frames"):
        parse_strategy(body, "right_hand", WHOLE, [{"type": "reach"},
                                                   {"type": "hang", "frames": [legs[0], ["left_knee_flexion"]]}])


def test_coupling_add_keeps_the_defaults_and_names_its_rules():
    from oracles.tasks.coupling import RECTUS

    body = human_body()
    joints = [*WHOLE, "*_knee_*"]
    default = parse_strategy(body, "right_hand", joints, [{"type": "reach"}, {"type": "coupling"}]).task("coupling")
    added = parse_strategy(body, "right_hand", joints,
                           [{"type": "reach"}, {"type": "coupling", "add": [RECTUS]}]).task("coupling")
    assert added.rules[:len(default.rules)] == default.rules
    assert sorted((r.joints, r.by) for r in added.rules[len(default.rules):]) == [
        (("left_knee_flexion",), "left_hip_flexion"), (("right_knee_flexion",), "right_hip_flexion")]
    with pytest.raises(TaskError, match=r"tasks\[1\]\.add\[0\]\.joint: no joint matches 'tail'"):
        parse_strategy(body, "right_hand", joints, [{"type": "reach"}, {"type": "coupling", "add": [
            {"joint": "tail", "by": "*_hip_flexion", "limit": 1.0, "slope": 0.0}]}])
    with pytest.raises(TaskError, match=r"tasks\[1\]\.add: expected a list"):
        parse_strategy(body, "right_hand", joints, [{"type": "reach"}, {"type": "coupling", "add": RECTUS}])


def test_the_couplings_check_is_each_rule_read_on_its_own():
    """The coupling's check (one matrix over the configuration) says what its rules say one by one, at postures
    across the ranges where both verdicts come often, with the squat's knee rule added."""
    from oracles.tasks.coupling import LIMIT_TOL, RECTUS

    body = human_body()
    task = parse_strategy(body, "right_hand", [*WHOLE, "*_knee_*"],
                          [{"type": "reach"}, {"type": "coupling", "add": [RECTUS]}]).task("coupling")
    data = body.model.createData()
    lo, hi = body.model.lowerPositionLimit[7:], body.model.upperPositionLimit[7:]
    rng = np.random.default_rng(5)
    verdicts = {True: 0, False: 0}
    for _ in range(600):
        q = body.q_ref.copy()
        q[7:] += rng.uniform(0.5, 1.0) * (rng.uniform(lo, hi) - q[7:])
        by_rule = all(sum(s * q[i] for s, i in zip(r.signs, r.iq, strict=True)) - r.slope * q[r.iby]
                      <= r.limit + LIMIT_TOL for r in task.rules)
        assert task.holds(Numeric(body.model, data, q, np.zeros(3))) == by_rule
        verdicts[by_rule] += 1
    assert min(verdicts.values()) > 50
