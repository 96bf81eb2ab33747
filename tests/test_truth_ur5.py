"""A UR5 against exact analytic IK: ur-analytic-ik's closed form says which points its tool
reaches; the oracle must find those, and every posture it finds is checked by the analytic forward kinematics."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from analytic_ur5 import URDF, any_reachable, cone, directions, down_reachable, tool

from oracles.ik.oracle import IKOracle
from oracles.ik.search import Search

BODY = {"urdf": str(URDF)}
DOWN = [{"type": "reach"}, {"type": "orientation", "axis": "x", "direction": "-z", "cone": 5}]
# Points about the arm: inside, outside, near its base's column and its outer shell.
POINTS = np.random.default_rng(48).uniform([-0.95, -0.95, -0.45], [0.95, 0.95, 1.05], (60, 3))


def test_the_repository_ur5_is_the_analytic_one():
    model = pin.buildModelFromUrdf(str(URDF))
    data = model.createData()
    fid = model.getFrameId("ee_link")
    for q in np.random.default_rng(0).uniform(-math.pi, math.pi, (50, 6)):
        pin.framesForwardKinematics(model, data, q)
        point, axis = tool(q)
        np.testing.assert_allclose(data.oMf[fid].translation, point, atol=1e-8)  # the URDF's pi/2 has 9 digits
        np.testing.assert_allclose(data.oMf[fid].rotation[:, 0], axis, atol=1e-8)


def test_tool_down_verdicts_against_exact_ik():
    oracle = IKOracle(BODY, "ee_link", ["*_joint"], DOWN, search=Search(restarts=2, seed=0))
    v = oracle.evaluate(POINTS)
    truth = down_reachable(POINTS)
    assert 10 <= truth.sum() <= 50  # the points tell something
    missed = POINTS[truth & ~v.reachable]
    assert not len(missed), f"exactly-down reachable, called unreachable: {missed.round(3).tolist()}"
    for p, q in zip(POINTS[v.reachable], np.asarray(v.posture)[v.reachable], strict=True):
        point, axis = tool(q, oracle.posture_names)
        assert np.linalg.norm(point - p) <= oracle.strategy.tolerance + 1e-9
        assert axis[2] <= -math.cos(math.radians(5.0)) + 1e-6
    # a reachable verdict the exact IK says no to with the axis straight down needs the cone's tilt
    tilted = v.reachable & ~truth
    assert any_reachable(POINTS[tilted], cone(5.0)).all(), POINTS[tilted].round(3).tolist()


def test_position_only_verdicts_against_analytic_ik():
    oracle = IKOracle(BODY, "ee_link", ["*_joint"], [{"type": "reach"}], search=Search(restarts=2, seed=0))
    v = oracle.evaluate(POINTS)
    missed = POINTS[~v.reachable & any_reachable(POINTS, directions(300))]
    assert not len(missed), f"reachable by analytic IK: {missed.round(3).tolist()}"
    for p, q in zip(POINTS[v.reachable], np.asarray(v.posture)[v.reachable], strict=True):
        assert np.linalg.norm(tool(q, oracle.posture_names)[0] - p) <= oracle.strategy.tolerance + 1e-9
