"""Feet on the floor: ``{type: feet, frames: [right_foot, left_foot], heels: down | rise, support: [...]}``.

``heels: down`` holds each foot flat where it stands; its support polygon
is spanned by the heels' and toes' corners. ``heels: rise`` holds the balls
of the feet and lets each foot pivot about its lateral axis, heels kept at
z >= 0, over a polygon of the balls and toes. ``support`` replaces the
polygon's frames. Bodies without the generated human's heel and toe frames
use the foot frames themselves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from oracles.errors import TaskError
from oracles.tasks.base import Scope, frames
from oracles.tasks.contacts import Contact, ContactsTask

HEELS = ("down", "rise")
DOWN_SUPPORT = ["heel_inner", "heel_outer", "toe_inner", "toe_outer"]
RISE_SUPPORT = ["ball_inner", "ball_outer", "toe_inner", "toe_outer"]


def _side_frames(scope: Scope, foot: str, parts: list[str]) -> list[str]:
    """The foot's named landmarks (``right_heel_inner``...), or the foot itself when the body has none."""
    prefix = foot[: -len("foot")] if foot.endswith("foot") else f"{foot}_"
    names = [f"{prefix}{p}" for p in parts]
    return names if all(scope.body.model.existFrame(n) for n in names) else [foot]


@dataclass
class FeetTask(ContactsTask):
    """Feet held on the floor, flat or pivoting about the balls (a contacts task with foot defaults)."""

    type: ClassVar[str] = "feet"
    keys: ClassVar[frozenset[str]] = frozenset({"frames", "heels", "support"})
    summary: ClassVar[str] = "feet held flat where they stand (`heels: down`), or on their balls, pivoting, heels at z >= 0 (`heels: rise`)"

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> FeetTask:
        feet = frames(scope, raw.get("frames", ["right_foot", "left_foot"]), f"{where}.frames")
        heels = raw.get("heels", "down")
        if heels not in HEELS:
            raise TaskError(f"{where}.heels", f"expected 'down' or 'rise', got {heels!r}")
        contacts, above, support = [], [], []
        for f in feet:
            if heels == "down":
                contacts.append(Contact(f, "fixed"))
                support += _side_frames(scope, f, DOWN_SUPPORT)
            else:
                contacts.append(Contact(f, "hinge"))
                above += _side_frames(scope, f, ["heel"])
                support += _side_frames(scope, f, RISE_SUPPORT)
        if "support" in raw:
            support = list(frames(scope, raw["support"], f"{where}.support"))
        return cls.held(scope, contacts, above, support)  # type: ignore[return-value]
