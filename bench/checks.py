"""What a posture's check and a population member's oracles cost; prints JSON lines.

* ``check``: for each right-hand strategy of ``configs/demo.yaml``, the verdict's own check of a posture
  (``faults``: Pinocchio's forward kinematics, the joint ranges and every hard task's ``holds``), and each part
  alone, in microseconds a posture: what a motion pays at every frame, a build at every verified vertex and
  ``reach evaluate --direct`` at every reached target. Postures drawn across the ranges (``--seed``).
* ``oracles``: the four strategies' oracles of a member of ``configs/population.yaml`` (its body loaded once, the
  programs shared with the members before it), in milliseconds a member, over ``--members`` members.

Each figure is the median of ``--repeats`` runs one after the other (this machine's speed moves by 10-20 % from
minute to minute: compare figures of one run). Usage::

    python bench/checks.py [--members 40] [--repeats 5] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

from oracles.protocol import OracleSpec, Sharing, create_siblings  # noqa: E402
from oracles.tasks.base import Numeric  # noqa: E402
from reach.answers.accommodation import SHARED  # noqa: E402
from reach.building.config import load_config, parse_config  # noqa: E402
from reach.building.documents import read_yaml  # noqa: E402
from reach.building.population import members_of  # noqa: E402

STRATEGIES = ("right_arm", "right_upper_body", "right_whole_body", "right_crouch")


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def median_us(run: Any, count: int, repeats: int) -> float:
    """The median over ``repeats`` of one call's time [us], each the mean of ``count`` calls."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append((time.perf_counter() - t0) / count * 1e6)
    return round(float(np.median(times)), 1)


def checks(repeats: int, seed: int) -> None:
    config = load_config(ROOT / "configs" / "demo.yaml")
    for name in STRATEGIES:
        oracle = config.strategy(name).oracle.create()
        emit(bench="check", strategy=name, **check(oracle, repeats, seed))


def check(oracle: Any, repeats: int, seed: int) -> dict[str, Any]:
    """One strategy's figures: its check of 200 postures drawn across the ranges, whole and by part."""
    body, problem = oracle.body, oracle.problem
    model, data = body.model, body.model.createData()
    lo, hi = model.lowerPositionLimit[7:], model.upperPositionLimit[7:]
    rng = np.random.default_rng(seed)
    postures = np.repeat(body.q_ref[None], 200, axis=0)
    postures[:, 7:] += rng.uniform(0.0, 0.5, (200, 1)) * (rng.uniform(lo, hi, (200, len(lo))) - postures[:, 7:])
    n = len(postures)
    parts = {"faults": median_us(lambda: oracle.faults(postures), n, repeats),
             "forward_kinematics": median_us(lambda: [pin.framesForwardKinematics(model, data, q) for q in postures],
                                             n, repeats),
             "ranges": median_us(lambda: [problem.out_of_limits(q) for q in postures], n, repeats)}
    nums = [Numeric(model, data, q, np.zeros(3)) for q in postures]
    for task in oracle.strategy.hard:
        def held(task: Any = task) -> None:
            for q, num in zip(postures, nums, strict=True):
                pin.framesForwardKinematics(model, data, q)  # the data each check reads is this posture's
                task.holds(num)
        parts[task.type] = round(median_us(held, n, repeats) - parts["forward_kinematics"], 1)
    return {"postures": n, "breaking_a_task": sum(bool(f) for f in oracle.faults(postures)), "us_a_posture": parts}


def oracles(members: int, repeats: int) -> None:
    data = read_yaml(ROOT / "configs" / "population.yaml")
    data["population"]["ansur"]["n"] = members
    config = parse_config(data, "population.yaml", "population")
    people = members_of(config)
    strategies = [(s.name, s.oracle.name, s.oracle.params) for s in config.strategies]

    def run() -> None:
        lenders: dict[str, list[object]] = {}
        for m in people:
            body = m.body(config.raw.get("body"))
            made = create_siblings([OracleSpec(o, {**p, **SHARED.get(o, {}), "body": body}) for _, o, p in strategies])
            for (name, *_), oracle in zip(strategies, made, strict=True):
                lending = lenders.setdefault(name, [])
                if isinstance(oracle, Sharing) and not any(oracle.share_programs(o) for o in lending):
                    lending.append(oracle)

    run()  # the programs loaded once
    emit(bench="oracles", members=len(people), strategies=len(strategies),
         ms_a_member=round(median_us(run, len(people), repeats) / 1e3, 2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--members", type=int, default=40, help="population members whose oracles are made")
    parser.add_argument("--repeats", type=int, default=5, help="runs of each figure; the median is printed")
    parser.add_argument("--seed", type=int, default=0, help="the postures' seed")
    args = parser.parse_args()
    emit(bench="machine", python=platform.python_version(), processor=platform.machine())
    checks(args.repeats, args.seed)
    oracles(args.members, args.repeats)


if __name__ == "__main__":
    main()
