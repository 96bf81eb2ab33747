"""IK oracle benchmarks; prints JSON lines.

For each strategy of configs/human.yaml (right side and the foot) and each
engine (casadi-ik with fatrop, compiled and interpreted; casadi-ik with
IPOPT; dls): time per verdict, median and p90, cold (no hint)
and warm-started as in a build (hint: the posture found for a goal 2 cm away,
about one D_max cell of the default atlas); the success rate against the
best-known answer (reachable if any oracle with 6 restarts reaches it: every
such verdict passed the Pinocchio check); and how often the two oracles
disagree.

Run: ``.venv/bin/python bench/ik.py [--points N]`` (one core: ``taskset -c 0``).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from oracles.protocol import Goals, OracleSpec
from reach.building.config import load_config

ROOT = Path(__file__).resolve().parents[1]
# Engines by label: registry name and parameters over the strategy's own.
# The strategy's own "jit" is replaced by each engine's (dls takes none).
ENGINES = {"casadi-ik": ("casadi-ik", {"solver": "fatrop", "jit": "auto"}),
           "casadi-ik/ipopt": ("casadi-ik", {"solver": "ipopt", "jit": "auto"}),
           "casadi-ik/interpreted": ("casadi-ik", {"solver": "fatrop", "jit": False}), "dls": ("dls", {})}
STRATEGIES = ["right_arm", "right_upper_body", "right_whole_body", "right_crouch", "right_tiptoe", "right_foot"]


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def timed(oracle, points: np.ndarray, hints: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-point seconds, verdicts and postures."""
    seconds, reach, post = [], [], []
    for i in range(len(points)):
        t0 = time.perf_counter()
        v = oracle.evaluate(Goals(points[i : i + 1], seeds=None if hints is None else hints[i : i + 1]))
        seconds.append(time.perf_counter() - t0)
        reach.append(v.reachable[0])
        post.append(v.posture[0])
    return np.array(seconds), np.array(reach), np.array(post)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=60)
    args = parser.parse_args()
    config = load_config(ROOT / "configs" / "human.yaml")
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine())
    rng = np.random.default_rng(0)
    for name in STRATEGIES:
        spec = config.strategy(name).oracle
        params = {k: v for k, v in spec.params.items() if k != "jit"}
        if "foot" not in name:
            lo, hi = np.array([-0.4, -0.9, 0.6]), np.array([0.9, 0.4, 2.1])
        else:
            lo, hi = np.array([-0.5, -0.7, 0.0]), np.array([0.8, 0.2, 1.2])
        goals = rng.uniform(lo, hi, (args.points, 3))
        near = goals + rng.normal(size=goals.shape) * (0.02 / np.sqrt(3))
        verdicts = {}
        for label, (oracle_name, extra) in ENGINES.items():
            oracle = OracleSpec(oracle_name, {**params, **extra}).create()
            _, _, posture = timed(oracle, near)  # postures of the neighbours, the build's hints
            cold, reach, _ = timed(oracle, goals)
            warm, reach_warm, _ = timed(oracle, goals, posture)
            # Points the pre-filter rejects cost microseconds; the solver's cost shows on the others.
            solved = np.array([oracle.problem.prefilter(g) <= oracle.strategy.tolerance for g in goals])
            verdicts[label] = reach | reach_warm
            emit(
                bench="ik", strategy=name, oracle=label, points=len(goals),
                cold_median_ms=round(1e3 * float(np.median(cold)), 3),
                cold_p90_ms=round(1e3 * float(np.percentile(cold, 90)), 3),
                warm_median_ms=round(1e3 * float(np.median(warm)), 3),
                warm_p90_ms=round(1e3 * float(np.percentile(warm, 90)), 3),
                solved_points=int(solved.sum()),
                solved_cold_median_ms=round(1e3 * float(np.median(cold[solved])), 3) if solved.any() else None,
                solved_warm_median_ms=round(1e3 * float(np.median(warm[solved])), 3) if solved.any() else None,
                reachable=int(reach.sum()),
            )
        best = np.zeros(len(goals), bool)
        for oracle_name, extra in ENGINES.values():
            strong = OracleSpec(oracle_name, {**params, **extra, "restarts": 6, "give_up": None}).create()
            best |= strong.evaluate(goals).reachable
        for oracle_name, found in verdicts.items():
            emit(bench="success", strategy=name, oracle=oracle_name, best_known_reachable=int(best.sum()),
                 found=int((found & best).sum()),
                 success_rate=round(float((found & best).sum() / max(best.sum(), 1)), 4))
        for a, b in (("casadi-ik", "casadi-ik/ipopt"), ("casadi-ik", "dls")):
            emit(bench="agreement", strategy=name, pair=[a, b],
                 agree=round(float(np.mean(verdicts[a] == verdicts[b])), 4))


if __name__ == "__main__":
    main()
