"""A body's skeleton: its joints grouped into bones, for animation files.

A human's shoulder is three revolute joints at one point (flexion, abduction,
rotation); an animation tool wants one bone there that turns in 3-D. A bone
is a chain of joints that share a point: a joint joins its parent's bone when
its placement has no translation, it is the parent joint's only child, and
nothing (a capsule, an end) hangs on the parent joint. The bone is named after
the link its last joint moves (the URDF's child link), so the human's bones
are ``pelvis``, ``right_upper_arm``, ``right_hand`` ... and a robot's are its
links.

Each leaf bone ends at the frame on it farthest from its origin (the hand's
``right_hand``, the foot's toe, the head's eyes); the strategy's effector is
an end too, wherever it is.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from oracles.errors import ModelError
from oracles.protocol import Skeleton

if TYPE_CHECKING:
    from oracles.bodies.body import Body

SHARED = 1e-9  # [m] a placement this short puts two joints at one point
NEAR = 0.01  # [m] frames this close to a leaf's farthest one end it as well
TURNING = ("JointModelR", "JointModelSpherical")  # Pinocchio's revolute (bounded or not, any axis) and spherical joints


def build_skeleton(body: Body, effector: str | None = None) -> tuple[Skeleton, tuple[int, ...]]:
    """The body's skeleton and, per bone, the Pinocchio joint whose frame is the bone's frame (its last joint)."""
    model = body.model
    eff_joint = int(model.frames[body.frame_id(effector)].parentJoint) if effector else -1
    _check_turning(body)
    bone_of, chains, parents = _bones(model, {p.joint for p in body.collision.placed} | {eff_joint})
    last = tuple(c[-1] for c in chains)
    names = tuple(_link_name(model, j) for j in last)
    leaves = set(range(len(chains))) - set(parents)
    ends = [_leaf_end(body, b, last[b], eff_joint, effector, names[b]) for b in sorted(leaves)]
    if effector and effector not in [e[0] for e in ends]:
        f = model.frames[body.frame_id(effector)]
        ends.append((effector, bone_of[int(f.parentJoint)], _xyz(f.placement.translation)))
    capsules = np.array([[*p.a, *p.b, p.radius] for p in body.collision.placed], float).reshape(-1, 7)
    capsule_bones = tuple(bone_of[p.joint] for p in body.collision.placed)
    skeleton = Skeleton(names, tuple(tuple(str(model.names[j]) for j in c) for c in chains), tuple(parents),
                        tuple(ends), tuple(p.name for p in body.collision.placed), capsules, capsule_bones)
    return skeleton, last


def _check_turning(body: Body) -> None:
    """Every joint but the root (which may float) only turns; ModelError naming the first that translates."""
    model = body.model
    for j in range(2, model.njoints):
        kind = model.joints[j].shortname()
        if not kind.startswith(TURNING):
            raise ModelError(f"joint {model.names[j]!r} is a {kind}, which translates; a skeleton's bones only turn "
                             "(write the motion as .json)", source=body.source, name=str(model.names[j]))


def _bones(model: pin.Model, hung: set[int]) -> tuple[dict[int, int], list[list[int]], list[int]]:
    """Each joint's bone, each bone's chain of joints, and each bone's parent bone (-1: none): a joint at its
    parent's place, its parent's only child, joins its parent's bone unless something hangs on the parent (a capsule,
    the effector) or the parent is the root."""
    children: dict[int, list[int]] = {j: [] for j in range(model.njoints)}
    for j in range(2, model.njoints):
        children[int(model.parents[j])].append(j)
    bone_of: dict[int, int] = {}
    chains: list[list[int]] = []
    parents: list[int] = []
    for j in range(1, model.njoints):  # Pinocchio numbers a parent before its children
        p = int(model.parents[j])
        merge = (j != 1 and np.linalg.norm(model.jointPlacements[j].translation) < SHARED and children[p] == [j]
                 and p not in hung
                 and p != 1)
        if merge:
            bone_of[j] = bone_of[p]
            chains[bone_of[p]].append(j)
        else:
            bone_of[j] = len(chains)
            parents.append(bone_of[p] if j != 1 else -1)
            chains.append([j])
    return bone_of, chains, parents


def _leaf_end(body: Body, b: int, joint: int, eff_joint: int, effector: str | None,
              name: str) -> tuple[str, int, tuple[float, float, float]]:
    """A leaf bone's end: the effector's frame when it is on the bone, else its farthest frame (of those within
    ``NEAR`` of the farthest, the plainest name: the toe, not the toe's inner edge), else the bone's own origin."""
    model = body.model
    frames = [f for f in model.frames if int(f.parentJoint) == joint
              and f.type in (pin.FrameType.BODY, pin.FrameType.OP_FRAME)]
    if joint == eff_joint:  # a leaf holds one end: the effector's, when it is on it
        frames = [model.frames[body.frame_id(str(effector))]]
    if not frames:
        return name + "_end", b, (0.0, 0.0, 0.0)
    reach = max(float(np.linalg.norm(f.placement.translation)) for f in frames)
    far = min((f for f in frames if np.linalg.norm(f.placement.translation) > reach - NEAR),
              key=lambda f: (len(f.name), f.name))
    return str(far.name), b, _xyz(far.placement.translation)


def bone_frames(model: pin.Model, last: tuple[int, ...], postures: np.ndarray) -> np.ndarray:
    """World transforms (T, B, 4, 4) of each bone at each posture (T, nq): Pinocchio's placement of its last joint."""
    data = model.createData()
    qs = np.atleast_2d(np.asarray(postures, float))
    out = np.empty((len(qs), len(last), 4, 4))
    for t, q in enumerate(qs):
        pin.forwardKinematics(model, data, q)
        for b, j in enumerate(last):
            out[t, b] = data.oMi[j].homogeneous
    return out


def _link_name(model: pin.Model, joint: int) -> str:
    """The link a joint moves: the first body frame on it (Pinocchio adds it right after the joint's own frame)."""
    for f in model.frames:
        if int(f.parentJoint) == joint and f.type == pin.FrameType.BODY:
            return str(f.name)
    return str(model.names[joint])


def _xyz(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])
