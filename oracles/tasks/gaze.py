"""Look at the goal: ``{type: gaze, frame: eyes, cone: 15, down: 15, priority: 2}``.

The line of sight, the frame's x axis turned ``down`` degrees below it
(about the frame's y axis), points within ``cone`` degrees of the goal:
the eyes turn the rest of the way. Its stage minimises
1 - cos of the angle between them (the head aims as well as it can); the
stages below it (the posture) then keep the angle within the cone, or
within what the stage reached when that is wider, so a goal the eyes can
reach leaves the neck to the posture task instead of driving it to its
limit. (A cost that is zero inside the cone converged in 40 fatrop
iterations where this takes a few.)

The default cone, 15 deg, is the easy eye rotation of MIL-STD-1472 (US
Department of Defense, *Human Engineering*, visual fields: eye rotation
"easy" 15 deg from the normal line of sight); ``cone: 0`` aims the head
itself at the goal.

The eyes rest looking down, not straight ahead: with trunk and head
upright, people prefer a line of sight 29 deg below the horizontal on
average (s.d. 11.6 deg; 24 deg for a target at 1 m, 33 deg at 0.5 m),
"much more steeply than listed in most human engineering design guides"
(Kroemer, K.H.E. & Hill, S.G. (1986), Preferred line of sight angle,
*Ergonomics* 29(9), 1129-1134, doi:10.1080/00140138608967228). The default
``down``, 15 deg, puts the easy cone between eye level and 30 deg below
the horizontal for an upright head: a goal at eye level needs no neck
extension and the measured preference lies inside the cone (a modelling
choice within the measurement's spread). Without it the neck bent fully
(45 deg) to look at goals near the feet that the eyes take at 30 deg.
``down: 0`` keeps the frame's x axis as the line of sight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from oracles.tasks.base import Numeric, Reference, Row, Scope, SoftTask, Symbolic, frame, number

CONE = 15.0  # [deg] the eyes' easy rotation (MIL-STD-1472; see the module docstring)
# [deg] the line of sight below the head's x axis (Kroemer & Hill 1986: 29 +- 11.6 deg preferred; see the module
# docstring)
DOWN = 15.0


@dataclass
class GazeTask(SoftTask):
    """Point a frame's line of sight (the eyes') at the goal."""

    type: ClassVar[str] = "gaze"
    keys: ClassVar[frozenset[str]] = frozenset({"frame", "cone", "down"})
    summary: ClassVar[str] = ("the line of sight of `frame` (default the `eyes`: its x axis turned `down` deg, "
                              "default 15) within `cone` deg (default 15: the eyes' easy rotation) of the goal")
    default_priority: ClassVar[int] = 2
    # [1 - cos of the gaze error]: about 0.8 deg beyond the cone (or from a perfect aim with none)
    slack: ClassVar[float] = 1e-4

    frame: str
    priority: float = 2.0
    cone: float = math.radians(CONE)  # [rad]
    down: float = math.radians(DOWN)  # [rad]
    _id: int = field(default=-1, init=False, repr=False, compare=False)

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> GazeTask:
        cone = number(raw.get("cone", CONE), f"{where}.cone", 0.0, 60.0)
        down = number(raw.get("down", DOWN), f"{where}.down", -45.0, 60.0)
        return cls(frame(scope, raw.get("frame", "eyes"), f"{where}.frame"), cls.priority_of(raw, where),
                   math.radians(cone), math.radians(down))

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "frame": self.frame, "cone_deg": round(math.degrees(self.cone), 3),
                "down_deg": round(math.degrees(self.down), 3)}

    @property
    def sight(self) -> np.ndarray:
        """The line of sight in the frame's coordinates: x turned ``down`` about y."""
        return np.array([math.cos(self.down), 0.0, -math.sin(self.down)])

    parametric: ClassVar[bool] = True  # the body enters only through the kinematics

    def bind(self, reference: Reference) -> None:
        self._id = reference.body.frame_id(self.frame)

    def objective(self, sym: Symbolic) -> ca.SX:
        rot, pos = sym.kin.frame(self.frame)
        to_goal = sym.goal - pos
        return 1.0 - ca.dot(rot @ ca.DM(self.sight), to_goal) / (ca.norm_2(to_goal) + 1e-9)

    @property
    def free(self) -> float:
        """Lower stages keep the line of sight within the cone (or the stage's optimum, if wider)."""
        return 1.0 - math.cos(self.cone)

    def level(self, num: Numeric) -> Row:
        assert num.jacobian is not None
        eye = num.frame(self._id)
        d, u = eye.rotation @ self.sight, num.goal - eye.translation
        u = u / (np.linalg.norm(u) + 1e-9)
        angle = float(np.arccos(np.clip(d @ u, -1.0, 1.0)))
        # Turn the line of sight towards the goal by what the cone leaves over (nothing inside it).
        axis = np.cross(d, u)
        scale = max(angle - self.cone, 0.0) / angle if angle > 1e-9 else 0.0
        return Row(num.jacobian(self._id)[3:], axis / (np.linalg.norm(axis) + 1e-12) * angle * scale if scale
                   else np.zeros(3))
