"""The truth suite (tests/truth_suite.py): generate it, or score an engine against it; prints JSON lines.

Generate (``--generate``): for each strategy, ``--candidates`` goals drawn with a seed, a part uniform over the
config's box and the rest where answers are hard: a shell near the strategy's reach bound, behind the body, across
it, low. Each candidate is asked of a thorough referee, every search cold (no hint) and independent of the engine's
staging:

* ``single``: fatrop from the reference posture alone (tells the goals one start misses);
* ``batch``: the batched engine with ``--batch-starts`` starts a goal, never giving up;
* ``ipopt``: IPOPT (the audit's referee) from the reference, the ready posture and ``--restarts`` random starts;
* ``fatrop``: fatrop from as many random starts of another seed;
* ``analytic`` (the repository's UR5, ``EXACT``): ur-analytic-ik's exact solutions over ``AXES`` tool axes.

A goal is labelled reachable when a posture one of them found passes the independent check (tests/truth_suite.py); that
posture is kept. ``--keep`` goals are kept, the hard ones first: reachable goals one start misses, reachable goals
beside an unreachable candidate (within ``NEAR`` m) and unreachable ones within ``CLOSE`` m of a posture, then the
rest. The folder's provenance.json records all of it.

Score (default): the engine of each strategy as the config makes it, asked cold (``evaluate(goals)``) and as a
build asks (each goal hinted with the kept posture of its nearest proven neighbour), against the suite.

    python bench/truth.py --generate [--config configs/demo.yaml] [--strategies a,b] [--out tests/data/truth]
    python bench/truth.py [--strategies a,b] [--jit]
    python bench/truth.py --config CONFIG --strategies a,b --out FOLDER [--generate]   (a suite of any config)
    python bench/truth.py --population [--generate]   (members from the survey's tails x population.yaml's strategies
                                                       x the workstation's targets)
    python bench/truth.py --restamp COMMIT   (a body changed in massless frames no task uses: see restamp)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from truth_suite import (  # noqa: E402
    POPULATION,
    SUITE,
    Suite,
    independent_check,
    load_suite,
    member_config,
    provenance,
    score,
    suite_spec,
)

from oracles.bodies import ansur  # noqa: E402
from oracles.protocol import Goals, OracleSpec  # noqa: E402
from reach.answers.evaluate import load_targets  # noqa: E402
from reach.building.config import load_config  # noqa: E402

NEAR = 0.12  # [m] a reachable goal this near an unreachable candidate lies at the boundary
CLOSE = 0.05  # [m] an unreachable goal whose referee's best posture ends this near lies at the boundary
TARGETS = ["configs/targets/workstation_right.csv", "configs/targets/workstation_heights.csv"]
TAILS = (1, 99)  # [percentile] of stature, each sex
SUITES = {  # the strategies of the suite, by config
    "configs/demo.yaml": ["right_arm", "right_upper_body", "right_whole_body", "right_crouch"],
    "configs/human.yaml": ["right_torsion", "right_squat", "right_step"],
    "configs/examples/ur5_floor.yaml": ["ur5_free", "ur5_guarded"],
}
EXACT = {"configs/examples/ur5_floor.yaml"}  # configs whose goals ur-analytic-ik labels too (the repository's UR5)
AXES = 200  # tool axes over the sphere the analytic labels try a goal with


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def candidates(oracle, box: tuple[np.ndarray, np.ndarray], n: int, rng: np.random.Generator,
               right: bool) -> tuple[np.ndarray, np.ndarray]:
    """n goals [m] and the region each was drawn in."""
    lo, hi = box
    bound = oracle.reach_bound()
    if bound is not None:
        centre, radius = np.asarray(bound[0], float), float(bound[1])
    else:
        centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    side = -1.0 if right else 1.0  # the effector's own side (y < 0 for the right hand)
    out, kinds = [], []
    share = {"box": 0.2, "shell": 0.35, "behind": 0.15, "across": 0.15, "low": 0.15}
    for kind, s in share.items():
        k = int(round(n * s))
        pts: list[np.ndarray] = []
        for _ in range(200 * k):  # a region the bound does not meet (the arm's low goals) gets fewer
            if len(pts) == k:
                break
            if kind == "box":
                p = rng.uniform(lo, hi)
            else:
                d = rng.normal(size=3)
                d /= np.linalg.norm(d)
                r = radius * (rng.uniform(0.55, 1.0) if kind == "shell" else rng.uniform(0.2, 0.9) ** (1 / 3))
                p = centre + r * d
                if kind == "behind" and p[0] > centre[0] - 0.05:
                    continue
                if kind == "across" and side * p[1] > -0.05:
                    continue
                if kind == "low" and p[2] > max(0.6, centre[2] - 0.5 * radius):
                    continue
            if np.all(p >= lo) and np.all(p <= hi):
                pts.append(p)
        out += pts
        kinds += [kind] * len(pts)
    return np.array(out), np.array(kinds)


def referee(spec: OracleSpec, goals: np.ndarray, restarts: int, batch_starts: int, seed: int) -> dict:
    """Each search's verdicts (see the module docstring), cold."""
    base = {**spec.params, "jit": False, "secondary": False, "seed": seed}
    searches = {
        "single": {**base, "solver": "fatrop", "restarts": 0, "give_up": None},
        "batch": {**base, "solver": "batch", "starts": batch_starts, "give_up": None},
        "ipopt": {**base, "solver": "ipopt", "restarts": restarts, "give_up": None},
        "fatrop": {**base, "solver": "fatrop", "restarts": restarts, "give_up": None, "seed": seed + 1},
    }
    out = {}
    for name, params in searches.items():
        t = time.process_time()
        out[name] = OracleSpec(spec.name, params).create().evaluate(Goals(goals))
        emit(search=name, goals=len(goals), reached=int(out[name].reachable.sum()),
             cpu_s=round(time.process_time() - t, 1))
    return out


def _config_path(config: str) -> Path:
    """A config named on the command line (as given, else from the repository's root, as SUITES names them)."""
    return Path(config) if Path(config).exists() else ROOT / config


def analytic(oracle, goals: np.ndarray) -> np.ndarray:
    """The repository's UR5's postures (N, nq) at each goal by ur-analytic-ik's exact solutions over ``AXES`` tool
    axes, the first that passes the independent check; NaN rows where none does (a lower bound: axes between the
    sampled ones are not tried)."""
    import ur_analytic_ik
    from analytic_ur5 import JOINTS, TURN, directions, frame_about

    model = oracle.body.model
    cols = [model.idx_qs[model.getJointId(j)] for j in JOINTS]
    out = np.full((len(goals), len(oracle.body.q_ref)), np.nan)
    for i, goal in enumerate(goals):
        for axis in directions(AXES):
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = frame_about(TURN @ axis), TURN @ goal
            for solution in ur_analytic_ik.ur5.inverse_kinematics(pose):
                q = oracle.body.q_ref.copy()
                q[cols] = np.asarray(solution, float).ravel()
                if not independent_check(oracle, q, goal):
                    out[i] = q
                    break
            if np.isfinite(out[i, 0]):
                break
    return out


def label(oracle, spec: OracleSpec, goals: np.ndarray, args: argparse.Namespace,
          exact: bool = False) -> tuple[np.ndarray, ...]:
    """Each goal's label by the referee (see the module docstring), and with ``exact`` by the UR5's analytic IK too:
    reachable, the proving posture (NaN rows where none), the referee's best residual [m], which search proved it,
    and which goals fatrop from the reference alone reached."""
    found = referee(spec, goals, args.restarts, args.batch_starts, args.seed)
    n, nq = len(goals), len(oracle.body.q_ref)
    reachable, posture = np.zeros(n, bool), np.full((n, nq), np.nan)
    residual, by = np.full(n, np.inf), np.array([""] * n, dtype="U16")
    if exact:
        t = time.process_time()
        solved = analytic(oracle, goals)
        reachable = np.all(np.isfinite(solved), axis=1)
        posture[reachable], by[reachable], residual[reachable] = solved[reachable], "analytic", 0.0
        emit(search="analytic", goals=n, reached=int(reachable.sum()), cpu_s=round(time.process_time() - t, 1))
    for search in ("ipopt", "fatrop", "batch", "single"):  # the audit's referee's posture first
        v = found[search]
        residual = np.minimum(residual, v.residual)
        for i in np.nonzero(v.reachable & ~reachable)[0]:
            if not independent_check(oracle, v.posture[i], goals[i]):
                reachable[i], posture[i], by[i] = True, v.posture[i], search
    return reachable, posture, residual, by, found["single"].reachable


def generate(config: str, name: str, args: argparse.Namespace) -> dict:
    cfg = load_config(_config_path(config))
    spec = cfg.strategy(name).oracle
    oracle = spec.create()
    rng = np.random.default_rng([args.seed, *name.encode()])
    box = (np.asarray(cfg.box.lo, float), np.asarray(cfg.box.hi, float))
    goals, kinds = candidates(oracle, box, args.candidates, rng, name.startswith("right"))
    n = len(goals)
    reachable, posture, residual, by, single = label(oracle, spec, goals, args, config in EXACT)
    # The hard goals first (see the module docstring), then the rest, in a seeded order.
    dist = np.linalg.norm(goals[:, None] - goals[None, :], axis=2)
    beside = np.array([np.any(dist[i, ~reachable] <= NEAR) for i in range(n)])
    order = rng.permutation(n)
    tiers = [reachable & ~single, (reachable & beside) | (~reachable & (residual <= CLOSE)), np.ones(n, bool)]
    keep: list[int] = []
    for tier in tiers:
        keep += [int(i) for i in order[tier[order]] if i not in keep][: max(args.keep - len(keep), 0)]
    keep_a = np.array(sorted(keep))
    Suite(name, goals[keep_a], reachable[keep_a], posture[keep_a], residual[keep_a], kinds[keep_a],
          by[keep_a]).save(Path(args.out))
    named = config if (ROOT / config).exists() else str(Path(config).resolve())  # as suite_spec finds it again
    return {"config": named, "strategy": name, "candidates": n, "kept": len(keep_a),
            "reachable": int(reachable[keep_a].sum()), "one_start_misses": int((reachable & ~single)[keep_a].sum()),
            "body_hash": oracle.model_hash, "nq": posture.shape[1], "tolerance": oracle.strategy.tolerance,
            "regions": {k: int(np.sum(kinds[keep_a] == k)) for k in np.unique(kinds)},
            "found_by": {k: int(np.sum(by[keep_a] == k)) for k in np.unique(by[keep_a]) if k}}


def tail_members() -> list[tuple[str, int]]:
    """The population suite's members: of each sex, the subjects nearest the survey's 1st and 99th stature
    percentiles."""
    out = []
    for sex in ("female", "male"):
        sample = ansur.sample(sex)  # type: ignore[arg-type]
        stature = sample.column("stature")
        out += [(sex, int(sample.ids[np.argmin(np.abs(stature - np.percentile(stature, q)))])) for q in TAILS]
    return out


def population_targets() -> tuple[np.ndarray, np.ndarray]:
    targets = [t for path in TARGETS for t in load_targets(ROOT / path)]
    return np.array([t.point for t in targets], float), np.array([t.name for t in targets])


def generate_population(args: argparse.Namespace) -> list[dict]:
    """Every tail member x strategy of POPULATION x target of TARGETS, labelled as ``generate`` labels; one suite per
    member and strategy, named ``MEMBER.STRATEGY``."""
    goals, names = population_targets()
    out = []
    for sex, subject in tail_members():
        cfg = member_config(sex, subject)
        for strategy in cfg.strategies:
            spec = cfg.strategy(strategy.name).oracle
            oracle = spec.create()
            reachable, posture, residual, by, single = label(oracle, spec, goals, args)
            name = f"{cfg.name}.{strategy.name}"
            Suite(name, goals, reachable, posture, residual, names, by).save(Path(args.out))
            out.append({"config": POPULATION, "member": {"sex": sex, "subject": subject}, "strategy": name,
                        "targets": TARGETS, "kept": len(goals), "reachable": int(reachable.sum()),
                        "one_start_misses": int((reachable & ~single).sum()), "body_hash": oracle.model_hash,
                        "nq": posture.shape[1], "tolerance": oracle.strategy.tolerance,
                        "found_by": {k: int(np.sum(by == k)) for k in np.unique(by) if k}})
    return out


def scored(name: str, jit: bool, folder: Path = SUITE) -> list[dict]:
    spec = suite_spec(name, folder)
    oracle = OracleSpec(spec.name, {**spec.params, "jit": "auto" if jit else False}).create()
    suite = load_suite(name, folder)
    lines = []
    for mode in ("cold", "hinted"):
        goals = Goals(suite.goals) if mode == "cold" else Goals(suite.goals, seeds=suite.neighbour_hints())
        solves, t = oracle.stats["solves"], time.process_time()
        v = oracle.evaluate(goals)
        cpu = time.process_time() - t
        lines.append({**score(oracle, suite, v).line(), "mode": mode, "cpu_s": round(cpu, 2),
                      "solves": oracle.stats["solves"] - solves})
    return lines


FRAME = re.compile(r'<link name="([^"]+)"/>|<joint name="([^"]+)_fixed" type="fixed">.*?</joint>', re.S)
# Where the tasks, the engine and the selector look frames up by name: a frame named there is used by some strategy.
USERS = ("oracles/tasks", "oracles/ik", "reach/answers")
OLD_URDFS = """
import json, sys
sys.path.insert(0, "tests")
from truth_suite import provenance, suite_spec
print(json.dumps({n: suite_spec(n).create().body.urdf for n in provenance()["strategies"]}))
"""


def frames(urdf: str) -> tuple[str, dict[str, str]]:
    """A URDF without its massless fixed frames (its white space collapsed), and those frames' text by name."""
    found: dict[str, str] = {}
    for m in FRAME.finditer(urdf):
        name = m.group(1) or m.group(2)
        found[name] = found.get(name, "") + m.group(0)
    return " ".join(FRAME.sub("", urdf).split()), found


def restamp(commit: str, folder: Path) -> list[dict]:
    """Each suite's body hash made anew where the body changed since ``commit`` only in massless fixed frames that no
    task, engine or selector names (a landmark moved or added): its labels and proving postures stand, the proving
    postures being checked again by the tests. Any other change (a joint, a length, a mass, a capsule, a frame a task
    looks up) is refused: that suite must be generated again."""
    import tempfile

    used = " ".join(p.read_text() for d in USERS for p in (ROOT / d).rglob("*.py"))
    commit = subprocess.run(["git", "rev-parse", "--short", commit], cwd=ROOT, check=True, capture_output=True,
                            text=True).stdout.strip()
    prov = provenance(folder)
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "old"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(tree), commit], cwd=ROOT, check=True)
        try:
            old = json.loads(subprocess.run([sys.executable, "-c", OLD_URDFS], cwd=tree, check=True, text=True,
                                            capture_output=True, env={**os.environ, "PYTHONPATH": str(tree)}).stdout)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=True)
    out = []
    for name, entry in prov["strategies"].items():
        spec = suite_spec(name, folder)
        oracle = spec.create()
        if oracle.model_hash == entry["body_hash"]:
            continue
        rest_old, frames_old = frames(old[name])
        rest_new, frames_new = frames(oracle.body.urdf)
        changed = sorted(n for n in set(frames_old) | set(frames_new) if frames_old.get(n) != frames_new.get(n))
        strategy = json.dumps(spec.params, sort_keys=True)
        named = [n for n in changed if n in strategy or n.removeprefix("right_").removeprefix("left_") in used]
        if rest_old != rest_new or named:
            what = ", ".join(named) if named else "joints, links or capsules"
            raise SystemExit(f"{name}: the body changed beyond frames no task uses ({what}): "
                             f"python bench/truth.py --generate --strategies {name}")
        entry["restamped"] = {"from": entry["body_hash"], "commit": commit, "frames": changed}
        entry["body_hash"] = oracle.model_hash
        out.append({"strategy": name, "restamped": entry["restamped"]})
    (folder / "provenance.json").write_text(json.dumps(prov, indent=1) + "\n")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generate", action="store_true")
    parser.add_argument("--config", help="a suite of this config's --strategies (default: the repository's, SUITES)")
    parser.add_argument("--population", action="store_true", help="the population suite: members from the survey's "
                        "tails x POPULATION's strategies x TARGETS")
    parser.add_argument("--strategies", help="comma-separated (default: every strategy of SUITES)")
    parser.add_argument("--candidates", type=int, default=800)  # as the suite was made
    parser.add_argument("--keep", type=int, default=300)
    parser.add_argument("--restarts", type=int, default=24)
    parser.add_argument("--batch-starts", type=int, default=64)
    parser.add_argument("--seed", type=int, default=59)
    parser.add_argument("--out", default=str(SUITE))
    parser.add_argument("--jit", action="store_true", help="score with compiled programs (as the configs ask)")
    parser.add_argument("--restamp", metavar="COMMIT", help="make each stale suite's body hash anew where its body "
                        "changed since COMMIT only in massless frames that no task uses (else: an error)")
    args = parser.parse_args()
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         cores=os.cpu_count(), load=os.getloadavg()[0])
    if args.restamp:
        for line in restamp(args.restamp, Path(args.out)):
            emit(**line)
        return
    wanted = None if not args.strategies else set(args.strategies.split(","))
    if args.config and not wanted:
        parser.error("--config needs --strategies")
    suites = {args.config: sorted(wanted or ())} if args.config else SUITES
    jobs = [(c, s) for c, names in suites.items() for s in names if wanted is None or s in wanted]
    if args.generate:
        out = Path(args.out)
        path = out / "provenance.json"
        prov = json.loads(path.read_text()) if path.exists() else {"strategies": {}}
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip()
        referee_settings = {"searches": ["single", "batch", "ipopt", "fatrop"], "restarts": args.restarts,
                            "batch_starts": args.batch_starts, "jit": False, "secondary": False}
        out.mkdir(parents=True, exist_ok=True)

        def keep(entry: dict) -> None:  # each strategy's entry as it is made: a long run stopped keeps the others
            prov["strategies"][entry["strategy"]] = entry
            emit(**entry)
            path.write_text(json.dumps(prov, indent=1) + "\n")

        t = time.time()
        made = generate_population(args) if args.population else []
        for entry in made:
            entry.update(commit=commit, seed=args.seed, referee=referee_settings,
                         wall_s=round((time.time() - t) / len(made), 1))
            keep(entry)
        for config, name in [] if args.population else jobs:
            t = time.time()
            entry = generate(config, name, args)
            entry.update(commit=commit, seed=args.seed, wall_s=round(time.time() - t, 1),
                         referee={**referee_settings, "candidates": args.candidates, "keep": args.keep, "near": NEAR,
                                  "close": CLOSE})
            keep(entry)
        return
    if args.population:
        jobs = [(POPULATION, n) for n, e in provenance(Path(args.out))["strategies"].items() if "member" in e
                and (wanted is None or n in wanted)]
    for _, name in jobs:
        if name in provenance(Path(args.out))["strategies"]:
            for line in scored(name, args.jit, Path(args.out)):
                emit(**line)


if __name__ == "__main__":
    main()
