"""BVH (Biovision hierarchy) files of a motion, as Blender, MotionBuilder and most animation tools import them.

The hierarchy is the body's skeleton (:mod:`oracles.bodies.skeleton`: a bone per
group of joints at one point), in the tools' Y-up axes (:mod:`reach.motion.rig`),
offsets in metres (Blender's importer reads them at scale 1 as metres). The
root has six channels (``Xposition Yposition Zposition`` then the
rotation), every other bone three. Rotations are ``Zrotation Xrotation
Yrotation`` in degrees: a bone's rotation relative to its parent is
R = Rz(z) Rx(x) Ry(y), intrinsic, the order most BVH files use. The angles
are read off each rotation matrix (scipy's ``as_euler("ZXY")``), not chained
from earlier angles, then unwrapped along the frames so that no channel
jumps by a turn. Leaf bones end in an ``End Site`` at the frame that ends
them (a hand at the hand's reach point).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from reach.motion.rig import Rig

ORDER = "ZXY"  # the channels' order; R = Rz Rx Ry
DIGITS = 6  # decimals: micrometres, micro-degrees


def bvh_text(rig: Rig) -> str:
    """The BVH file's text."""
    sk = rig.skeleton
    children: dict[int, list[int]] = {b: [] for b in range(len(sk.bones))}
    for b, p in enumerate(sk.parents):
        if p >= 0:
            children[p].append(b)
    end_of: dict[int, int] = {}  # a leaf bone -> its end (the first listed)
    for e, (_, bone, _) in enumerate(sk.ends):
        end_of.setdefault(bone, e)
    channels = " ".join(f"{axis}rotation" for axis in ORDER)
    lines = ["HIERARCHY"]

    def write(b: int, depth: int) -> None:
        pad = "  " * depth
        root = sk.parents[b] < 0
        lines.append(f"{pad}{'ROOT' if root else 'JOINT'} {sk.bones[b]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {_vec(rig.offsets[b])}")
        lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition {channels}" if root else f"{pad}  CHANNELS 3 "
            f"{channels}")
        for c in children[b]:
            write(c, depth + 1)
        if not children[b]:
            offset = rig.ends[end_of[b]] if b in end_of else np.zeros(3)
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {_vec(offset)}", f"{pad}  }}"])
        lines.append(pad + "}")

    write(0, 0)
    order = _depth_first(children)
    t, n = rig.rotations.shape[:2]
    angles = Rotation.from_matrix(rig.rotations.reshape(-1, 3, 3)).as_euler(ORDER, degrees=True).reshape(t, n, 3)
    angles = np.degrees(np.unwrap(np.radians(angles), axis=0))
    lines += ["MOTION", f"Frames: {t}", f"Frame Time: {1.0 / rig.rate:.{DIGITS + 2}f}"]
    for k in range(t):
        values = [rig.root[k]] + [angles[k, b] for b in order]
        lines.append(" ".join(_vec(v) for v in values))
    return "\n".join(lines) + "\n"


def write_bvh(rig: Rig, path: str | Path) -> Path:
    path = Path(path)
    path.write_text(bvh_text(rig))
    return path


def _depth_first(children: dict[int, list[int]]) -> list[int]:
    """Bones in the order the hierarchy lists them (the order of the motion's channels)."""
    out, stack = [], [0]
    while stack:
        b = stack.pop()
        out.append(b)
        stack.extend(reversed(children[b]))
    return out


def _vec(v: np.ndarray) -> str:
    return " ".join(f"{float(x):.{DIGITS}f}" for x in v)
