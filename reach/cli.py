"""The ``reach`` command line.

Every command has ``--help``. Errors from reach (bad configs, files, names)
print one line naming what was wrong and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from reach.errors import ReachError


def _print_json(data: Any) -> None:
    print(json.dumps(data, indent=2, sort_keys=True))


def cmd_build(args: argparse.Namespace) -> int:
    from reach.atlas import build_atlas
    from reach.config import load_config

    config = load_config(args.config)
    out = Path(args.output) if args.output else Path("out") / config.name
    print(f"building {len(config.strategies)} strateg{'y' if len(config.strategies) == 1 else 'ies'} of {config.source} into {out}")
    build_atlas(config, out, progress=not args.quiet, log=print)
    print(f"atlas written to {out}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from reach.atlas import summary
    from reach.store import load_atlas

    info = summary(load_atlas(args.atlas))
    if args.json:
        _print_json(info)
        return 0
    print(f"atlas {info['name']} at {info['path']}")
    for name, s in info["strategies"].items():
        ext = s["extent"]
        print(
            f"  {name} (effector {s['effector']}, priority {s['priority']}): "
            f"inner volume {s['volume']['inner']:.6g}, boundary {s['volume']['boundary']:.6g}, "
            f"{s['oracle_calls']} oracle calls of {s['lattice_vertices']} lattice vertices"
        )
        if ext:
            print(f"    extent min {np.round(ext['min'], 4).tolist()} max {np.round(ext['max'], 4).tolist()}")
    return 0


def cmd_query(args: argparse.Namespace) -> int:
    from reach.select import Selector
    from reach.store import load_atlas

    goal = np.array([args.x, args.y] + ([args.z] if args.z is not None else []), dtype=float)
    selector = Selector(load_atlas(args.atlas), policy=args.policy)
    effectors = [args.effector] if args.effector else selector.effectors
    answers = [selector.select(e, goal) for e in effectors]
    if args.json:
        _print_json({"answers": [a.to_dict() for a in answers]})
        return 0
    for a in answers:
        if a.reachable:
            also = f" (also: {', '.join(a.alternatives)})" if a.alternatives else ""
            print(f"{a.effector}: goal {list(a.goal)} reachable with strategy {a.strategy}{also}")
        else:
            print(f"{a.effector}: goal {list(a.goal)} not reachable by any strategy")
    return 0


def cmd_model(args: argparse.Namespace) -> int:
    from oracles.body import human_body, load_body, urdf_body

    spec = args.spec
    if spec == "human":
        body = human_body(args.sex, args.stature, args.percentile, args.mass)
    elif spec.endswith((".yaml", ".yml")):
        import yaml

        try:
            data = yaml.safe_load(Path(spec).read_text())
        except (OSError, yaml.YAMLError) as exc:
            raise ReachError(f"{spec}: cannot read the config ({exc})") from exc
        if not isinstance(data, dict) or "body" not in data:
            raise ReachError(f"{spec}: body: the config names no body")
        body = load_body(data["body"])
    else:
        body = urdf_body(spec)
    frames = {name: pos.round(6).tolist() for name, pos in body.frame_positions().items()}
    info: dict[str, Any] = {
        "source": body.source,
        "hash": body.hash,
        "mass": body.mass,
        "nq": int(body.model.nq),
        "joints": [{"name": n, "lower": lo, "upper": hi} for n, lo, hi in body.limits()],
        "frames": frames,
        "center_of_mass": body.center_of_mass().round(6).tolist(),
        "units": {"length": "m", "angle": "rad", "mass": "kg"},
        "world_frame": "z up, x forward, y left",
    }
    if body.anthropometry is not None:
        info["stature"] = body.anthropometry.stature
        info["sex"] = body.anthropometry.sex
    if args.json:
        _print_json(info)
        return 0
    print(f"{body.source}: {len(info['joints'])} joints, mass {info['mass']:.2f} kg" + (f", stature {info['stature']:.4f} m" if "stature" in info else ""))
    for j in info["joints"]:
        print(f"  {j['name']:<28} [{j['lower']:+.4f}, {j['upper']:+.4f}]")
    print(f"  centre of mass {info['center_of_mass']}")
    return 0


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="reach",
        description="Reachable volumes as adaptive octrees (VATrees): build, inspect and query them.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("build", help="build every strategy's tree of a config", description="Build every strategy of CONFIG into an atlas folder (one tree per strategy plus manifest.json).")
    p.add_argument("config", help="YAML configuration, e.g. configs/sphere.yaml")
    p.add_argument("-o", "--output", help="output folder (default: out/<config name>)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("info", help="summarise an atlas", description="Print node counts, volumes, extents and oracle calls of every strategy of an atlas.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("query", help="which strategy reaches a goal", description="Ask an atlas which strategy reaches the goal X Y [Z] (metres, atlas world frame), by priority.")
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("x", type=float, help="goal x [m]")
    p.add_argument("y", type=float, help="goal y [m]")
    p.add_argument("z", type=float, nargs="?", help="goal z [m] (3-D atlases)")
    p.add_argument("--effector", help="effector to ask about (default: every effector of the atlas)")
    p.add_argument("--policy", default="vertex", choices=["conservative", "optimistic", "vertex"], help="how boundary cells answer (default: vertex)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_query)

    p = sub.add_parser(
        "model", help="describe a body", description="Describe a body: its joints and ranges [rad], mass [kg], stature [m] and frame positions [m] in the reference posture (world frame: z up, x forward, y left)."
    )
    p.add_argument("spec", help="a config file (its body), a URDF file, or 'human'")
    p.add_argument("--sex", default="male", choices=["male", "female"], help="for 'human' (default male)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--percentile", type=float, help="for 'human': stature percentile of ANSUR II (default 50)")
    group.add_argument("--stature", type=float, help="for 'human': stature [m]")
    p.add_argument("--mass", type=float, help="for 'human': body mass [kg] (default: ANSUR II mean at constant BMI)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_model)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except ReachError as exc:
        print(f"reach: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("reach: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
