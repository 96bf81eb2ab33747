"""The two IK engines in one run: the batched engine (``solver: batch``) against fatrop; prints JSON lines.

* **oracle calls**: per strategy of a config, seeded random goals in the
  strategy's box, cold (no hint) and warm (the hint a build gives: the
  posture found for a goal 2 cm away), solved in build-sized calls; CPU
  seconds per goal and their ratio to one forward kinematics and frame
  Jacobian (Pinocchio, from Python, measured here); the goals each engine
  reaches, and those only one reaches; every "reachable" posture is put
  through the verdict's own check again (``verify``).
* **builds**: the config's atlas built with each engine, one after the
  other on all cores: wall and CPU seconds (this process and its workers),
  and the reachable vertices of each tree.
* **against a revision** (``--against REV``): the config's atlas built by this
  tree's code and by the code of git revision REV (checked out in a temporary
  worktree), alternately, ``--repeat`` times each, every build in a fresh
  process on all cores: wall and CPU seconds, reachable vertices per tree.
  The engine's own before and after, in one run (docs/decisions/0008).
* **where the rounds go** (``--rounds``): the config's atlas built in this
  process, one oracle a strategy, and each oracle's counts: goals, reached,
  reach rounds (one start's iteration) spent on goals reached and on goals
  never reached, fatrop polishes, CPU seconds.

Run: ``.venv/bin/python bench/engine.py [--config configs/demo.yaml] [--goals 200] [--skip-build] [--strategies a,b]``,
``bench/engine.py --against HEAD~3 [--repeat 2]`` or ``bench/engine.py --rounds``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from oracles.protocol import Goals, OracleSpec
from reach.building.atlas import build_atlas
from reach.building.config import load_config, parse_config
from reach.building.documents import read_yaml
from reach.building.executor import InlineExecutor, ProcessExecutor

ROOT = Path(__file__).resolve().parents[1]
ENGINES = ("batch", "fatrop")


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def cpu() -> float:
    """CPU seconds of this process and its finished children."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def fk_jacobian_seconds(oracle) -> float:  # noqa: ANN001
    """One forward kinematics and frame Jacobian of the body (Pinocchio from Python), seconds."""
    model, data, q = oracle.body.model, oracle.body.model.createData(), oracle.body.q_ref
    fid = oracle.problem.effector_id
    t0 = time.process_time()
    for _ in range(4000):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    return (time.process_time() - t0) / 4000


def with_engine(data: dict, engine: str) -> dict:
    out = dict(data)
    oracle = dict(out.get("oracle", {}))
    oracle["params"] = {**oracle.get("params", {}), "solver": engine}
    out["oracle"] = oracle
    return out


def calls(data: dict, names: list[str], goals: int, chunk: int) -> None:
    rng = np.random.default_rng(7)
    for engine in ENGINES:
        config = parse_config(with_engine(data, engine), "bench", "bench")
        for name in names:
            strategy = config.strategy(name)
            oracle = strategy.oracle.create()
            oracle.prepare()
            lo, hi = np.array(config.box.lo), np.array(config.box.hi)
            bound = oracle.reach_bound()
            if bound is not None:  # goals where the strategy may reach: its ball within the box
                lo, hi = np.maximum(lo, bound.centre - bound.radius), np.minimum(hi, bound.centre + bound.radius)
            goals_at = np.random.default_rng([7, len(name)]).uniform(lo, hi, (goals, 3))
            near = goals_at + rng.normal(size=goals_at.shape) * (0.02 / np.sqrt(3))
            hints = oracle.evaluate(near).posture
            fkj = fk_jacobian_seconds(oracle)
            for label, h in (("cold", None), ("warm", hints)):
                t0, c0 = time.perf_counter(), time.process_time()
                parts = [oracle.evaluate(Goals(goals_at[k : k + chunk], seeds=None if h is None
                                               else h[k : k + chunk])) for k in range(0, goals, chunk)]
                wall, spent = time.perf_counter() - t0, time.process_time() - c0
                reach = np.concatenate([p.reachable for p in parts])
                posture = np.concatenate([p.posture for p in parts])
                verified = oracle.verify(goals_at[reach], posture[reach]) if reach.any() else np.zeros(0, bool)
                emit(bench="engine_calls", engine=engine, strategy=name, start=label, goals=goals,
                     cpu_ms_per_goal=round(1e3 * spent / goals, 3),
                     wall_ms_per_goal=round(1e3 * wall / goals, 3), fk_jacobian_us=round(1e6 * fkj, 2),
                     calls_over_fk_jacobian=round(spent / goals / fkj, 1), reachable=int(reach.sum()),
                     verified=int(verified.sum()),
                     starts=getattr(oracle, "starts_per_goal", 1) if engine == "batch" else None)
                np.save(Path(tempfile.gettempdir()) / f"engine_{engine}_{name}_{label}.npy", reach)
    for name in names:
        for label in ("cold", "warm"):
            a, b = (np.load(Path(tempfile.gettempdir()) / f"engine_{e}_{name}_{label}.npy") for e in ENGINES)
            emit(bench="engine_agreement", strategy=name, start=label, both=int((a & b).sum()),
                 batch_only=int((a & ~b).sum()), fatrop_only=int((b & ~a).sum()))


def builds(data: dict, workers: int) -> None:
    for engine in ENGINES:
        config = parse_config(with_engine(data, engine), str(data.get("name", "bench")), "bench")
        with tempfile.TemporaryDirectory() as tmp:
            t0, c0 = time.perf_counter(), cpu()
            atlas = build_atlas(config, Path(tmp) / "atlas", executor_factory=lambda s,
                                c=config: ProcessExecutor(s, workers, c.chunk_size))
            wall, spent = time.perf_counter() - t0, cpu() - c0
            for name, tree in atlas.trees.items():
                b = tree.meta["build"]
                emit(bench="engine_build_tree", engine=engine, strategy=name, oracle_calls=b["oracle_calls"],
                     seconds=round(b["seconds"], 1),
                     reachable_vertices=int(tree.vertices.reachable.sum()), mirrored=b.get("mirrored_from") is not None)
            emit(bench="engine_build", engine=engine, config=config.name, workers=workers, wall_s=round(wall, 1),
                 cpu_s=round(spent, 1))


# One build in a fresh process of the code in its working directory: the trees' reachable vertices, wall and CPU seconds
# (the process and its workers).
BUILD = """
import json, resource, sys, tempfile, time
sys.path.insert(0, ".")
from pathlib import Path
from reach.building.atlas import build_atlas
from reach.building.config import load_config
from reach.building.executor import ProcessExecutor
from reach.maps.tree import FINAL, INNER
config = load_config(Path(sys.argv[1]))
workers = int(sys.argv[2])
def cpu():
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime
with tempfile.TemporaryDirectory() as tmp:
    t0, c0 = time.perf_counter(), cpu()
    atlas = build_atlas(config, Path(tmp) / "atlas", executor_factory=lambda s: ProcessExecutor(s, workers,
                        config.chunk_size))
    wall, spent = time.perf_counter() - t0, cpu() - c0
    trees = {n: int(t.vertices.reachable.sum()) for n, t in atlas.trees.items()}
    inner = {n: round(float(t.volume(INNER)), 4) for n, t in atlas.trees.items()}
    final = {n: round(float(t.volume(FINAL)), 4) for n, t in atlas.trees.items()}
print(json.dumps({"wall_s": round(wall, 1), "cpu_s": round(spent, 1), "reachable": trees, "inner_m3": inner,
                  "boundary_m3": final}))
"""


def against(config: Path, rev: str, repeat: int, workers: int) -> None:
    """This tree's build and REV's, alternately, each in a fresh process (see BUILD)."""
    with tempfile.TemporaryDirectory() as tmp:
        other = Path(tmp) / "rev"
        added = subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(other), rev],
                               capture_output=True, text=True)
        if added.returncode:
            raise SystemExit(f"--against {rev}: no such revision to check out ({added.stderr.strip()})")
        try:
            commit = subprocess.run(["git", "-C", str(other), "rev-parse", "--short", "HEAD"], check=True,
                                    capture_output=True, text=True).stdout.strip()
            for k in range(repeat):
                for label, where in (("this", ROOT), (f"rev {rev} ({commit})", other)):
                    run = subprocess.run([sys.executable, "-c", BUILD, str(config.resolve()), str(workers)], cwd=where,
                                         env={**os.environ, "PYTHONPATH": str(where)}, capture_output=True, text=True)
                    if run.returncode:
                        raise SystemExit(f"the build of {label} failed:\n{run.stderr[-2000:]}")
                    emit(bench="engine_against", code=label, run=k + 1, workers=workers,
                         **json.loads(run.stdout.strip().splitlines()[-1]))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(other)], check=False,
                           capture_output=True)


def rounds(config_path: Path) -> None:
    """The config's atlas built inline, one oracle a strategy, and where each oracle's reach rounds went."""
    config = load_config(config_path)
    made: list[tuple[str, InlineExecutor, float]] = []

    def factory(spec: OracleSpec) -> InlineExecutor:
        name = next((s.name for s in config.strategies if s.oracle == spec), spec.name)
        made.append((name, InlineExecutor(spec, config.chunk_size), time.process_time()))
        return made[-1][1]

    with tempfile.TemporaryDirectory() as tmp:
        build_atlas(config, Path(tmp) / "atlas", executor_factory=factory)
    ends = [t for _, _, t in made[1:]] + [time.process_time()]
    for (name, ex, t0), t1 in zip(made, ends, strict=True):
        st, oracle = ex.oracle.stats, ex.oracle
        reached, missed = st.get("rounds_reached", 0), st.get("rounds_missed", 0)
        emit(bench="engine_rounds", config=config.name, strategy=name, joints=len(oracle.posture_names),
             coordinates=getattr(getattr(oracle, "problem", None), "nx", None), goals=st.get("points", 0),
             reachable=st.get("reachable", 0), rounds_reached=reached, rounds_missed=missed,
             missed_share=round(missed / max(reached + missed, 1), 3), polished=st.get("polished", 0),
             polished_missed=st.get("polished_missed", 0), cpu_s=round(t1 - t0, 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "demo.yaml"))
    parser.add_argument("--goals", type=int, default=200)
    parser.add_argument("--strategies", default="right_arm,right_upper_body,right_whole_body,right_crouch")
    parser.add_argument("--skip-calls", action="store_true")
    parser.add_argument("--skip-build", action="store_true")
    parser.add_argument("--against", metavar="REV", help="compare this tree's build with git revision REV's, and stop")
    parser.add_argument("--repeat", type=int, default=1, help="builds of each code with --against (default 1)")
    parser.add_argument("--rounds", action="store_true", help="where the reach rounds of an inline build go, and stop")
    args = parser.parse_args()
    workers = os.cpu_count() or 1
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         cores=workers)
    if args.against:
        against(Path(args.config), args.against, args.repeat, workers)
        return
    if args.rounds:
        rounds(Path(args.config))
        return
    data = read_yaml(Path(args.config))
    if not args.skip_calls:
        calls(data, args.strategies.split(","), args.goals, int(data.get("build", {}).get("chunk_size", 256)))
    if not args.skip_build:
        builds(data, workers)


if __name__ == "__main__":
    main()
