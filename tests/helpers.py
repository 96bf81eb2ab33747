"""Helpers shared by test modules (not a test module itself)."""

from __future__ import annotations

import os
import socket

import numpy as np
import pytest

HUMAN = {"human": {"sex": "male", "percentile": 50}}
ARM = ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*"]
LEFT_ARM = [j.replace("right_", "left_") for j in ARM]

# Debian's Chromium and ChromeDriver, for the tests that look at the viewer's page: without them those tests skip,
# saying how to install them; in CI (CI=true) a missing browser fails instead.
CHROMIUM, DRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
INSTALL = "apt-get install chromium chromium-driver"
BROWSER_MISSING = None if os.path.exists(CHROMIUM) and os.path.exists(DRIVER) else f"{CHROMIUM} or {DRIVER} not found"
browser_only = pytest.mark.skipif(BROWSER_MISSING is not None and os.environ.get("CI") != "true",
                                  reason=f"no browser ({BROWSER_MISSING}); install it with: {INSTALL}")


def human_config(d_max=3, strategies=None, name="arm"):
    return {
        "name": name,
        "body": dict(HUMAN),
        "box": {"min": [-0.6, -1.0, 0.5], "max": [0.9, 1.0, 2.1]}, "depth": {"min": 1, "max": d_max},
        # fatrop, the engine these small fixtures' figures were written on: without lower tasks (secondary: false, for
        # speed) its interior point keeps the raw reach off the joint bounds, where the batched engine's clamped steps
        # end on them (any posture that reaches is right there; the motion tests' frames were measured on fatrop's).
        "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "secondary": False, "solver": "fatrop"}},
        "strategies": strategies
        or [{"name": "right_arm", "effector": "right_hand", "joints": ARM, "tasks": [{"type": "reach"}]}],
    }


def same_tree(a, b):
    assert np.array_equal(a.kind, b.kind) and np.array_equal(a.corner, b.corner) and np.array_equal(a.depth, b.depth)
    assert np.array_equal(a.vertices.keys, b.vertices.keys)
    assert np.array_equal(a.vertices.reachable, b.vertices.reachable)
    if a.vertices.posture is not None:
        assert np.allclose(a.vertices.posture, b.vertices.posture, atol=1e-9)


class TwoLinkArm:
    """A third-party oracle, as a plug-in would register it: an analytic two-link arm with postures.

    The shoulder is at ``shoulder`` [m]; the upper arm (``upper`` m) points
    by ``yaw`` and ``pitch``; the forearm (``fore`` m) bends by ``elbow`` in
    the vertical plane of the upper arm. Its volume is the spherical shell
    ``|upper - fore| <= r <= upper + fore`` about the shoulder, solved in
    closed form. It offers the optional capabilities of
    :mod:`oracles.protocol` by their declared names only.
    """

    dim = 3
    posture_names = ("yaw", "pitch", "elbow")

    def __init__(self, upper: float = 0.3, fore: float = 0.25, shoulder: tuple[float, float, float] = (0.0, 0.0, 1.0),
                 refine: bool = False) -> None:
        self.upper, self.fore = float(upper), float(fore)
        self.shoulder = np.asarray(shoulder, float)
        self.refining = bool(refine)
        self.solved = 0

    # -- the Oracle protocol
    def evaluate(self, goals):  # noqa: ANN001, ANN201
        from oracles.protocol import Goals, Verdicts

        points = Goals.points_of(goals, 3)
        p = points - self.shoulder
        self.solved += len(p)
        r = np.clip(np.linalg.norm(p, axis=1), abs(self.upper - self.fore) + 1e-12, self.upper + self.fore)
        elbow = np.arccos(np.clip((r**2 - self.upper**2 - self.fore**2) / (2 * self.upper * self.fore), -1.0, 1.0))
        beta = np.arctan2(self.fore * np.sin(elbow), self.upper + self.fore * np.cos(elbow))
        pitch = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])) - beta
        posture = np.stack([np.arctan2(p[:, 1], p[:, 0]), pitch, elbow], axis=1)
        residual = np.linalg.norm(self.effector_positions(posture) - points, axis=1)
        return Verdicts(residual <= 1e-6, residual, posture)

    # -- optional capabilities
    @property
    def spec(self):  # noqa: ANN201
        from oracles.protocol import OracleSpec

        return OracleSpec("two-link-arm",
                          {"upper": self.upper, "fore": self.fore, "shoulder": self.shoulder.tolist(),
                           "refine": self.refining})

    def effector_positions(self, postures: np.ndarray) -> np.ndarray:
        yaw, pitch, elbow = np.asarray(postures, float).T
        u = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1)
        w = np.stack([-np.sin(pitch) * np.cos(yaw), -np.sin(pitch) * np.sin(yaw), np.cos(pitch)], axis=1)
        fore = np.cos(elbow)[:, None] * u + np.sin(elbow)[:, None] * w
        return self.shoulder + self.upper * u + self.fore * fore

    def reach_bound(self) -> tuple[np.ndarray, float]:
        return self.shoulder.copy(), self.upper + self.fore

    def variant(self, purpose: str, *, budget: float | None = None, restarts: int = 6) -> TwoLinkArm:
        return TwoLinkArm(self.upper, self.fore, tuple(self.shoulder), refine=purpose == "refine")


def two_link_arm(**params) -> TwoLinkArm:  # noqa: ANN003
    """The plug-in's factory, named by its entry point."""
    return TwoLinkArm(**params)


def strategies_service(context, job: dict, deadline: float) -> list[bytes]:  # noqa: ANN001
    """A worker hook a test adds as an operation (tests/test_server.py): the served strategies of an effector, and
    which of them hold a point, answered in a worker process."""
    import json

    selector = context.selector
    names = [n for n, e in selector.order if e == job["effector"]]
    held = [n for n in names if selector.atlas.map(n).contains_one(job["goals"][0], selector.policy)]
    return [json.dumps({"strategies": names, "held": held, "pid": os.getpid()}).encode()]


def free_port() -> int:
    """A loopback TCP port free now (the OS's pick)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


# the BVH's axes from the world's: Y up, Z forward, X to the body's left (reach.motion.rig)
Y_UP = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def quat_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation matrix of a unit quaternion (this file's own, not the parser's)."""
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def bvh_chain(joint, name: str) -> list:  # noqa: ANN001
    """The joints of a parsed BVH (bvhio) from ``joint`` down to the one called ``name`` (empty when none is)."""
    if joint.Name == name:
        return [joint]
    for child in joint.Children:
        if found := bvh_chain(child, name):
            return [joint, *found]
    return []


def bvh_end(chain: list, root: object, k: int) -> np.ndarray:
    """The world position, in the world's axes, of a chain's end site at frame k: the parsed keyframes' rotations
    and offsets multiplied here."""
    world = np.eye(4)
    for joint in chain:
        pose, local = joint.Keyframes[k], np.eye(4)
        local[:3, :3] = quat_matrix(pose.Rotation.w, pose.Rotation.x, pose.Rotation.y, pose.Rotation.z)
        local[:3, 3] = list(pose.Position) if joint is root else list(joint.Offset)
        world = world @ local
    return Y_UP.T @ (world[:3, :3] @ np.array(list(chain[-1].EndSite)) + world[:3, 3])


def reached(oracle, goals: np.ndarray):  # noqa: ANN001, ANN201
    """Asks an IK oracle for goals, asserts every one reached, and returns Pinocchio's data at the oracle's reference
    posture (frames placed) and the postures."""
    import pinocchio as pin

    from oracles.protocol import Goals

    v = oracle.evaluate(Goals(goals))
    assert v.reachable.all(), v.residual
    ref = oracle.body.model.createData()
    pin.framesForwardKinematics(oracle.body.model, ref, oracle.body.q_ref)
    return ref, v.posture


def inside_hull(points: np.ndarray, p: np.ndarray, margin: float = 0.0) -> bool:
    """Whether a point p (2,) lies inside the convex hull of points (N, 2) [m], shrunk by margin [m] (scipy's hull:
    each facet's outward normal and offset)."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(points)
    return bool(np.all(hull.equations[:, :2] @ p + hull.equations[:, 2] <= -margin + 1e-6))


def com_over(model, q: np.ndarray, points: np.ndarray, margin: float = 0.0) -> bool:  # noqa: ANN001
    """Whether the centre of mass's ground projection at q lies inside the convex hull of points (N, 2) [m], shrunk by
    margin [m]."""
    import pinocchio as pin

    return inside_hull(points, pin.centerOfMass(model, model.createData(), q)[:2], margin)
