"""Feet on the floor: ``{type: feet, frames: [right_foot, left_foot], heels: down | rise, support: [...]}``.

``heels: down`` holds each foot flat where it stands; its support polygon
is spanned by the heels' and toes' corners. ``heels: rise`` holds the balls
of the feet and lets each foot pivot about its lateral axis, heels kept at
z >= 0, over a polygon of the balls and toes.

The corners are found by name, as the generated human has them: for a foot
frame ``right_foot``, ``right_heel_inner``, ``right_heel_outer``,
``right_toe_inner``, ``right_toe_outer`` (and ``right_ball_inner``,
``right_ball_outer`` for ``heels: rise``); for a name not ending in ``foot``,
such as ``r_sole``, ``r_sole_heel_inner`` and so on. ``soles`` names each foot's polygon
explicitly instead: foot frame -> its corner frames (3 or more; add them
with the body's ``frames``), used for both ``heels`` settings. ``support``
replaces the whole polygon's frames. A foot with neither stands on its own
frame alone, and ``reach model`` and ``reach build`` warn about it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar

from oracles.errors import TaskError
from oracles.tasks.base import Scope, frames
from oracles.tasks.contacts import Contact, ContactsTask

HEELS = ("down", "rise")
DOWN_SUPPORT = ["heel_inner", "heel_outer", "toe_inner", "toe_outer"]
RISE_SUPPORT = ["ball_inner", "ball_outer", "toe_inner", "toe_outer"]


def corner_frames(model: Any, foot: str, parts: list[str]) -> list[str]:
    """The foot's named landmarks (``right_heel_inner``...) on a Pinocchio model, or the foot itself when it has
    none."""
    prefix = foot[: -len("foot")] if foot.endswith("foot") else f"{foot}_"
    names = [f"{prefix}{p}" for p in parts]
    return names if all(model.existFrame(n) for n in names) else [foot]


def _side_frames(scope: Scope, foot: str, parts: list[str]) -> list[str]:
    return corner_frames(scope.body.model, foot, parts)


@dataclass
class FeetTask(ContactsTask):
    """Feet held on the floor, flat or pivoting about the balls (a contacts task with foot defaults)."""

    type: ClassVar[str] = "feet"
    keys: ClassVar[frozenset[str]] = frozenset({"frames", "heels", "support", "soles"})
    summary: ClassVar[str] = ("feet held flat where they stand (`heels: down`), or on their balls, pivoting, heels at "
                              "z >= 0 (`heels: rise`)")

    bare: tuple[str, ...] = ()  # feet with no sole corners: each stands on its own frame alone

    @classmethod
    def parse(cls, raw: dict[str, Any], where: str, scope: Scope) -> FeetTask:
        feet = frames(scope, raw.get("frames", ["right_foot", "left_foot"]), f"{where}.frames")
        heels = raw.get("heels", "down")
        if heels not in HEELS:
            raise TaskError(f"{where}.heels", f"expected 'down' or 'rise', got {heels!r}")
        soles = raw.get("soles", {})
        if not isinstance(soles, dict) or set(soles) - set(feet):
            raise TaskError(f"{where}.soles", f"expected a mapping of foot frame (one of {list(feet)}) to its corner "
                                              f"frames, got {soles!r}")
        contacts, above, support, bare = [], [], [], []
        for f in feet:
            if f in soles:
                corners = list(frames(scope, soles[f], f"{where}.soles.{f}"))
                if len(set(corners)) < 3:
                    raise TaskError(f"{where}.soles.{f}", "expected 3 corner frames or more (a polygon), got "
                                                          f"{corners!r}")
            else:
                corners = _side_frames(scope, f, DOWN_SUPPORT if heels == "down" else RISE_SUPPORT)
                bare += [f] if corners == [f] else []
            support += corners
            if heels == "down":
                contacts.append(Contact(f, "fixed"))
            else:
                contacts.append(Contact(f, "hinge"))
                above += _side_frames(scope, f, ["heel"])
        if "support" in raw:
            support = list(frames(scope, raw["support"], f"{where}.support"))
            bare = []
        task = cls.held(scope, contacts, above, support)
        assert isinstance(task, FeetTask)
        return replace(task, bare=tuple(bare))

    @property
    def rising(self) -> bool:
        """Whether the heels may rise (each foot pivots about its ball)."""
        return any(c.mode == "hinge" for c in self.contacts)

    def warnings(self) -> list[str]:
        return [f"foot {f!r} has no sole corners (no frames named as the feet task's docs say, no soles.{f}): it "
                "stands on its own frame alone, a point, and balance has no polygon from it; give soles: "
                f"{{{f}: [corner frames]}}"
                for f in self.bare]
