"""Exact reachability of the repository's UR5 (configs/urdf/ur5.urdf) by ur-analytic-ik's closed-form IK.

ur-analytic-ik's ``ur5`` is the same arm in another base frame: its base is the URDF's turned by pi about z, and its
tool frame ``tool0`` is the URDF's ``ee_link`` with the tool axis (``ee_link``'s x) as its z
(tests/test_truth_ur5.py checks both). The tool's roll about that axis is the last joint's, which moves nothing else:
whether a point is reachable depends on the tool axis alone.

* ``down_reachable``: the tool axis exactly down, a yes or no for every point (exact);
* ``any_reachable``: some of the given tool axes (``directions`` over the sphere, or a ``cone`` about straight down;
  a lower bound of position-only reachability: a point reached
  only by axes between the sampled ones counts as unreachable).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import ur_analytic_ik

URDF = Path(__file__).resolve().parents[1] / "configs" / "urdf" / "ur5.urdf"
TURN = np.diag([-1.0, -1.0, 1.0])  # the analytic base frame in the URDF's: pi about z


def frame_about(axis: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) whose z column is the unit ``axis`` (its roll is free)."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def reachable_with(point: np.ndarray, axis: np.ndarray) -> bool:
    """Whether the tool reaches ``point`` [m] (URDF base frame) with its axis along ``axis`` (URDF frame)."""
    pose = np.eye(4)
    pose[:3, :3] = frame_about(TURN @ axis)
    pose[:3, 3] = TURN @ point
    return len(ur_analytic_ik.ur5.inverse_kinematics(pose)) > 0


def down_reachable(points: np.ndarray) -> np.ndarray:
    down = np.array([0.0, 0.0, -1.0])
    return np.array([reachable_with(p, down) for p in np.asarray(points, float)], bool)


def directions(n: int) -> np.ndarray:
    """n unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5**0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def cone(degrees: float) -> np.ndarray:
    """Tool axes within ``degrees`` of straight down: straight down, and 4 tilts up to it at 16 azimuths each."""
    out = [np.array([0.0, 0.0, -1.0])]
    for tilt in np.radians(np.linspace(degrees / 4, degrees, 4)):
        for az in np.linspace(0.0, 2 * np.pi, 16, endpoint=False):
            out.append(np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)]))
    return np.array(out)


def any_reachable(points: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Whether some of the tool ``axes`` reaches each point (a lower bound of reaching with any axis between them)."""
    return np.array([any(reachable_with(p, a) for a in axes) for p in np.asarray(points, float)], bool)


JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")


def tool(q: np.ndarray, names: tuple[str, ...] = JOINTS) -> tuple[np.ndarray, np.ndarray]:
    """The analytic forward kinematics of a posture (its coordinates named by ``names``; reach's postures carry the
    fixed root first): the tool's point [m] and axis, in the URDF's frame."""
    angles = [float(q[names.index(j)]) for j in JOINTS]
    pose = np.asarray(ur_analytic_ik.ur5.forward_kinematics(*angles))
    return TURN.T @ pose[:3, 3], TURN.T @ pose[:3, 2]
