"""How long loading and validating a config takes (bodies built, tasks parsed, nothing solved or compiled).

Prints one JSON line per shipped config: the median of --repeat loads [s]
in this process after a first, untimed load (imports), and whether gcc (the
jit compiler the configs ask for) is on the PATH.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import time
from pathlib import Path

import numpy as np

from reach.building.config import load_config

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(json.dumps({"bench": "machine", "python": platform.python_version(), "processor": platform.processor()
                      or platform.machine(), "gcc": shutil.which("gcc") is not None}))
    for path in sorted((ROOT / "configs").glob("*.yaml")):
        load_config(path)
        seconds = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            config = load_config(path)
            seconds.append(time.perf_counter() - t0)
        print(json.dumps({"bench": "load_config", "config": path.name, "strategies": len(config.strategies),
                          "median_s": round(float(np.median(seconds)), 4), "max_s": round(max(seconds), 4)}),
                              flush=True)


if __name__ == "__main__":
    main()
