"""Accommodation: the share of a population that reaches each target, with its 95 % interval.

Two ways to the same table:

* **from a built population** (``reach build`` of a config with ``population:``, then ``reach evaluate FOLDER``):
  each member's atlas answers as ``reach evaluate`` answers one atlas (the trees, each answer refined at the target);
* **direct** (``reach evaluate CONFIG --direct``): each member's strategies' oracles solve the targets, no tree. For
  a few targets and many members this is cheaper than building an atlas a member; for many targets, or targets asked
  again and again (a layout being moved, a server), the atlases pay.

A member reaches a target when a strategy does, tried by priority; per strategy, the share of members whose strategy
reaches it (a strategy the selector did not choose counts when it reaches too). Members may carry weights (the whole
survey weighted to a mix of the sexes): a share is the weighted mean, and its interval is Wilson's score interval
(Wilson, E. B. (1927), *Probable inference, the law of succession, and statistical inference*, JASA 22:209-212)
at Kish's effective sample size (sum w)^2 / sum w^2 (Kish, L. (1965), *Survey Sampling*): with equal weights, the
plain Wilson interval of k in n. The interval is the sampling error of the population's members standing for the
people they were drawn from; a boundary family is not a sample, and its interval is printed but means little.
"""

from __future__ import annotations

import math
from collections.abc import Generator, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from reach.answers.evaluate import Target, evaluate, on_body, to_body
from reach.errors import ConfigError
from reach.maps.atlas import Atlas

Z95 = 1.959963984540054  # the standard normal's 97.5th percentile: a two-sided 95 % interval


def wilson(share: float, n: float, z: float = Z95) -> tuple[float, float]:
    """Wilson's score interval of a proportion ``share`` observed on ``n`` (possibly effective, not whole) trials."""
    if n <= 0:
        return 0.0, 1.0
    centre = (share + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(share * (1 - share) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def weighted_share(weights: np.ndarray, hits: np.ndarray) -> dict[str, float]:
    """The weighted share of ``hits`` (bool) with its Wilson interval at Kish's effective n."""
    w = np.asarray(weights, float)
    total = float(w.sum())
    share = float(w[np.asarray(hits, bool)].sum() / total) if total > 0 else 0.0
    n_eff = total * total / float((w * w).sum()) if total > 0 else 0.0
    lo, hi = wilson(share, n_eff)
    return {"share": round(share, 4), "low": round(lo, 4), "high": round(hi, 4)}


def table(members: Sequence[dict[str, Any]], targets: list[str], strategies: list[str]) -> dict[str, Any]:
    """Per target: the share reached (any strategy) and per strategy, from each member's rows.

    ``members``: ``{"name", "weight", "rows"}``, a row per target with ``reachable``, ``strategy`` and ``also`` (the
    other strategies that reach it), as :func:`reach.answers.evaluate.evaluate` gives them.
    """
    weights = np.array([m["weight"] for m in members], float)
    out = [_target_row(members, weights, t, name, strategies) for t, name in enumerate(targets)]
    verdicts = [{"name": m["name"], "weight": m["weight"], "reached": [bool(r["reachable"]) for r in m["rows"]],
                 "strategy": [r["strategy"] for r in m["rows"]], "also": [list(r["also"]) for r in m["rows"]]}
                for m in members]
    return {"targets": out, "members": len(members), "strategies": strategies, "by_member": verdicts,
            "effective_n": round(float(weights.sum() ** 2 / (weights * weights).sum()), 1) if len(members) else 0}


def _target_row(members: Sequence[dict[str, Any]], weights: np.ndarray, t: int, name: str,
                strategies: list[str]) -> dict[str, Any]:
    """Target t's shares: reached by any strategy, by each, and chosen by each."""
    rows = [m["rows"][t] for m in members]
    reached = np.array([r["reachable"] for r in rows], bool)
    per = {s: weighted_share(weights, np.array([r["reachable"] and (r["strategy"] == s or s in r["also"])
                                                for r in rows], bool)) for s in strategies}
    chosen = {s: weighted_share(weights, np.array([r["reachable"] and r["strategy"] == s for r in rows], bool))
              ["share"] for s in strategies}
    return {"target": name, **weighted_share(weights, reached), "members": len(rows),
            "unreached": [m["name"] for m, ok in zip(members, reached, strict=True) if not ok][:20],
            "by_strategy": per, "chosen": chosen}


def load_members(folder: str | Path) -> tuple[list[Atlas], np.ndarray, list[str]]:
    """A built population's member atlases, their weights (summing to 1) and names; an unbuilt member is an error."""
    from reach.maps.atlas import load_atlas

    paths, weights, names = member_atlases(folder)
    return [load_atlas(path) for path in paths], weights, names


def member_atlases(folder: str | Path) -> tuple[list[Path], np.ndarray, list[str]]:
    """A built population's member atlas folders (not loaded), their weights (summing to 1) and names; an unbuilt
    member is an error."""
    from reach.building.population import read_manifest

    doc = read_manifest(folder)
    paths = []
    for m in doc["members"]:
        path = Path(folder) / m["atlas"]
        if not (path / "manifest.json").is_file():
            raise ConfigError(str(Path(folder) / "population.json"), "", f"member {m['name']}: its atlas {path} is not "
                                                                    "built yet: run reach build --resume on the "
                                                                    "population's config")
        paths.append(path)
    w = np.array([m["weight"] for m in doc["members"]], float)
    if not len(w) or w.sum() <= 0:
        raise ConfigError(str(Path(folder) / "population.json"), "members", "no member with a weight above 0")
    return paths, w / w.sum(), [str(m["name"]) for m in doc["members"]]


ANY = "any"  # the share of members that some strategy of theirs holds
# at most this many members a process answers with one program a strategy (direct; building one costs about 1.3 s:
# the whole survey in runs of 24 built 253 of them, in runs of 96, 64)
CHUNK = 192
# members whose solves run joined (oracles.ik.joined), in groups fixed by their order (a run holds whole groups), so
# that the answers depend on neither the processes nor the cluster: 40 members x 7 targets, one process, 15.0-16.9 s
# alone, 11.9-12.9 s joined 8 at a time; 192 members, 52.9 and 59.8 s 8 at a time, 49.8 and 51.9 s 16 (measured
# here, one after the other, the same answers; more than 16 gained nothing beyond this machine's noise)
JOIN = 16
# at most this many oracles a strategy lend their programs in a run: a body no program serves is rare (none of the
# survey's once its numbers 0 or 1 by chance are lifted), and a run of such bodies keeps no more than these alive
LENDERS = 4
# the engines' option that makes one program serve every member (oracles.ik.parameters); answers do not depend on it
SHARED = {"casadi-ik": {"body_parameters": True}}


def shares(atlases: Sequence[Atlas], weights: np.ndarray, points: np.ndarray,
           effector: str | None = None) -> dict[str, np.ndarray]:
    """By the trees' word (``vertex`` policy), per point (N, 3): per strategy name the weighted share of members whose
    tree of that name holds it, and under :data:`ANY` the share one of whose strategies does (only the ``effector``'s
    strategies when given). ``weights`` sum to 1."""
    return run_steps(sharing(atlases, weights, points, effector))


def sharing(atlases: Sequence[Atlas], weights: np.ndarray, points: np.ndarray, effector: str | None = None,
            shift: np.ndarray | None = None) -> Generator[None, None, dict[str, np.ndarray]]:
    """:func:`shares` a member at a time: yields after each member (a server answers between them), returns them.
    ``shift`` (M, 3) [m]: each member's points moved by its own row (targets given on each person's body)."""
    out: dict[str, np.ndarray] = {}
    some = np.zeros(len(points))
    for k, (atlas, w) in enumerate(zip(atlases, weights, strict=True)):
        mine = points if shift is None else points + shift[k]
        held_here = np.zeros(len(points), bool)
        for name, tree in atlas.trees.items():
            if effector is not None and tree.meta.get("effector") != effector:
                continue
            inside = tree.contains(mine, "vertex")
            out[name] = out.get(name, np.zeros(len(points))) + w * inside
            held_here |= inside
        some += w * held_here
        yield
    return {ANY: some, **out}


T = TypeVar("T")


def run_steps(steps: Generator[None, None, T]) -> T:
    """A stepwise computation's result, its steps taken at once."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value  # type: ignore[no-any-return]


def held(atlases: Sequence[Atlas], weights: np.ndarray, effector: str, goals: np.ndarray,
         relative_to: str | None = None) -> Generator[None, None, dict[str, Any]]:
    """Per goal, the share of members one of whose ``effector`` strategies holds it (:func:`sharing`, a member a
    step), with its Wilson interval at Kish's effective n, and per strategy name its share. ``relative_to``: the goals
    are offsets (world axes) from that frame of each member's body in its reference posture, as its build recorded it
    (:meth:`Atlas.landmark`)."""
    shift = None if relative_to is None else np.array([a.landmark(relative_to) for a in atlases], float)
    found = yield from sharing(atlases, weights, goals, effector, shift)
    w = np.asarray(weights, float)
    n_eff = float(w.sum() ** 2 / (w * w).sum())
    bounds = [wilson(float(p), n_eff) for p in found[ANY]]
    return {"share": np.round(found[ANY], 4).tolist(), "low": [round(lo, 4) for lo, _ in bounds],
            "high": [round(hi, 4) for _, hi in bounds],
            "by_strategy": {k: np.round(v, 4).tolist() for k, v in found.items() if k != ANY}}


def from_atlases(folder: str | Path, targets: list[Target], effector: str | None = None, refine: bool = True,
                 budget: float = 1.0, placement: np.ndarray | None = None) -> dict[str, Any]:
    """Accommodation from a built population's atlases (one :func:`evaluate` per member)."""
    from reach.building.population import read_manifest

    atlases, weights, names = load_members(folder)
    members = []
    strategies: list[str] = []
    for atlas, weight, name in zip(atlases, weights, names, strict=True):
        result = evaluate([atlas], targets, effector, refine=refine, budget=budget, placements=placement)
        members.append({"name": name, "weight": float(weight), "rows": result["atlases"][0]["rows"]})
        strategies += [s for s in atlas.trees if s not in strategies]
    used = [s for s in strategies if any(s == r["strategy"] or s in r["also"] for m in members for r in m["rows"])]
    return {"population": read_manifest(folder).get("name"), "way": "atlases",
            **table(members, [t.name for t in targets], used)}


def direct(config: Any, targets: list[Target], effector: str | None = None,
           placement: np.ndarray | None = None, verify: bool = True,
           log: Any = None, workers: int = 1, client: Any = None, members: list[Any] | None = None) -> dict[str, Any]:
    """Accommodation by solving every member x target with the members' strategies' oracles (no tree).

    Every reached target is checked by the strategy's own forward-kinematics check of the posture on that member's
    model (``Verifying``); one that fails it counts as not reached, and the count is reported. ``workers`` > 1 solves
    members in that many processes (each dies with this one); a Dask ``client`` (``distributed.Client``) solves them
    on its cluster's workers instead. The answers depend on neither. ``members``
    (:class:`oracles.bodies.population.Member`): these instead of the config's population.
    """
    from reach.building.population import members_of

    points = np.array([t.point for t in targets], float).reshape(-1, 3)
    if placement is not None:
        points = to_body(points, np.asarray(placement, float).reshape(1, 4))[0]
    effs = _effectors(targets, effector, sorted({s.effector for s in config.strategies}))
    strategies = [(s.name, s.effector, s.oracle.name, s.oracle.params) for s in config.strategies
                  if s.effector in set(effs)]
    members = members_of(config) if members is None else members
    # Members in runs of CHUNK, each run in one process with one program a strategy (the body's numbers its
    # parameters: oracles.ik.parameters), built for the run's first member and shared by the others (see _members).
    if client is not None:
        workers = max(workers, len(client.scheduler_info().get("workers", {})))
    runs = _runs(members, workers)
    jobs = [([m.body(config.raw.get("body")) for m in run], strategies, points, effs, verify, targets) for run in runs]
    results = _logged(_solved(jobs, workers, client), members, log)
    table_members = [{"name": m.name, "weight": m.weight, "rows": rows} for m, (rows, _) in zip(members, results,
                                                                                                 strict=True)]
    return {"population": config.name, "way": "direct", "refuted_by_check": sum(r for _, r in results),
            **table(table_members, [t.name for t in targets], [name for name, *_ in strategies])}


def _runs(members: list[Any], workers: int) -> list[list[Any]]:
    """The members in runs of whole groups of ``JOIN`` (by their order), at most ``CHUNK`` a run, as many as a
    multiple of the processes, their sizes as even as whole groups allow (500 members on 2 processes: 4 runs of
    112-128 members, not 5 of 96 and one of 20, which left a process idle)."""
    groups = [members[k : k + JOIN] for k in range(0, len(members), JOIN)]
    workers = max(workers, 1)
    count = min(workers * math.ceil(len(members) / (CHUNK * workers)), len(groups))  # every process at work
    cut = np.linspace(0, len(groups), max(count, 1) + 1).round().astype(int)
    return [[m for g in groups[a:b] for m in g] for a, b in zip(cut[:-1], cut[1:], strict=True) if b > a]


def _effectors(targets: list[Target], effector: str | None, known: list[str]) -> list[str]:
    """Each target's effector: its own, else ``effector``, else the config's only one (ConfigError when none)."""
    effs = [t.effector or effector for t in targets]
    for t, e in zip(targets, effs, strict=True):
        if e is None and len(known) != 1:
            raise ConfigError("targets", t.name, f"no effector: give an effector column or --effector (one of "
                                                 f"{', '.join(known)})")
    return [e or known[0] for e in effs]


def _solved(jobs: list[Any], workers: int, client: Any) -> Iterator[tuple[list[dict[str, Any]], int]]:
    """Each member's answers and refuted count, in order: runs of members solved on a Dask cluster, in processes,
    or here."""
    if client is not None:
        futures = client.map(_members, jobs, pure=False)
        yield from (r for f in futures for r in f.result())
    elif workers > 1 and len(jobs) > 1:
        from concurrent.futures import ProcessPoolExecutor

        from reach.building.executor import build_worker

        with ProcessPoolExecutor(max_workers=workers, initializer=build_worker) as pool:
            yield from (r for run in pool.map(_members, jobs) for r in run)
    else:
        yield from (r for job in jobs for r in _members(job))


def _logged(results: Any, members: list[Any], log: Any) -> list[tuple[list[dict[str, Any]], int]]:
    out = []
    for k, (entry, result) in enumerate(zip(members, results, strict=True), start=1):
        out.append(result)
        if log is not None:
            log(f"member {k}/{len(members)}: {entry.name}, {sum(r['reachable'] for r in result[0])} of "
                f"{len(result[0])} targets reached")
    return out


def _members(job: tuple[Any, ...]) -> list[tuple[list[dict[str, Any]], int]]:
    """Each member's rows of a run of members (a row per target: reached, the strategy chosen by priority, the others
    that reach it) and the count of reached answers its forward-kinematics check refuted. A strategy's oracle of the
    run's first member lends its programs to the others' (``share_programs``): they are built once a run. A member
    they cannot serve (a body of another shape) lends its own to the members after it."""
    from oracles.protocol import OracleSpec, Sharing, create_siblings

    bodies, strategies, points, effs, verify, targets = job
    lenders: dict[str, list[Any]] = {}  # by strategy, the oracles whose programs the run's others take
    out = []  # a list, not a generator: a worker process sends it back whole
    for k in range(0, len(bodies), JOIN):
        group, mine = [], []
        for body in bodies[k : k + JOIN]:
            oracles = {}
            # the member's strategies on one loaded body (Sibling)
            made = create_siblings([OracleSpec(oracle_name, {**params, **SHARED.get(oracle_name, {}), "body": body})
                                    for _, _, oracle_name, params in strategies])
            for (name, *_), oracle in zip(strategies, made, strict=True):
                # the first lender whose programs serve this body, else this one lends its own to the next
                lending = lenders.setdefault(name, [])
                if isinstance(oracle, Sharing) and not any(oracle.share_programs(o) for o in lending) \
                        and len(lending) < LENDERS:
                    lending.append(oracle)
                oracles[name] = oracle
            group.append(oracles)
            # a target on the body where it lies on this member's body (every strategy's oracle holds the same body)
            mine.append(on_body(targets, next(iter(oracles.values()), None), points))
        out += _group(group, strategies, mine, effs, verify)
    return out


def _member(oracles: dict[str, Any], strategies: list[tuple[Any, ...]], points: np.ndarray, effs: list[str],
            verify: bool) -> tuple[list[dict[str, Any]], int]:
    """One member's rows and refuted count (see :func:`_members`), by its strategies' oracles."""
    return _group([oracles], strategies, [points], effs, verify)[0]


def _group(oracles: list[dict[str, Any]], strategies: list[tuple[Any, ...]], points: list[np.ndarray],
           effs: list[str], verify: bool) -> list[tuple[list[dict[str, Any]], int]]:
    """Each member's rows and refuted count (see :func:`_members`), by its strategies' oracles (``oracles``, a
    member's by strategy name, ``points`` where the targets lie on each), the members' solves joined."""
    rows: list[list[dict[str, Any]]] = [[{"reachable": False, "strategy": None, "also": []} for _ in p] for p in points]
    refuted = [0] * len(oracles)
    # Each target's posture from the first strategy that reached it (a full posture of this member's body): the next
    # strategies start from it. A strategy with more freedom holds every posture of one with less (its other joints at
    # the reference), but its own cold search may not find one: the whole body and the crouch reached the
    # workstation's chest button for 95 and 97.5 % of configs/population.yaml's members, the arm alone for 100 %.
    found: list[dict[int, np.ndarray]] = [{} for _ in oracles]  # target index -> the first reaching posture
    for name, eff, _, _ in strategies:
        pick = [i for i, e in enumerate(effs) if e == eff]
        mine = [m[name] for m in oracles]
        # A target an earlier strategy reached is this one's too when that posture passes this strategy's own check:
        # no solve (the whole body and the crouch then solve only what the arm and upper body missed).
        held = [_held(o, p, pick, f) for o, p, f in zip(mine, points, found, strict=True)]
        rest = [[i for i in pick if i not in h] for h in held]
        solved = _reached(mine, [p[r] for p, r in zip(points, rest, strict=True)],
                          [[f.get(i) for i in r] for f, r in zip(found, rest, strict=True)], verify)
        for m, (ok, postures, wrong) in enumerate(solved):
            refuted[m] += wrong
            reached = [*held[m].items(), *((i, q) for i, hit, q in zip(rest[m], ok, postures, strict=True) if hit)]
            for i, q in sorted(reached, key=lambda iq: iq[0]):
                if q is not None:
                    found[m].setdefault(i, q)
                row = rows[m][i]
                if row["reachable"]:
                    row["also"].append(name)
                else:
                    row["reachable"], row["strategy"] = True, name
    return list(zip(rows, refuted, strict=True))


def _reached(oracles: list[Any], points: list[np.ndarray], found: list[list[np.ndarray | None]],
             verify: bool) -> list[tuple[np.ndarray, Sequence[np.ndarray | None], int]]:
    """For each oracle, which of its points it reaches (:func:`_solved_from`; with ``verify``, by postures that pass
    its own check), their postures, and how many reached ones that check refuted."""
    solved = _solved_from(oracles, points, found)
    out: list[tuple[np.ndarray, Sequence[np.ndarray | None], int]] = []
    for oracle, p, v in zip(oracles, points, solved, strict=True):
        if v is None:
            out.append((np.zeros(0, bool), [], 0))
            continue
        ok, wrong = _checked(oracle, p, v) if verify else (np.asarray(v.reachable, bool), 0)
        out.append((ok, list(np.asarray(v.posture, float)) if v.posture is not None else [None] * len(p), wrong))
    return out


def _held(oracle: Any, points: np.ndarray, pick: list[int], found: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """Of the targets ``pick``, those whose posture ``found`` by an earlier strategy passes this oracle's own
    forward-kinematics check (:class:`Verifying`), with that posture."""
    from oracles.protocol import Verifying

    mine = [i for i in pick if i in found]
    if not mine or not isinstance(oracle, Verifying):
        return {}
    ok = oracle.verify(points[mine], np.array([found[i] for i in mine]))
    return {i: found[i] for i, hit in zip(mine, ok, strict=True) if hit}


def _checked(oracle: Any, points: np.ndarray, v: Any) -> tuple[np.ndarray, int]:
    """Which verdicts say reached and pass the oracle's own forward-kinematics check (:class:`Verifying`), and how
    many reached ones failed it."""
    from oracles.protocol import Verifying

    ok = np.asarray(v.reachable, bool)
    if not (ok.any() and isinstance(oracle, Verifying) and v.posture is not None):
        return ok, 0
    checked = oracle.verify(points[ok], np.asarray(v.posture)[ok])
    ok[np.flatnonzero(ok)[~checked]] = False
    return ok, int(np.sum(~checked))


def _solved_from(oracles: list[Any], points: list[np.ndarray], found: list[list[np.ndarray | None]]) -> list[Any]:
    """Each oracle's verdicts on its points (None where it has none), asked cold, then again from the posture
    ``found`` for a point (by an earlier strategy) where the cold search missed it; the oracles' calls run joined
    (:func:`oracles.protocol.evaluate_together`)."""
    from oracles.protocol import Goals, evaluate_together

    asked = [m for m, p in enumerate(points) if len(p)]
    out: list[Any] = [None] * len(oracles)
    for m, v in zip(asked, evaluate_together([oracles[m] for m in asked], [Goals.of(points[m]) for m in asked]),
                    strict=True):
        out[m] = v
    again = {m: ks for m in asked if out[m].posture is not None
             and (ks := [k for k, q in enumerate(found[m]) if not out[m].reachable[k] and q is not None])}
    retried = evaluate_together([oracles[m] for m in again],
                                [Goals(points[m][ks], seeds=np.array([found[m][k] for k in ks]))
                                 for m, ks in again.items()])
    for (m, ks), w in zip(again.items(), retried, strict=True):
        v = out[m]
        reachable, residual = np.array(v.reachable, bool), np.array(v.residual, float)
        posture = np.array(v.posture, float)
        reachable[ks], residual[ks], posture[ks] = w.reachable, w.residual, w.posture
        out[m] = v._replace(reachable=reachable, residual=residual, posture=posture)
    return out


def text(result: dict[str, Any]) -> str:
    """The accommodation table: one row per target, the share reached and per strategy, in percent."""
    strategies = result["strategies"]
    head = ["target", "reached % [95 % CI]", *strategies]
    lines = [head]
    for row in result["targets"]:
        lines.append([row["target"], f"{100 * row['share']:.1f} [{100 * row['low']:.1f}, {100 * row['high']:.1f}]",
                      *(f"{100 * row['by_strategy'][s]['share']:.1f}" for s in strategies)])
    widths = [max(len(r[i]) for r in lines) for i in range(len(head))]
    out = [("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True))).rstrip() for r in lines]
    out.append(f"{result['members']} members (effective n {result['effective_n']}), {result['way']}; a strategy's "
               "column: the share it reaches, chosen or not")
    return "\n".join(out)
