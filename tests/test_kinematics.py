"""CasADi kinematics against Pinocchio's numeric kinematics, to 1e-9."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from oracles.bodies.body import human_body, urdf_body
from oracles.bodies.kinematics import SymbolicKinematics

HERE = Path(__file__).resolve().parent


def _random_q(model: pin.Model, rng: np.random.Generator) -> np.ndarray:
    lo = np.clip(model.lowerPositionLimit, -3.0, 3.0)
    hi = np.clip(model.upperPositionLimit, -3.0, 3.0)
    q = rng.uniform(lo, hi)
    # Normalise every quaternion or (cos, sin) block the joints carry.
    for j in range(1, model.njoints):
        jm = model.joints[j]
        kind, i = jm.shortname(), jm.idx_q
        if kind == "JointModelFreeFlyer":
            q[i + 3 : i + 7] /= np.linalg.norm(q[i + 3 : i + 7])
        elif kind == "JointModelSpherical":
            q[i : i + 4] /= np.linalg.norm(q[i : i + 4])
        elif kind.startswith("JointModelRUB") or kind == "JointModelRevoluteUnboundedUnaligned":
            a = rng.uniform(-np.pi, np.pi)
            q[i : i + 2] = np.cos(a), np.sin(a)
        elif kind == "JointModelPlanar":
            a = rng.uniform(-np.pi, np.pi)
            q[i + 2 : i + 4] = np.cos(a), np.sin(a)
    return q


def _check(model: pin.Model, seed: int, n: int = 20) -> None:
    frames = [str(f.name) for f in model.frames if str(f.name) != "universe"]
    fk = SymbolicKinematics(model).function(frames)
    data = model.createData()
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q = _random_q(model, rng)
        pin.framesForwardKinematics(model, data, q)
        pos, rot, com = (np.asarray(v) for v in fk(q))
        for k, name in enumerate(frames):
            placement = data.oMf[model.getFrameId(name)]
            assert np.allclose(pos[:, k], placement.translation, atol=1e-9, rtol=0), name
            assert np.allclose(rot[:, 3 * k : 3 * k + 3], placement.rotation, atol=1e-9, rtol=0), name
        assert np.allclose(com.ravel(), pin.centerOfMass(model, data, q), atol=1e-9, rtol=0)


def test_human_frames_and_com_match_pinocchio():
    _check(human_body().model, seed=0)


def test_every_urdf_joint_type_matches_pinocchio():
    # revolute (aligned and not), continuous, prismatic (aligned and not),
    # planar and floating joints, as the URDF parser yields them.
    body = urdf_body(HERE / "data" / "all_joints.urdf")
    kinds = {body.model.joints[j].shortname() for j in range(1, body.model.njoints)}
    assert {"JointModelFreeFlyer", "JointModelRevoluteUnaligned", "JointModelRZ", "JointModelRUBX", "JointModelPX",
            "JointModelPrismaticUnaligned", "JointModelPlanar"} <= kinds
    _check(body.model, seed=1)


@pytest.mark.parametrize("kind",
                         ["JointModelSpherical", "JointModelSphericalZYX", "JointModelTranslation",
                          "JointModelRevoluteUnboundedUnaligned"])
def test_other_joint_types_match_pinocchio(kind):
    model = pin.Model()
    joint = getattr(pin, kind)()
    j = model.addJoint(0, joint, pin.SE3(pin.rpy.rpyToMatrix(0.1, 0.2, 0.3), np.array([0.1, 0.2, 0.3])), "j")
    model.appendBodyToJoint(j, pin.Inertia(2.0, np.array([0.1, -0.2, 0.3]), np.eye(3) * 0.01), pin.SE3.Identity())
    model.addFrame(pin.Frame("tip", j, 0, pin.SE3(np.eye(3), np.array([0.4, 0.0, -0.1])), pin.FrameType.OP_FRAME))
    _check(model, seed=2)


def test_x_of_q_inverts_q_of_x_for_every_one_axis_joint_type():
    # x holds one coordinate per active joint: a continuous joint's (cos, sin) pair maps back to its angle.
    from oracles.ik.problem import ReachProblem
    from oracles.ik.strategy import parse_strategy

    body = urdf_body(HERE / "data" / "all_joints.urdf")
    joints = ["revolute_skew", "revolute_z", "continuous_x", "prismatic_x", "prismatic_skew"]
    problem = ReachProblem(body, parse_strategy(body, "tool", joints, [{"type": "reach"}]))
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.uniform(np.maximum(problem.lower, -3.0), np.minimum(problem.upper, 3.0))
        q = problem.q_of_x(x)
        assert np.allclose(problem.x_of_q(q), x, atol=1e-12)
        assert np.isclose(q[body.model.joints[body.joint_id("continuous_x")].idx_q + 1], np.sin(x[2]))
