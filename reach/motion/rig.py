"""A motion as bones: the form animation files (BVH, glTF) write.

The oracle's :class:`~oracles.protocol.Articulated` capability gives the
skeleton and each bone's world transform at each frame; a rig holds each
bone's offset from its parent and its rotation relative to its parent, per
frame, and the root's position.

Animation tools are Y-up, the atlas's world is Z-up (x forward, y to the
body's left). A rig is written in the tools' axes: x' = y (left), y' = z
(up), z' = x (forward), glTF's own convention (+Y up, +Z forward, +X left)
and the usual one of BVH. Every bone frame is turned alike (W' = C W C^T), so
that a bone at rest (no rotation) stands as the body's reference frame does:
a human's rest pose is upright, not lying on its back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from oracles.protocol import Articulated, Skeleton
from reach.errors import InputError
from reach.motion.planner import Motion

# Rows: the tools' x, y, z in the atlas's world axes (a cyclic permutation: a proper rotation).
TO_Y_UP = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
RIGID = 1e-9  # [m] an offset varying more than this between frames is not a bone's


@dataclass(frozen=True)
class Rig:
    """A motion as bone transforms, in the tools' Y-up axes [m].

    Attributes:
        skeleton: The bones, their parents, ends and capsules (atlas axes).
        offsets: (B, 3) each bone's origin in its parent's frame (the root's: zero).
        rotations: (T, B, 3, 3) each bone's rotation relative to its parent (the root's: to the world).
        root: (T, 3) the root bone's origin in the world.
        ends: (E, 3) each end's offset in its bone's frame, in the order of ``skeleton.ends``.
        capsules: (K, 7) the capsules' end points in their bone's frame and radius.
        times: (T,) [s].
        rate: [Hz] frames per second.
    """

    skeleton: Skeleton
    offsets: np.ndarray
    rotations: np.ndarray
    root: np.ndarray
    ends: np.ndarray
    capsules: np.ndarray
    times: np.ndarray
    rate: float

    @property
    def bones(self) -> tuple[str, ...]:
        return self.skeleton.bones

    def to_dict(self) -> dict[str, Any]:
        """The rig as JSON-compatible data (a motion reply's ``rig``; :meth:`from_dict` reads it back)."""
        sk = self.skeleton
        return {"bones": list(sk.bones), "joints": [list(j) for j in sk.joints], "parents": list(sk.parents),
                "ends": [[name, bone, list(offset)] for name, bone, offset in sk.ends],
                "capsule_names": list(sk.capsule_names),
                "capsule_bones": list(sk.capsule_bones), "bone_capsules": np.asarray(sk.capsules, float).tolist(),
                "offsets": self.offsets.tolist(), "rotations": self.rotations.tolist(), "root": self.root.tolist(),
                "end_offsets": self.ends.tolist(), "capsules": self.capsules.tolist(), "times": self.times.tolist(),
                "rate": self.rate}

    @staticmethod
    def from_dict(data: Any) -> Rig:
        """A rig from :meth:`to_dict`'s data (a server's motion reply); raises InputError naming ``rig`` when
        malformed."""
        try:
            bones = tuple(str(b) for b in data["bones"])
            n = len(bones)
            skeleton = Skeleton(bones, tuple(tuple(str(j) for j in js) for js in data["joints"]),
                                tuple(int(p) for p in data["parents"]),
                                tuple((str(e[0]), int(e[1]), (float(e[2][0]), float(e[2][1]), float(e[2][2])))
                                      for e in data["ends"]),
                                tuple(str(c) for c in data["capsule_names"]),
                                np.asarray(data["bone_capsules"], float).reshape(-1, 7),
                                tuple(int(b) for b in data["capsule_bones"]))
            times = np.asarray(data["times"], float).reshape(-1)
            t = len(times)
            out = Rig(skeleton, np.asarray(data["offsets"], float).reshape(n, 3),
                      np.asarray(data["rotations"], float).reshape(t, n, 3, 3),
                      np.asarray(data["root"], float).reshape(t, 3),
                      np.asarray(data["end_offsets"], float).reshape(-1, 3),
                      np.asarray(data["capsules"], float).reshape(-1, 7), times, float(data["rate"]))
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError("rig", f"a motion's bones are malformed ({type(exc).__name__}: {exc})") from None
        if len(skeleton.parents) != n or len(skeleton.joints) != n or len(out.ends) != len(skeleton.ends):
            raise InputError("rig", "a motion's bones, parents, joints and ends do not match")
        return out

    def world(self, frame: int) -> np.ndarray:
        """(B, 4, 4) each bone's world transform at a frame, Y-up axes."""
        out = np.empty((len(self.bones), 4, 4))
        for b, p in enumerate(self.skeleton.parents):
            local = np.eye(4)
            local[:3, :3] = self.rotations[frame, b]
            local[:3, 3] = self.root[frame] if p < 0 else self.offsets[b]
            out[b] = local if p < 0 else out[p] @ local
        return out


def rig(motion: Motion, body: object) -> Rig:
    """The rig of a motion planned on ``body`` (the strategy's oracle, :class:`~oracles.protocol.Articulated`)."""
    if not isinstance(body, Articulated):
        raise InputError("output", f"strategy {motion.strategy}'s oracle has no skeleton (no Articulated capability): "
                                   "write the motion as .json")
    skeleton = body.skeleton()
    world = np.asarray(body.bone_frames(motion.postures), float)
    c = np.eye(4)
    c[:3, :3] = TO_Y_UP
    world = c @ world @ c.T  # every bone frame in the tools' axes
    parents = np.array(skeleton.parents)
    local = world.copy()
    child = parents >= 0
    local[:, child] = np.linalg.inv(world[:, parents[child]]) @ world[:, child]
    offsets = local[:, :, :3, 3]
    spread = np.abs(offsets - offsets[:1]).max(axis=(0, 2))
    moving = [skeleton.bones[b] for b in np.flatnonzero(child & (spread > RIGID))]
    if moving:
        raise InputError("output",
                         f"bones {', '.join(moving)} change length during the motion: not a skeleton's motion")
    base = offsets[0].copy()
    base[~child] = 0.0
    ends = np.array([TO_Y_UP @ np.asarray(off) for _, _, off in skeleton.ends]).reshape(-1, 3)
    caps = np.asarray(skeleton.capsules, float).reshape(-1, 7).copy()
    caps[:, :3], caps[:, 3:6] = caps[:, :3] @ TO_Y_UP.T, caps[:, 3:6] @ TO_Y_UP.T
    root = world[:, 0, :3, 3]  # Pinocchio's one root joint is bone 0
    return Rig(skeleton, base, local[:, :, :3, :3], root, ends, caps, np.asarray(motion.times, float), motion.rate)


def with_bones(data: dict[str, Any], motion: Motion, body: object) -> dict[str, Any]:
    """A motion's data (``Motion.to_dict``) with its rig as ``rig``, for a request that asks for bones."""
    return {**data, "rig": rig(motion, body).to_dict()}
