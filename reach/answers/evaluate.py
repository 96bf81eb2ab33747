"""Evaluating a layout: which strategy reaches each target, for one body or a population.

Targets come from a CSV file with a header and the columns ``name, x, y, z``
[m, atlas world frame] and optionally ``effector`` (else the one given on the
command line) and ``relative_to``: a frame of the body (``right_acromion``,
``eyes``, ``right_elbow_rest``, ``right_heel``, ...) that the target is given
from, in the world's axes, placed on each body where that body's frame lies in
its reference posture (a population's members each get their own target).
For each atlas and target the priority mechanism gives the chosen strategy
(or none) and the other strategies that reach it. Given several atlases (say
a 5th-percentile woman, a 50th- and a 95th-percentile man), the population
table shows, per target, the strategy each body uses: the ergonomics question
the paper opens with (front-panel controls in a car).

A target counts as reachable only when a posture reaches it: each answer is
refined by IK at the target (within ``budget`` per target), and a target the
trees hold but no refinement reaches counts as unreachable (the selector's
``miss="unreachable"``). With ``refine=False`` the trees' word is taken, and
each row says how near the stored posture comes (``within``).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from oracles.protocol import Landmarked
from reach.answers.select import Selector
from reach.errors import ConfigError, ReachError
from reach.maps.atlas import Atlas


@dataclass(frozen=True)
class Target:
    """A target [m]: a point in the layout's frame, or with ``relative_to`` an offset (world axes) from that frame of
    each body in its reference posture; reached by ``effector`` (a frame of the body), or the one asked."""

    name: str
    point: tuple[float, float, float]
    effector: str | None = None
    relative_to: str | None = None


def on_body(targets: list[Target], oracle: Any, points: np.ndarray) -> np.ndarray:
    """``points`` (T, 3) with each target given on the body placed on this oracle's body: its landmark's position
    plus its offset; the others as given."""
    if not any(t.relative_to for t in targets):
        return points
    if not isinstance(oracle, Landmarked):
        raise ConfigError("targets", "relative_to", "a target on the body needs a body model (a URDF or the "
                                                    "generated human), not an analytic shape")
    found: dict[str, np.ndarray] = {}
    out = np.array(points, float, copy=True)
    for i, t in enumerate(targets):
        if not t.relative_to:
            continue
        if t.relative_to not in found:
            try:
                found[t.relative_to] = oracle.landmarks([t.relative_to])[t.relative_to]
            except ReachError as exc:
                raise ConfigError("targets", f"{t.name}.relative_to", str(exc)) from None
        out[i] = found[t.relative_to] + np.asarray(t.point, float)
    return out


def load_targets(path: str | Path) -> list[Target]:
    """Read targets; errors name the file, the row and the column."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(path, "", f"cannot read: {exc.strerror or exc}") from exc
    rows = list(csv.DictReader(text.splitlines()))
    need = {"name", "x", "y", "z"}
    if not rows or not need <= set(rows[0]):
        raise ConfigError(path, "header", "expected the columns name, x, y, z (and optionally effector, "
                                          f"relative_to), got {sorted(rows[0]) if rows else 'nothing'}")
    out = []
    for i, row in enumerate(rows, start=2):
        try:
            point = (float(row["x"]), float(row["y"]), float(row["z"]))
        except (TypeError, ValueError):
            raise ConfigError(path, f"row {i}", f"x, y and z must be numbers in metres, got {row.get('x')!r}, "
                                                f"{row.get('y')!r}, {row.get('z')!r}") from None
        if not all(np.isfinite(point)):
            raise ConfigError(path, f"row {i}", "x, y and z must be finite")
        out.append(Target(row["name"], point, (row.get("effector") or "").strip() or None,
                          (row.get("relative_to") or "").strip() or None))
    return out


PLACE_KEYS = ("x", "y", "z", "yaw")


def to_body(targets: np.ndarray, placements: np.ndarray) -> np.ndarray:
    """Targets (T, 3) in the layout's frame seen from each placement (C, 4): (C, T, 3) in the body's frame."""
    d = targets[None, :, :] - placements[:, None, :3]
    c, s = np.cos(placements[:, 3])[:, None], np.sin(placements[:, 3])[:, None]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)


EVALUATE_BUDGET = 1.0  # [s] refinement budget per target: an offline question, no frame to keep


def evaluate(atlases: list[Atlas], targets: list[Target], effector: str | None = None, policy: str = "vertex",
             refine: bool = True,
             budget: float = EVALUATE_BUDGET, placements: np.ndarray | None = None) -> dict[str, Any]:
    """Per atlas and target: the chosen strategy, the alternatives, whether a posture reaches it; and a summary.

    ``placements`` (one row, or one per atlas: x, y, z [m], yaw [rad]) puts each body's frame in the layout's
    frame: the targets are given in the layout's frame and moved into the body's (``reach evaluate --at``).
    """
    results: dict[str, Any] = {"atlases": [], "targets": [t.name for t in targets], "refined": refine}
    relative = any(t.relative_to for t in targets)
    points = np.array([t.point for t in targets], float).reshape(-1, 3)
    if placements is not None:
        placements = np.asarray(placements, float).reshape(-1, 4)
        if len(placements) not in (1, len(atlases)):
            raise ConfigError("--at", "", f"expected one placement or one per atlas ({len(atlases)}), got "
                                          f"{len(placements)}")
    for k, atlas in enumerate(atlases):
        selector = Selector(atlas, policy, refine=refine, budget=budget, miss="unreachable")  # type: ignore[arg-type]
        seen = points if placements is None else to_body(points, placements[min(k, len(placements) - 1)][None])[0]
        # a target on the body is placed on this atlas's body (any strategy's oracle: they share it), not moved by --at
        seen = on_body(targets, selector.oracle(selector.order[0][0]) if relative else None, seen)
        rows = [_row(selector, t, point, effector, refine) for t, point in zip(targets, seen, strict=True)]
        reached = sum(r["reachable"] for r in rows)
        by_strategy: dict[str, int] = {}
        for r in rows:
            key = r["strategy"] or "none"
            by_strategy[key] = by_strategy.get(key, 0) + 1
        at = (None if placements is None
              else dict(zip(PLACE_KEYS, placements[min(k, len(placements) - 1)].tolist(), strict=True)))
        results["atlases"].append({"atlas": str(atlas.path), "name": atlas.manifest.get("name"), "rows": rows, "at": at,
                                   "summary": {"targets": len(rows), "reachable": reached,
                                               "unreachable": len(rows) - reached, "by_strategy": by_strategy}})
    return results


def _row(selector: Selector, t: Target, point: np.ndarray, effector: str | None, refine: bool) -> dict[str, Any]:
    """One target's row: the chosen strategy, the alternatives, whether a posture reaches it (beyond the trees: a
    thorough IK solve per strategy, by priority, when no tree holds it)."""
    eff = t.effector or effector or (selector.effectors[0] if len(selector.effectors) == 1 else None)
    if eff is None:
        raise ConfigError("targets", t.name, "no effector: give an effector column or --effector (one of "
                                             f"{', '.join(selector.effectors)})")
    a = selector.select(eff, point)
    probed = False
    if refine and not a.reachable and a.refined == "none":
        found = selector.probe(eff, point)
        if found is not None:
            a, probed = found, True
    # the layout's point; a target on the body, where it lies on this body
    shown = np.round(point, 6).tolist() if t.relative_to else list(t.point)
    return {"target": t.name, "effector": eff, "point": shown,
            **({"relative_to": t.relative_to} if t.relative_to else {}), "strategy": a.strategy,
            "reachable": a.reachable, "also": list(a.alternatives), "refined": a.refined, "within": a.within,
            "beyond_trees": probed,
            "nearest": None if a.nearest is None else {k: a.nearest[k] for k in ("strategy", "point", "distance")}}


def text_table(results: dict[str, Any]) -> str:
    """The population table: one row per target, one column per atlas."""
    names = [a["name"] or Path(a["atlas"]).name for a in results["atlases"]]
    width = max([len("target"), *map(len, results["targets"])])
    cols = [max(len(n), *(len(_cell(r)) for r in a["rows"])) for n, a in zip(names, results["atlases"], strict=True)]
    lines = ["  ".join(["target".ljust(width), *(n.ljust(c) for n, c in zip(names, cols, strict=True))])]
    for i, t in enumerate(results["targets"]):
        cells = [_cell(a["rows"][i]).ljust(c) for a, c in zip(results["atlases"], cols, strict=True)]
        lines.append("  ".join([t.ljust(width), *cells]))
    lines.append("  ".join(["reachable".ljust(width),
                            *(f"{a['summary']['reachable']}/{a['summary']['targets']}".ljust(c)
                              for a, c in zip(results["atlases"], cols, strict=True))]))
    if any(r.get("beyond_trees") for a in results["atlases"] for r in a["rows"]):
        lines.append("* no tree holds the target; a thorough IK solve (8 random restarts and the nearest stored "
                     "posture) reaches it")
    return "\n".join(lines)


def _cell(row: dict[str, Any]) -> str:
    return (row["strategy"] or "none") + ("*" if row.get("beyond_trees") else "")
