"""The step forward: one foot set down in a step region, balance over the new support.

Every "reachable" answer is checked here by our own forward kinematics (Pinocchio): the hand at its goal, the stepping
foot flat on the floor inside its region, the stance foot where it stood, and the centre of mass inside the convex
hull of both feet's corners (scipy), shrunk by the margin.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial import ConvexHull

from oracles.ik.oracle import IKOracle
from oracles.ik.search import Search
from oracles.protocol import Goals
from reach.errors import TaskError
from tests.helpers import bvh_chain, bvh_end, inside_hull
from tests.test_ik import CROUCH, HUMAN, PLANTED

STANCE = {"type": "feet", "frames": ["left_foot"], "heels": "down"}
STEP = {"type": "step", "foot": "right_foot", "stance": "left_foot"}
CORNERS = ("heel_inner", "heel_outer", "toe_inner", "toe_outer")
HAND_HEIGHT = 1.0  # [m] the goals' height, about the 50th-percentile man's elbow height standing


@pytest.fixture(scope="module")
def stepping():
    return IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, STANCE, STEP, {"type": "self_collision"},
                                                  {"type": "floor"}, {"type": "coupling"}], search=Search(restarts=2))


@pytest.fixture(scope="module")
def planted():
    return IKOracle(HUMAN, "right_hand", CROUCH, [*PLANTED, {"type": "self_collision"}, {"type": "floor"},
                                                  {"type": "coupling"}], search=Search(restarts=2))


def _check_step(oracle: IKOracle, goal: np.ndarray, q: np.ndarray) -> None:
    model = oracle.body.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    ref = model.createData()
    pin.framesForwardKinematics(model, ref, oracle.body.q_ref)

    def at(d: pin.Data, name: str) -> pin.SE3:
        return d.oMf[model.getFrameId(name)]

    assert np.linalg.norm(at(data, "right_hand").translation - goal) <= 0.005
    foot, foot_ref = at(data, "right_foot"), at(ref, "right_foot")
    assert abs(foot.translation[2] - foot_ref.translation[2]) <= 1e-4  # at its standing height
    assert np.linalg.norm((foot.rotation @ foot_ref.rotation.T)[:2, 2]) <= 1e-3  # flat: its vertical still vertical
    task = oracle.strategy.task("step")
    off = foot.translation - foot_ref.translation
    assert task.forward[0] - 1e-6 <= off[0] <= task.forward[1] + 1e-6
    assert task.aside[0] - 1e-6 <= off[1] <= task.aside[1] + 1e-6
    stance, stance_ref = at(data, "left_foot"), at(ref, "left_foot")
    assert np.linalg.norm(stance.translation - stance_ref.translation) <= 1e-4
    pts = np.array([at(data, f"{side}_{c}").translation[:2] for side in ("right", "left") for c in CORNERS])
    hull = ConvexHull(pts)
    com = pin.centerOfMass(model, data, q)[:2]
    assert np.all(hull.equations[:, :2] @ com + hull.equations[:, 2] <= -task.margin + 1e-5)


def test_a_step_reaches_farther_ahead_than_the_planted_body_and_every_answer_holds(stepping, planted):
    """Goals straight ahead of the right shoulder at hand height: the step's farthest reached goal lies at least
    25 cm beyond the planted whole body's (docs/decisions/0021), and each step answer passes our own checks."""
    xs = np.arange(0.6, 1.7, 0.05)
    goals = np.column_stack([xs, np.full(len(xs), -0.15), np.full(len(xs), HAND_HEIGHT)])
    feet_planted = planted.evaluate(Goals(goals))
    stepped = stepping.evaluate(Goals(goals))
    assert feet_planted.reachable.any() and not feet_planted.reachable.all()
    farthest_planted = xs[feet_planted.reachable].max()
    farthest_step = xs[stepped.reachable].max()
    assert farthest_step >= farthest_planted + 0.25
    for g, q in zip(goals[stepped.reachable], stepped.posture[stepped.reachable], strict=True):
        _check_step(stepping, g, q)
    # the step is taken: the farthest answer's foot left its place
    model = stepping.body.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, stepped.posture[np.nonzero(stepped.reachable)[0][-1]])
    assert data.oMf[model.getFrameId("right_foot")].translation[0] > 0.3


def test_the_step_region_defaults_to_the_stature_and_bad_steps_name_their_key():
    oracle = IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, STANCE, STEP])
    stature = oracle.body.anthropometry.stature
    task = oracle.strategy.task("step")
    assert task.forward == (0.0, pytest.approx(0.41 * stature, abs=1e-3))
    assert task.turn == pytest.approx(math.radians(30))
    with pytest.raises(TaskError, match="remove the strategy's balance task"):
        IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, STANCE, STEP, {"type": "balance"}])
    with pytest.raises(TaskError, match="holds the stepping foot 'right_foot'"):
        IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, {"type": "feet"}, STEP])
    with pytest.raises(TaskError, match=r"tasks\[1\]\.forward: expected \[low, high\]"):
        IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, {**STEP, "forward": [0.5, 0.1]}, STANCE])
    with pytest.raises(TaskError, match=r"step\.margin: the feet are 0\.\d+ m wide: a margin of 0\.049 m leaves no "
                                        r"polygon"):
        IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, {**STEP, "margin": 0.049}, STANCE])
    with pytest.raises(TaskError, match=r"\.stance: expected the other foot"):
        IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, {**STEP, "stance": "right_foot"}, STANCE])
    with pytest.raises(TaskError, match=r"tasks\[1\]\.foot: one stepping foot a strategy: for either foot give two"):
        IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, {**STEP, "foot": "either"}, STANCE])


STEP_TASKS = [{"type": "reach"}, STANCE, STEP, {"type": "self_collision"}, {"type": "floor"}, {"type": "coupling"},
              {"type": "posture"}]


@pytest.fixture(scope="module")
def atlas(tmp_path_factory):
    """A small atlas: an arm, and a step (D_max 3)."""
    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config

    tmp = tmp_path_factory.mktemp("step")
    raw = {"name": "step", "body": HUMAN, "box": {"min": [-0.4, -1.0, 0.4], "max": [1.6, 0.6, 1.6]},
           "depth": {"min": 2, "max": 3}, "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "seed": 0}},
           "strategies": [{"name": "arm", "effector": "right_hand", "joints": ["right_shoulder_*", "right_elbow_*"],
                           "tasks": [{"type": "reach"}]},
                          {"name": "step", "effector": "right_hand", "joints": CROUCH, "tasks": STEP_TASKS}]}
    return build_atlas(parse_config(raw, str(tmp / "step.yaml")), tmp / "a")


def _posture(oracle: IKOracle, posture: dict, root: dict) -> np.ndarray:
    names = list(oracle.body.q_names)
    q = oracle.body.q_ref.copy()
    for k, v in posture.items():
        q[names.index(k)] = v
    q[:3], q[3:7] = root["position"], root["quaternion"]
    return q


def test_an_answer_says_where_the_step_sets_the_foot_down(atlas, capsys):
    """A query answered by the step gives ``step``: the stepping foot's frame, where the answer's posture puts it (by
    Pinocchio, computed here) and its turn; a strategy that does not step gives none."""
    from reach.answers.select import Selector

    selector = Selector(atlas)
    answer = selector.select("right_hand", np.array([1.3, -0.15, 1.0]))
    assert answer.reachable and answer.strategy == "step" and answer.step is not None
    oracle = IKOracle(HUMAN, "right_hand", CROUCH, STEP_TASKS)
    q = _posture(oracle, answer.posture, answer.root)
    model = oracle.body.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    foot = data.oMf[model.getFrameId("right_foot")]
    assert answer.step["foot"] == "right_foot"
    assert np.allclose(answer.step["position"], foot.translation, atol=1e-5)
    assert foot.translation[0] > 0.3  # it stepped
    assert abs(answer.step["yaw"]) <= math.radians(30) + 1e-6
    near = selector.select("right_hand", np.array([0.3, -0.3, 1.2]))
    assert near.strategy == "arm" and near.step is None
    assert answer.to_dict()["step"] == answer.step
    from reach.tools.cli import main

    assert main(["query", str(atlas.path), "1.3", "-0.15", "1.0", "--effector", "right_hand"]) == 0
    assert "step: right_foot set down at [" in capsys.readouterr().out


def test_a_step_motion_lifts_the_foot_sets_it_down_and_the_stance_foot_stays(atlas, tmp_path):
    """The motion to a goal the step answers: the weight shifted over the stance foot, the stepping foot lifted
    (at least 5 cm), carried and set down where the answer says, the centre of mass over the stance foot's sole as
    the foot lifts off and over both soles (the landing one where it lands) while it is in the air, and the stance
    foot still (under 1 cm) at every frame; all by our own forward kinematics. Its BVH file, read by bvhio, puts the
    stepping foot where Pinocchio does."""
    import bvhio

    from reach.answers.select import Selector
    from reach.motion.bvh import write_bvh
    from reach.motion.planner import Planner
    from reach.motion.rig import rig

    planner = Planner(Selector(atlas))
    goal = np.array([1.3, -0.15, 1.0])
    motion = planner.plan("right_hand", goal)
    assert motion.strategy == "step" and motion.outcome == "reached" and "step" in motion.parts
    answer = planner.selector.select("right_hand", goal, False)  # the stored answer the end posture settles from
    assert motion.end == "settled"
    model = IKOracle(HUMAN, "right_hand", CROUCH, STEP_TASKS).body.model
    data = model.createData()
    right, left = model.getFrameId("right_foot"), model.getFrameId("left_foot")
    feet, stance, com, soles = [], [], [], []
    for q in motion.postures:
        pin.framesForwardKinematics(model, data, q)
        feet.append(data.oMf[right].translation.copy())
        stance.append(data.oMf[left].translation.copy())
        com.append(pin.centerOfMass(model, data, q)[:2])
        soles.append(np.array([data.oMf[model.getFrameId(f"{side}_{c}")].translation[:2]
                               for side in ("left", "right") for c in CORNERS]))
    feet, stance, com = np.array(feet), np.array(stance), np.array(com)
    assert np.linalg.norm(stance - stance[0], axis=1).max() < 0.01

    air = np.nonzero(feet[:, 2] > 0.005)[0]
    apex = int(np.argmax(feet[:, 2]))
    assert feet[apex, 2] >= 0.05 and len(air) >= 5
    # the weight over the stance foot as the foot lifts off (its first half way up), over the new support while it is
    # in the air (the fall onto the landing foot)
    landing = soles[-1][len(CORNERS):]
    lift_off = [k for k in air if k < apex and feet[k, 2] < 0.5 * feet[apex, 2]]
    assert lift_off and all(inside_hull(soles[k][: len(CORNERS)], com[k]) for k in lift_off)
    assert all(inside_hull(np.vstack([soles[k][: len(CORNERS)], landing]), com[k]) for k in air)
    assert np.linalg.norm(feet[-1] - answer.step["position"]) <= 0.015
    assert feet[-1][0] - feet[0][0] > 0.3
    landed = next(k for k in range(apex, len(feet)) if feet[k, 2] <= 1e-4)
    assert np.linalg.norm(feet[landed:] - feet[-1], axis=1).max() < 0.001  # set down, the foot stays (no sliding)
    # no frame puts a segment through another or through the floor, or moves the stance foot (the tasks' own checks)
    guard = IKOracle(HUMAN, "right_hand", CROUCH, [{"type": "reach"}, STANCE, {"type": "self_collision"},
                                                   {"type": "floor"}])
    assert [f for f in guard.faults(motion.postures) if f] == []
    parsed = bvhio.readAsBvh(str(write_bvh(rig(motion, planner.body("step")), tmp_path / "step.bvh")))
    assert parsed.FrameCount == len(motion.times)

    leg = bvh_chain(parsed.Root, "right_sole")
    assert [j.Name for j in leg] == ["pelvis", "right_thigh", "right_shank", "right_sole"]
    toe = model.getFrameId("right_toe")
    for k in range(parsed.FrameCount):
        pin.framesForwardKinematics(model, data, motion.postures[k])
        assert np.linalg.norm(bvh_end(leg, parsed.Root, k) - data.oMf[toe].translation) < 0.001
