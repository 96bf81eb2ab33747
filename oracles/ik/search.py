"""How an IK oracle looks for a posture: its starts, restarts and when it stops.

:class:`Search` is the policy half of an IK oracle; the engine (CasADi's
programs, damped least squares) is the other. An oracle holds one Search;
``variant(purpose)`` replaces it and shares everything else (body, problem,
compiled programs). The measurements behind the defaults and the shipped
configs' choices are in docs/decisions/0002 and 0007.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from oracles.errors import OracleError

NEAR_HINT = 0.1  # [m] default of `decisive`: a hint this close to the goal makes its failed warm solve decisive
# [m] default of `give_up`: a decisive hint that fails ending nearer than this keeps the goal's other starts. The
# batched engine runs them beside the hint, so keeping them costs little; on the truth suite the arm and upper body,
# asked as a build asks, lost 2 and 3 proven goals against 5 and 5 with 0 (docs/results.md, "The truth suite").
GIVE_UP = 0.1
INDEX_SETTLE = 0.01  # [m] the index variant's `settle`: its hints reach the vertex already (within the reach tolerance)


@dataclass(frozen=True)
class Search:
    """The search policy of an IK oracle (every field is also a flat key of the oracle's ``params``).

    Attributes:
        restarts: Seeded random starts tried after the hint and the reference posture.
        seed: Seed of those starts; each goal derives its own stream from it and its coordinates.
        secondary: Also solve the tasks below reach (gaze, posture). They never
            change a verdict, only which reaching posture is kept.
        max_seconds: Time budget [s] of one ``evaluate`` call; None for none.
        give_up: Distance [m]: a decisive warm start (see ``decisive``) that fails
            and ends farther than this from the goal skips the reference start
            and all but ``rescues`` random ones. None tries every start always.
        rescues: Random starts still tried after giving up.
        decisive: Distance [m]: a hint whose effector lies within it of the goal
            makes its failed warm solve decisive (see ``give_up``).
        settle: Distance [m]: a hint this near the goal solves the reach stage
            alone, pulled towards the hint (the neighbour's posture moved the
            least that reaches); 0 solves every stage always.
        prefer: Try every start even after one reaches and keep the reaching
            posture the lower tasks like best.
        reference_first: Without a current posture, start from the reference
            and ready postures before the hint (their basin is the natural one).
    """

    restarts: int = 3
    seed: int = 0
    secondary: bool = True
    max_seconds: float | None = None
    give_up: float | None = GIVE_UP
    rescues: int = 0
    decisive: float = NEAR_HINT
    settle: float = 0.0
    prefer: bool = False
    reference_first: bool = False

    def __post_init__(self) -> None:
        for name in ("restarts", "seed", "rescues"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or (name != "seed" and value < 0):
                raise OracleError(f"{name} must be a whole number{'' if name == 'seed' else ' >= 0'}, got {value!r}",
                                  key=name)
        for name in ("give_up", "decisive", "settle", "max_seconds"):
            value = getattr(self, name)
            if value is None and name in ("give_up", "max_seconds"):
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise OracleError(f"{name} must be a distance or time of 0 or more, got {value!r}", key=name)
        for name in ("secondary", "prefer", "reference_first"):
            if not isinstance(getattr(self, name), bool):
                raise OracleError(f"{name} must be true or false, got {getattr(self, name)!r}", key=name)

    @property
    def give_up_distance(self) -> float:
        """``give_up`` [m] with None as infinity (never give up)."""
        return math.inf if self.give_up is None else float(self.give_up)

    @classmethod
    def split(cls, params: dict[str, Any]) -> tuple[Search, dict[str, Any]]:
        """The Search named by a flat params mapping, and the params left for the engine."""
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in params.items() if k in names}), {k: v for k, v in params.items()
            if k not in names}

    def to_params(self) -> dict[str, Any]:
        """The flat params this Search is written as in a spec."""
        return dataclasses.asdict(self)

    def for_purpose(self, purpose: str, *, budget: float | None, restarts: int) -> Search:
        """The search of a purpose's variant (see :class:`oracles.protocol.Tunable`).

        ``refine``: the hint, the reference and ready postures, every one tried
        and the best-liked kept, within ``budget`` [s]; never settled, since an
        answer is the natural posture reached from the character's. ``referee``:
        a verdict only, every start, at least ``restarts`` random ones. ``index``: a verdict only, from the hints
        (the neighbouring direction's posture, the vertex's) and the reference, no random start; a hint at the
        goal solves the reach stage alone (see :mod:`reach.maps.index`).
        """
        if purpose == "index":
            return dataclasses.replace(self, restarts=0, give_up=0.0, rescues=0,
                                       decisive=max(self.decisive, NEAR_HINT), secondary=False,
                                       prefer=False, reference_first=False, settle=max(self.settle, INDEX_SETTLE))
        if purpose == "refine":
            return dataclasses.replace(self, restarts=0, give_up=None, secondary=True, max_seconds=budget, prefer=True,
                                       reference_first=True, settle=0.0)
        return dataclasses.replace(self, restarts=max(self.restarts, int(restarts)), give_up=None, secondary=False,
                                   settle=0.0)
