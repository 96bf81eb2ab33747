"""What the build-time refinements cost and buy; prints JSON lines.

Builds strategies of configs/demo.yaml (default: right_arm and
right_upper_body at the demo's depths) plainly and with each refinement
option, then audits every tree with the same seeded probes: oracle calls
against false-reachable and false-unreachable rates.

Run: ``.venv/bin/python bench/audit.py [--samples N] [--strategies a,b]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
from pathlib import Path

from reach.answers.audit import audit
from reach.building.atlas import build_atlas
from reach.building.config import parse_config
from reach.building.documents import read_yaml
from reach.building.executor import ProcessExecutor
from reach.building.tree import Refine

ROOT = Path(__file__).resolve().parents[1]
OPTIONS = {
    "plain": Refine(),
    "centres": Refine(centres=True),
    "centres+faces": Refine(centres=True, faces=True),
    "isolated": Refine(isolated=True), "centres+isolated": Refine(centres=True, isolated=True),
}


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=600)
    parser.add_argument("--strategies", default="right_arm,right_upper_body")
    parser.add_argument("--config", default=str(ROOT / "configs" / "demo.yaml"))
    args = parser.parse_args()
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         cores=os.cpu_count())
    names = args.strategies.split(",")
    data = read_yaml(Path(args.config))
    data["strategies"] = [s for s in data["strategies"] if s["name"] in names]
    for s in data["strategies"]:
        s.pop("mirror_of", None)
    for label, refine in OPTIONS.items():
        data["build"] = {**data.get("build", {}), "refine": refine.to_dict()}
        config = parse_config(data, label, "audit")
        with tempfile.TemporaryDirectory() as tmp:
            atlas = build_atlas(config, Path(tmp) / "a", executor_factory=lambda s,
                                c=config: ProcessExecutor(s, os.cpu_count(), c.chunk_size))
            result = audit(atlas, args.samples, "vertex", seed=0)
        for name in names:
            r = result["strategies"][name]
            emit(bench="audit", option=label, strategy=name, oracle_calls=atlas.trees[name].oracle_calls,
                 probes=r["probes"], false_reachable=round(r["false_reachable"], 4),
                 false_reachable_ci95=[round(v, 4) for v in r["false_reachable_ci95"]],
                 false_unreachable=round(r["false_unreachable"], 4),
                 false_unreachable_ci95=[round(v, 4) for v in r["false_unreachable_ci95"]])


if __name__ == "__main__":
    main()
