"""The truth suite's independent check and an engine's score on it.

The suite (``tests/data/truth``, stored as :mod:`reach.maps.truth` reads it) holds goals labelled by a thorough
referee, each "reachable" label kept with the posture that proves it. ``bench/truth.py`` writes it;
``tests/test_truth.py`` and ``bench/truth.py`` score an engine on it here.

A "reachable" label is proven: its posture passes :func:`independent_check`. An "unreachable" label is only what
no search of the referee found; an engine that reaches such a goal with a posture that passes the check is right,
and the suite is regenerated.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import coal
import numpy as np
import pinocchio as pin

from reach.maps.truth import Suite
from reach.maps.truth import load_suite as stored_suite
from reach.maps.truth import provenance as stored_provenance

SUITE = Path(__file__).resolve().parent / "data" / "truth"
LIMIT_TOL = 1e-6  # [rad or m] a joint this far past its range still holds (the interior-point programs' tolerance)
GAP_TOL = 1e-6  # [m] coal's distance this far below a pair's floor still holds


ROOT = SUITE.parents[2]
POPULATION = "configs/population.yaml"  # the population suite's config: its strategies, for members of the survey


def member_config(sex: str, subject: int) -> Any:
    """POPULATION's config for one member, its body the subject's own (as a ``population:`` member's)."""
    import yaml

    from reach.building.config import parse_config

    raw = yaml.safe_load((ROOT / POPULATION).read_text())
    raw.pop("population")
    raw["body"] = {"human": {**(raw.get("body") or {}).get("human", {}), "ansur": {"sex": sex, "subject": subject}}}
    raw["name"] = f"{sex}_{subject}"
    return parse_config(raw, f"{POPULATION} (member {raw['name']})", raw["name"])


def suite_spec(name: str, folder: Path = SUITE) -> Any:
    """The oracle spec a suite was made for: its config's strategy, or a population member's (``MEMBER.STRATEGY``)."""
    from reach.building.config import load_config

    entry = provenance(folder)["strategies"][name]
    if "member" in entry:
        return member_config(entry["member"]["sex"], entry["member"]["subject"]).strategy(name.split(".", 1)[1]).oracle
    config = Path(entry["config"])
    return load_config(config if config.is_absolute() else ROOT / config).strategy(name).oracle


def load_suite(strategy: str, folder: Path = SUITE) -> Suite:
    return stored_suite(strategy, folder)


def provenance(folder: Path = SUITE) -> dict[str, Any]:
    return stored_provenance(folder)


def _capsule(a: np.ndarray, b: np.ndarray, r: float) -> tuple[Any, Any]:
    """coal's capsule between world points a and b (a sphere when they meet), and its placement."""
    axis = b - a
    n = float(np.linalg.norm(axis))
    if n < 1e-12:
        return coal.Sphere(r), coal.Transform3s(np.eye(3), a)
    z = axis / n
    x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    return coal.Capsule(r, n), coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), 0.5 * (a + b))


def independent_check(oracle: Any, q: np.ndarray, goal: np.ndarray) -> list[str]:
    """What a posture breaks, by this module's own computations where it can: the effector's distance to the goal
    by Pinocchio's forward kinematics, the joints' ranges, every self-collision pair by coal on capsules placed by
    those kinematics, every capsule above the floor; the other hard tasks (feet, balance, couplings, hang, ...) by
    their own verdicts. An empty list: the posture proves the goal reachable."""
    model = oracle.body.model
    data = model.createData()
    q = np.asarray(q, float)
    pin.framesForwardKinematics(model, data, q)
    faults = []
    hand = data.oMf[model.getFrameId(oracle.effector)].translation
    if np.linalg.norm(hand - goal) > oracle.strategy.tolerance + 1e-9:
        faults.append(f"reach ({np.linalg.norm(hand - goal) * 1e3:.1f} mm)")
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    bounded = np.isfinite(lo) & np.isfinite(hi) & (hi - lo < 1e6)
    bounded[:7] = False  # the floating root's coordinates
    if np.any((q < lo - LIMIT_TOL)[bounded] | (q > hi + LIMIT_TOL)[bounded]):
        faults.append("limits")
    collision = oracle.body.collision
    ends = ([collision.world(data, i) for i in range(len(collision.placed))] if collision is not None else [])
    for task in oracle.strategy.hard:
        if task.type == "self_collision":
            for pair in task.pairs:
                (a, b), (c, d) = ends[pair.first], ends[pair.second]
                ga, ta = _capsule(a, b, collision.placed[pair.first].radius)
                gb, tb = _capsule(c, d, collision.placed[pair.second].radius)
                gap = coal.distance(ga, ta, gb, tb, coal.DistanceRequest(), coal.DistanceResult())
                if gap < pair.floor - GAP_TOL:
                    faults.append(f"self_collision ({collision.placed[pair.first].name}-"
                                  f"{collision.placed[pair.second].name} {gap * 1e3:+.1f} mm)")
                    break
        elif task.type == "floor":
            low = min(min(a[2], b[2]) - collision.placed[i].radius for i, (a, b) in enumerate(ends)
                      if i in task.capsules)
            if low < -1e-4:  # the floor task's contact tolerance (oracles/tasks/floor.py)
                faults.append(f"floor ({low * 1e3:+.1f} mm)")
        else:
            faults += [f for f in oracle.faults(q[None])[0] if f == task.type]
    return sorted(set(faults))


@dataclass
class Score:
    """An engine's verdicts on a suite: goals proven reachable it calls unreachable (``false_unreachable``), its
    "reachable" answers whose posture fails the independent check (``false_reachable``), and goals labelled
    unreachable that it proves reachable (``new``: the suite is stale there)."""

    strategy: str
    goals: int
    proven: int
    false_unreachable: list[int]
    false_reachable: list[int]
    new: list[int]

    @property
    def false_unreachable_rate(self) -> float:
        return len(self.false_unreachable) / max(self.proven, 1)

    @property
    def false_reachable_rate(self) -> float:
        return len(self.false_reachable) / max(self.goals, 1)

    def line(self) -> dict[str, Any]:
        return {"strategy": self.strategy, "goals": self.goals, "proven_reachable": self.proven,
                "false_unreachable": len(self.false_unreachable),
                "false_unreachable_rate": round(self.false_unreachable_rate, 4),
                "false_reachable": len(self.false_reachable),
                "false_reachable_rate": round(self.false_reachable_rate, 4), "reached_beyond_suite": len(self.new)}


def score(oracle: Any, suite: Suite, verdicts: Any) -> Score:
    """Score an engine's verdicts (``reachable``, ``posture``) on a suite against its labels and the check."""
    said = np.asarray(verdicts.reachable, bool)
    bad = [int(i) for i in np.nonzero(said)[0] if independent_check(oracle, verdicts.posture[i], suite.goals[i])]
    fu = [int(i) for i in np.nonzero(suite.reachable & ~said)[0]]
    new = [int(i) for i in np.nonzero(~suite.reachable & said)[0] if i not in bad]
    return Score(suite.strategy, len(suite.goals), int(suite.reachable.sum()), fu, bad, new)
