"""The squat: buttocks near the heels, knees deeply flexed, heels free to rise.

The shipped strategy (``configs/human.yaml``'s ``right_squat``) is asked for goals low in front and beside the feet,
and every "reachable" answer is checked by our own forward kinematics (Pinocchio): the hand at its goal, each hip at or
below its knee, the balls of the feet where they stood, the knees within the squat's own 157 deg and the rectus
femoris's coupling, the centre of mass over the balls and toes where they stood (scipy's convex hull).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from oracles.protocol import Goals
from tests.helpers import com_over, reached
from tests.test_torsion import shipped

GOALS = np.array([[0.5, -0.25, 0.5], [0.6, -0.2, 0.1], [0.3, -0.35, 0.2]])  # [m] low, in front of and beside the feet
SQUAT_KNEE = math.radians(157.0)  # Hemmerich et al. 2006 (the strategy's `ranges`)


@pytest.fixture(scope="module")
def squat():
    return shipped("right_squat")


def test_the_squat_reaches_low_with_the_buttocks_near_the_heels(squat):
    body = squat.body
    model = body.model
    ref, postures = reached(squat, GOALS)
    deepest = 0.0
    for goal, q in zip(GOALS, postures, strict=True):
        data = model.createData()
        pin.framesForwardKinematics(model, data, q)

        def at(name: str, d: pin.Data = data) -> np.ndarray:
            return np.asarray(d.oMf[body.frame_id(name)].translation)

        assert np.linalg.norm(at("right_hand") - goal) <= 0.005
        for side in ("right", "left"):
            assert at(f"{side}_hip_flexion")[2] <= at(f"{side}_knee_flexion")[2] + 1e-6  # hips at or below the knees
            for ball in ("ball_inner", "ball_outer"):
                assert np.linalg.norm(at(f"{side}_{ball}") - at(f"{side}_{ball}", ref)) <= 1e-3
            knee, hip = (q[body.q_names.index(f"{side}_{j}")] for j in ("knee_flexion", "hip_flexion"))
            assert knee <= SQUAT_KNEE + 1e-6
            assert knee <= math.radians(135.0) + 22.0 / 90.0 * hip + 1e-3  # the rectus femoris's coupling
            deepest = max(deepest, knee)
        # the toes stay on the floor where they stood (the model's foot is rigid: its toe tips pivot with it)
        assert com_over(model, q, np.array([at(f"{s}_{c}", ref)[:2] for s in ("right", "left")
                                            for c in ("ball_inner", "ball_outer", "toe_inner", "toe_outer")]))
    assert deepest > math.radians(140.0)  # past the muscles' 135 deg: the squat's own range is used


def test_the_squat_keeps_the_back_straighter_than_the_crouch(squat):
    """For the same low goals the crouch (heels down) stoops: its lumbar flexion is larger."""
    crouch = shipped("right_crouch")
    i = squat.body.q_names.index("lumbar_flexion")
    a, b = squat.evaluate(Goals(GOALS)), crouch.evaluate(Goals(GOALS))
    assert a.reachable.all() and b.reachable.all()
    assert np.median(a.posture[:, i]) < np.median(b.posture[:, i]) - math.radians(5.0)


@pytest.fixture(scope="module")
def atlas(tmp_path_factory):
    """A small atlas of the shipped tiptoe and squat (D_max 3, compiled programs off)."""
    import yaml

    from reach.building.atlas import build_atlas
    from reach.building.config import parse_config
    from tests.test_torsion import ROOT

    shipped_raw = yaml.safe_load((ROOT / "configs" / "human.yaml").read_text())
    raw = {**shipped_raw, "name": "squat", "box": {"min": [-0.4, -0.8, 0.0], "max": [0.9, 0.4, 2.3]},
           "depth": {"min": 2, "max": 3},
           "oracle": {**shipped_raw["oracle"], "params": {**shipped_raw["oracle"]["params"], "jit": False}},
           "strategies": [s for s in shipped_raw["strategies"] if s["name"] in ("right_tiptoe", "right_squat")]}
    tmp = tmp_path_factory.mktemp("squat")
    return build_atlas(parse_config(raw, str(tmp / "squat.yaml")), tmp / "a")


@pytest.mark.parametrize(("goal", "strategy"), [((0.5, -0.25, 0.5), "right_squat"),
                                               ((0.3, -0.3, 2.05), "right_tiptoe")])
def test_motions_from_standing_rise_onto_the_balls_and_keep_them_where_they_stood(atlas, goal, strategy):
    """From standing (which breaks the squat's hips-below-knees and the tiptoe's and squat's balance over the balls),
    the frames hold the rest, balance over the whole soles, the end holds all: by our own forward kinematics, the
    balls of the feet stay (under 1 cm), no heel goes below the floor, the centre of mass stays over the soles where
    they stood; the squat ends with the hips below the knees and the pelvis 0.4 m lower."""
    from reach.answers.select import Selector
    from reach.motion.planner import Planner

    motion = Planner(Selector(atlas)).plan("right_hand", np.array(goal))
    assert motion.strategy == strategy and motion.outcome == "reached"
    body = shipped(strategy).body
    model = body.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, motion.postures[0])
    balls = [body.frame_id(f"{s}_{b}") for s in ("right", "left") for b in ("ball_inner", "ball_outer")]
    start = np.array([data.oMf[f].translation for f in balls])
    soles = np.array([data.oMf[body.frame_id(f"{s}_{c}")].translation[:2] for s in ("right", "left")
                      for c in ("heel_inner", "heel_outer", "toe_inner", "toe_outer")])
    for q in motion.postures:
        pin.framesForwardKinematics(model, data, q)
        assert np.linalg.norm(np.array([data.oMf[f].translation for f in balls]) - start, axis=1).max() < 0.01
        assert min(data.oMf[body.frame_id(f"{s}_heel")].translation[2] for s in ("right", "left")) >= -1e-3
        assert com_over(model, q, soles)
    if strategy == "right_squat":
        q = motion.postures[-1]
        pin.framesForwardKinematics(model, data, q)
        for side in ("right", "left"):
            assert (data.oMf[body.frame_id(f"{side}_hip_flexion")].translation[2]
                    <= data.oMf[body.frame_id(f"{side}_knee_flexion")].translation[2] + 1e-6)
        assert q[2] < motion.postures[0][2] - 0.4
