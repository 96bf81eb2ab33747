"""What a body's postures show, asked of the body alone.

The oracle protocol's body-only capabilities (:mod:`oracles.protocol`): where
postures put the effector, the body's capsules, the joint ranges, the
skeleton's bones, postures between two postures, the mirror image. An IK
oracle is a :class:`PosedBody` (:class:`oracles.ik.tasked.TaskedBody` adds
what the strategy's tasks say, :class:`oracles.ik.oracle.IKOracle` the search);
these ask nothing of the tasks but the effector and, for a standing body's
path, the foot it moves from.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin

from oracles.bodies.body import Body
from oracles.bodies.mirror import MirrorMap
from oracles.bodies.skeleton import bone_frames, build_skeleton
from oracles.protocol import Skeleton


class PosedBody:
    """A body and its effector frame, asked by Pinocchio what postures show.

    Args:
        body: The body (see :func:`oracles.bodies.body.load_body`).
        effector: The frame that reaches.
        anchor: The frame a standing body moves from (see :meth:`interpolate`), or None.
    """

    def __init__(self, body: Body, effector: str, anchor: str | None = None) -> None:
        self.body = body
        self.effector = effector
        self.anchor = anchor
        self._data = body.model.createData()
        self._bones: tuple[Skeleton, tuple[int, ...]] | None = None

    @property
    def data(self) -> pin.Data:
        """The body's Pinocchio data, the scratch of this oracle's forward kinematics and checks."""
        return self._data

    @property
    def model_hash(self) -> str:
        return self.body.hash

    @property
    def shape_hash(self) -> str:
        return self.body.shape_hash

    def reference_posture(self) -> np.ndarray:
        return self.body.q_ref.copy()

    def landmarks(self, names: list[str] | None) -> dict[str, np.ndarray]:
        """The named frames' world positions [m] in the body's reference posture (None: every frame; an unknown name:
        ModelError)."""
        return self.body.frame_positions(None, None if names is None else list(names))

    def effector_positions(self, postures: np.ndarray) -> np.ndarray:
        """Effector positions [m] (N, 3) of postures (N, nq), by Pinocchio."""
        model, data, fid = self.body.model, self._data, self.body.frame_id(self.effector)
        out = np.empty((len(postures), 3))
        for k, q in enumerate(postures):
            pin.forwardKinematics(model, data, q)
            out[k] = pin.updateFramePlacement(model, data, fid).translation
        return out

    def shape(self, posture: np.ndarray) -> tuple[list[str], np.ndarray]:
        """The body's capsules (K, 7) at a posture, world frame (see :class:`oracles.protocol.Shaped`)."""
        return [p.name for p in self.body.collision.placed], self.body.capsules_at(posture)

    def posture_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The model's joint ranges per posture coordinate; a floating base's position and a continuous joint are
        unbounded."""
        model = self.body.model
        lower, upper = model.lowerPositionLimit.astype(float).copy(), model.upperPositionLimit.astype(float).copy()
        for j in range(1, model.njoints):
            jm = model.joints[j]
            if j == 1 or jm.nq != 1:  # the root (its limits are the solvers' box) and continuous joints
                lower[jm.idx_q : jm.idx_q + jm.nq], upper[jm.idx_q : jm.idx_q + jm.nq] = -np.inf, np.inf
        return lower, upper

    def skeleton(self) -> Skeleton:
        """The body's bones (see :mod:`oracles.bodies.skeleton`), the effector among their ends."""
        return self._skeleton()[0]

    def bone_frames(self, postures: np.ndarray) -> np.ndarray:
        """World transforms (T, B, 4, 4) of the skeleton's bones at postures (T, nq), by Pinocchio."""
        return bone_frames(self.body.model, self._skeleton()[1], postures)

    def _skeleton(self) -> tuple[Skeleton, tuple[int, ...]]:
        if self._bones is None:
            self._bones = build_skeleton(self.body, self.effector)
        return self._bones

    def interpolate(self, q0: np.ndarray, q1: np.ndarray, s: np.ndarray, exact: bool = True) -> np.ndarray:
        """Pinocchio's interpolation on the model's configuration space (see :class:`oracles.protocol.Moving`;
        ``exact`` changes nothing here).

        With a floating root and an ``anchor`` (a foot held fixed), the root is
        then placed so that this foot follows its own interpolation between its
        two placements: a standing body moves from its foot, as people do, and
        the feet hardly slide, so that a hold has little to mend.
        """
        model, a, b = self.body.model, np.asarray(q0, float), np.asarray(q1, float)
        out = np.array([pin.interpolate(model, a, b, float(u)) for u in np.atleast_1d(s)]).reshape(-1, model.nq)
        if self.anchor is None:
            return out
        anchor, data = self.body.frame_id(self.anchor), self._data
        ends = []
        for q in (a, b):
            pin.framesForwardKinematics(model, data, q)
            ends.append(data.oMf[anchor].copy())
        for k, u in enumerate(np.atleast_1d(s)):
            pin.framesForwardKinematics(model, data, out[k])
            target = pin.SE3.Interpolate(ends[0], ends[1], float(u))
            root = target * data.oMf[anchor].inverse() * data.oMi[1]
            out[k, :3], out[k, 3:7] = root.translation, pin.Quaternion(root.rotation).coeffs()
        return out

    def mirror(self) -> Callable[[np.ndarray], np.ndarray]:
        """The map of postures to their mirror images about y = 0 (raises ModelError for an asymmetric body)."""
        return MirrorMap(self.body).mirror_q
