"""How many bodies (Pinocchio models with their capsules) a selector and a build construct; prints JSON lines.

* ``Selector(atlas).warm_up()`` on an atlas (the demo's by default): every
  strategy's refinement oracle and its posture index.
* ``reach build`` of a config (``configs/demo.yaml`` by default) in this
  process (inline executor) at depths 1-2, which constructs the same oracles
  as a full build: the config's check, the sub-strategy search, mirroring
  and the executor's own.

Run: ``.venv/bin/python bench/bodies.py [--atlas out/demo] [--config configs/demo.yaml]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from unittest import mock

import yaml

import oracles.bodies.body
import oracles.ik.oracle


def counting() -> tuple[mock._patch, list[int]]:  # type: ignore[type-arg]
    calls: list[int] = []
    real = oracles.bodies.body.load_body

    def load(spec: dict) -> oracles.bodies.body.Body:  # type: ignore[type-arg]
        calls.append(1)
        return real(spec)

    return mock.patch.object(oracles.ik.oracle, "load_body", load), calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--atlas", default="out/demo")
    parser.add_argument("--config", default="configs/demo.yaml")
    args = parser.parse_args()
    from reach.answers.select import Selector
    from reach.building.atlas import build_atlas
    from reach.building.config import load_config
    from reach.maps.atlas import load_atlas

    patch, calls = counting()
    with patch:
        atlas = load_atlas(args.atlas)
        Selector(atlas).warm_up()
    print(json.dumps({"case": "Selector(atlas).warm_up()", "atlas": args.atlas, "strategies": len(atlas.trees),
                      "bodies": len(calls)}))
    config = Path(args.config).resolve()
    data = yaml.safe_load(config.read_text())
    with tempfile.TemporaryDirectory() as tmp:
        shallow = Path(tmp) / "shallow.yaml"
        shallow.write_text(yaml.safe_dump({"base": str(config), "depth": {"min": 1, "max": 2}, "name": "shallow"}))
        patch, calls = counting()
        with patch:
            cfg = load_config(shallow)
            loaded = len(calls)
            build_atlas(cfg, Path(tmp) / "out")
    print(json.dumps({"case": "reach build (inline, depths 1-2)", "config": args.config,
                      "strategies": len(data["strategies"]), "bodies": len(calls), "of_which_load_config": loaded}))


if __name__ == "__main__":
    main()
