"""Building atlases and their bodies: build, accept, model."""



from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from reach.errors import ConfigError, InputError, TreeError
from reach.serving import protocol as P
from reach.tools.commands.common import (
    add_executor_arguments,
    executor_factory,
    on_terminate,
    print_json,
)


def _with_options(config: Any, args: argparse.Namespace) -> Any:
    """The config, its warnings said (errors with --strict), with the command line's refinement options."""
    for note in config.notes:
        print(f"warning: {config.source}: {note}", file=sys.stderr, flush=True)
    if args.strict and config.notes:
        raise ConfigError(config.source, "", f"{len(config.notes)} warning(s) above, and --strict makes them errors")
    if not (args.refine_centres or args.refine_faces or args.retry_isolated):
        return config
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.building.tree import Refine

    r = config.refine
    return dataclasses.replace(config, refine=Refine(r.centres or args.refine_centres, r.faces or args.refine_faces,
                                                     r.isolated or args.retry_isolated))


def cmd_build(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.building.atlas import build_atlas
    from reach.building.config import load_config

    config = _with_options(load_config(args.config), args)
    out = Path(args.output) if args.output else Path("out") / config.name
    factory, client, how = executor_factory(args, config.chunk_size)

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_terminate)  # as Ctrl-C: the checkpoints stay, a message, status 143
    if config.population is not None:
        print(f"building a population ({config.population.to_dict()}), {len(config.strategies)} "
              f"strateg{'y' if len(config.strategies) == 1 else 'ies'} a member, of {config.source} into {out} "
              f"({how})", flush=True)
        return _build_population(args, config, out, factory, client)
    print(f"building {len(config.strategies)} strateg{'y' if len(config.strategies) == 1 else 'ies'} of "
          f"{config.source} into {out} ({how})", flush=True)
    try:
        atlas = build_atlas(config, out, executor_factory=factory, progress=not args.quiet,
                            log=lambda line: print(line, flush=True),
                    resume=args.resume, mirror=not args.no_mirror,
                    inherit=not args.no_inherit)
    finally:
        if client is not None:
            client.close()
    print(f"atlas written to {out}")
    cut = [w["strategy"] for w in atlas.manifest.get("warnings", {}).get("faces", [])]
    if args.strict and cut:
        raise TreeError(f"the box cuts the volume of {', '.join(cut)} (warnings above), and --strict makes that an "
                        "error; the atlas is kept")
    return 0


def _build_population(args: argparse.Namespace, config: Any, out: Path, factory: Any, client: Any) -> int:
    """``reach build`` of a config with ``population:``: one atlas per member (reach.building.population)."""
    from reach.building.atlas import build_atlas
    from reach.building.population import build_population

    def one(member: Any, folder: Path) -> None:
        build_atlas(member, folder, executor_factory=factory, progress=not args.quiet,
                    log=lambda line: print(f"  {line}", flush=True), resume=args.resume, mirror=not args.no_mirror,
                    inherit=not args.no_inherit)

    try:
        members = build_population(config, out, one, say=lambda line: print(line, flush=True), resume=args.resume)
    finally:
        if client is not None:
            client.close()
    print(f"population of {len(members)} written to {out} (population.json and one atlas folder per member)")
    return 0


def add_build(sub: Any) -> None:
    """Register ``reach build``."""
    p = sub.add_parser("build", help="build every strategy's tree of a config", description="Build every strategy of "
        "CONFIG into an atlas folder (one tree per strategy plus manifest.json).")
    p.add_argument("config", help="YAML configuration, e.g. configs/sphere.yaml")
    p.add_argument("-o", "--output", help="output folder (default: out/<config name>)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    add_executor_arguments(p)
    p.add_argument("--resume", action="store_true", help="keep finished trees and continue interrupted ones from "
                                                         "their last depth")
    p.add_argument("--no-mirror", action="store_true", help="build both sides instead of mirroring 'mirror_of' "
                                                            "strategies")
    p.add_argument("--no-inherit", action="store_true",
                   help="solve every vertex, instead of taking a sub-strategy's verified reachable vertices (the "
                        "crouch the whole body's)")
    p.add_argument("--refine-centres", action="store_true", help="probe the centre of each would-be inner cell; "
        "split it if the probe fails")
    p.add_argument("--refine-faces", action="store_true", help="also probe the centres of its faces")
    p.add_argument("--retry-isolated", action="store_true", help="retry unreachable vertices whose neighbours are "
        "all reachable, from their postures")
    p.add_argument("--strict", action="store_true",
                   help="make warnings errors (exit 2): the config's (a clipped reference joint, a hard task the "
                        "reference breaks, capsules overlapping there) before building, and reachable vertices on a "
                        "face of the box after (the atlas is kept)")
    p.set_defaults(func=cmd_build)


def cmd_accept(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.maps.atlas import accept_manifest

    atlas = accept_manifest(args.atlas)
    print(f"{atlas.path}: manifest accepted as it is ({len(atlas.trees)} strategies: {', '.join(atlas.trees)})")
    return 0


def add_accept(sub: Any) -> None:
    """Register ``reach accept``."""
    p = sub.add_parser("accept", help="accept a hand-edited atlas manifest",
                       description="Stamp an atlas's manifest.json with the digest of its content as it now is, "
                                   "after checking that the atlas loads with it. A manifest edited by hand "
                                   "(priorities, strategies, model hashes) is refused until accepted so.")
    p.add_argument("atlas", help="atlas folder")
    p.set_defaults(func=cmd_accept)


def cmd_prepare(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.select import Selector
    from reach.building.population import is_population
    from reach.maps.atlas import load_atlas

    t0 = time.perf_counter()
    folder, whom = Path(args.atlas), ""
    if is_population(folder):
        # The members' programs are one a strategy (their bodies' numbers are the programs' parameters): the first
        # member's serve every member.
        from reach.answers.accommodation import member_atlases

        paths, _, names = member_atlases(folder)
        atlas, whom = load_atlas(paths[0]), f" (its first member, {names[0]}, for all {len(names)})"
    else:
        atlas = load_atlas(folder)
    selector = Selector(atlas)
    strategies = selector.strategies_for(args.effector) if args.effector else list(selector.atlas.maps)
    selector.warm_up(args.effector)
    stored = [n for n in strategies if selector.atlas.maps[n].posture_names]
    print(f"{args.atlas}: the refinement programs of {len(stored)} strategies ready{whom} "
          f"({', '.join(stored) or 'none'}; {time.perf_counter() - t0:.1f} s): queries, motions, evaluate's "
          "refinements and serve compile nothing more for them")
    return 0


def add_prepare(sub: Any) -> None:
    """Register ``reach prepare``."""
    p = sub.add_parser("prepare", help="compile the programs an atlas's answers use, now",
                       description="Build every strategy's refinement solvers of an atlas (compiling their programs "
                                   "when the configs ask for jit and the cache lacks them, each said with progress), "
                                   "so that the first query, motion or serve does not compile (evaluate's thorough "
                                   "solve of a target no tree holds compiles its own). Safe to run again: compiled "
                                   "programs are kept in the cache.")
    p.add_argument("atlas", help="atlas folder written by 'reach build', or a population's folder (its members share "
                                 "their programs)")
    p.add_argument("--effector", help="only this effector's strategies")
    p.set_defaults(func=cmd_prepare)


def _members(config: Any, as_json: bool) -> int:
    """``reach model`` of a config with ``population:``: its members and their key dimensions."""
    from oracles.bodies.population import key_dimensions, members

    rows = [{"name": m.name, "sex": m.sex, "weight": round(m.weight, 4), **key_dimensions(m), "body": m.human}
            for m in members(config.population)]
    if as_json:
        print_json({"population": config.population.to_dict(), "members": rows})
        return 0
    print(f"{config.source}: a population of {len(rows)} ({sum(r['sex'] == 'female' for r in rows)} women); key "
          "dimensions [m] (ANSUR II's; a boundary manikin's regressed on its family's): stature, thumb-tip reach, "
          "sitting height, buttock-knee length")
    print(f"  {'member':<22} {'sex':<7} {'weight':>7} {'stature':>8} {'thumbtip':>9} {'sitting':>8} {'butt-knee':>9}")
    for r in rows:
        print(f"  {r['name']:<22} {r['sex']:<7} {r['weight']:>7.3f} {r['stature']:>8.4f} {r['thumbtipreach']:>9.4f} "
              f"{r['sittingheight']:>8.4f} {r['buttockkneelength']:>9.4f}")
    return 0


def cmd_model(args: argparse.Namespace) -> int:
    spec = args.spec
    placing = {"up": args.up, "forward": args.forward, "root_position": args.root_position, "root_rpy": args.root_rpy,
               "package_dirs": args.package_dir}
    given = sorted(k for k, v in placing.items() if v is not None)
    if given and (spec == "human" or spec.endswith((".yaml", ".yml"))):
        raise InputError(given[0], "options for a URDF (a config gives them in its body; the generated human stands "
                                   "on z = 0 facing +x)")
    if spec.endswith((".yaml", ".yml")):
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.building.config import load_config

        config = load_config(spec)  # errors name the file and the key
        if config.population is not None:
            return _members(config, args.json)
        body, strategies, warnings = _config_body(config, spec)
    else:
        body, strategies, warnings = _model_body(args, placing), {}, []
        if spec != "human":
            warnings = list(body.notes)
    info = {**body.describe(), "world_frame": P.WORLD_AXES, "warnings": warnings,
            **({"strategies": strategies} if strategies else {})}
    if body.anthropometry is not None:
        info["dimensions"] = _dimensions(body)
    if args.figure:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.tools.sketch import body_figure

        body_figure(body.capsules_at(), body.furniture, Path(args.figure), Path(spec).stem if spec != "human"
                    else "human")
        info["figure"] = args.figure
    if args.json:
        print_json(info)
    else:
        _print_model(body, info, strategies, args.figure)
    return 0


def _model_body(args: argparse.Namespace, placing: dict[str, Any]) -> Any:
    """The generated human of the command line's options, or a URDF placed by them."""
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from oracles.bodies.body import human_body, load_body

    if args.spec != "human":
        return load_body({"urdf": args.spec, **{k: v for k, v in placing.items() if v is not None}})
    dims = {}
    for item in args.dim:
        name, _, value = item.partition("=")
        try:
            dims[name.strip()] = float(value)
        except ValueError:
            raise InputError("--dim", f"expected NAME=METRES, got {item!r}") from None
    return human_body(args.sex, args.stature, args.percentile, args.mass, dims=dims, proportions=args.proportions,
                      ansur=None if args.subject is None else {"sex": args.sex, "subject": args.subject})


def _config_body(config: Any, spec: str) -> tuple[Any, dict[str, Any], list[str]]:
    """A config's body, each strategy's description and the config's warnings."""
    from oracles.bodies.body import load_body
    from oracles.protocol import Described
    from reach.building.documents import read_yaml

    data = read_yaml(Path(spec))
    if not isinstance(data, dict) or "body" not in data:
        raise ConfigError(spec, "body", "the config names no body")
    body = load_body(data["body"])
    strategies = {}
    for s in config.strategies:
        oracle = s.oracle.create()
        if isinstance(oracle, Described):
            strategies[s.name] = oracle.describe()
    return body, strategies, list(config.notes)


def _print_model(body: Any, info: dict[str, Any], strategies: dict[str, Any], figure: str | None) -> None:
    print(f"{body.source}: {len(info['joints'])} joints, mass {info['mass']:.2f} kg" + (", stature "
        f"{info['stature']:.4f} m" if "stature" in info else ""))
    for j in info["joints"]:
        print(f"  {j['name']:<28} " + ("continuous (-pi, pi]" if j.get("continuous") else f"[{j['lower']:+.4f}, "
            f"{j['upper']:+.4f}]"))
    if "dimensions" in info:
        _print_dimensions(info)
    print(f"  centre of mass {info['center_of_mass']}")
    print(f"  {len(info['frames'])} frames at the reference posture [m]:")
    for name, pos in info["frames"].items():
        print(f"    {name:<28} {np.round(pos, 4).tolist()}")
    print(f"  {len(info['capsules'])} collision capsules [m]:")
    for c in info["capsules"]:
        print(f"    {c['name']:<20} on {c['link']:<16} radius {c['radius']:.4f} length {c['length']:.4f}")
    if "seat" in info:
        print("  seated on " + ", ".join(f"{k} {v}" for k, v in info["seat"].items()) + " [m, deg]")
        for b in info["furniture"]:
            print(f"    {b['name']:<20} min {b['min']} max {b['max']}" + (" turned rpy "
                f"{np.round(b['rpy'], 4).tolist()} [rad]" if "rpy" in b else ""))
    if figure:
        print(f"  wrote {figure}")
    _print_strategies(strategies)
    for w in info["warnings"]:
        print(f"warning: {w}", file=sys.stderr)


def _print_strategies(strategies: dict[str, Any]) -> None:
    for name, d in strategies.items():
        for t in d["tasks"]:
            if t.get("text"):  # the task's own line (see oracles.tasks.base.Task.describe)
                print(f"  {name}: {t['text']}")
        if "reference" in d:  # reference: auto, as found for this strategy
            print(f"  {name}: reference (auto) " + ", ".join(f"{k} {v:+.4f}" for k, v in d["reference"].items()))


def _print_dimensions(info: dict[str, Any]) -> None:
    print(f"  {info['proportions']} body; ANSUR II dimensions [m; weightkg in kg]: asked, regressed (residual SD), "
          "measured on the model (- where it has no such measure; oracles/bodies/measure.py)")
    for name, d in info["dimensions"].items():
        asked = "" if d["asked"] is None else f"{d['asked']:.4f}"
        built = "-" if d["measured"] is None else f"{d['measured']:.4f}"
        regressed = "-" if d["regressed"] is None else f"{d['regressed']:.4f} ({d['sd']:.4f})"
        print(f"    {name:<32} {asked:>8} {regressed:>17} {built:>8}")


def _dimensions(body: Any) -> dict[str, dict[str, float | None]]:
    """A human's ANSUR II dimensions: asked for, as regressed (and the residual SD), and measured on the model as the
    survey measures people (oracles.bodies.measure), the reach-setting ones first."""
    # loaded when the command runs: `reach --help` starts without Pinocchio
    from oracles.bodies.ansur import COLUMNS, REACH
    from oracles.bodies.measure import measure

    a = body.anthropometry
    measured = measure(body)
    names = [*REACH, *(c for c in COLUMNS if c not in REACH)] if a.dims else list(measured)
    return {n: {"asked": a.asked.get(n), "regressed": a.dims.get(n), "sd": a.spread.get(n),
                "measured": measured.get(n)} for n in names}


def add_model(sub: Any) -> None:
    """Register ``reach model``."""
    p = sub.add_parser(
        "model", help="describe a body", description="Describe a body: its joints and ranges [rad], mass [kg], "
                                                     "stature [m] and frame positions [m] in the reference posture "
                                                     "(world frame: z up, x forward, y left)."
    )
    p.add_argument("spec", help="a config file (its body), a URDF file, or 'human'")
    p.add_argument("--sex", default="male", choices=["male", "female"], help="for 'human' (default male)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--percentile", type=float, help="for 'human': stature percentile of ANSUR II (default 50)")
    group.add_argument("--stature", type=float, help="for 'human': stature [m]")
    p.add_argument("--mass", type=float, help="for 'human': body mass [kg] (default: ANSUR II's regression on what is "
                                              "given)")
    p.add_argument("--dim", action="append", metavar="NAME=M", default=[],
                   help="for 'human': an ANSUR II dimension by its name [m] (acromialheight=1.44); repeatable; those "
                        "not given are the survey's regression on those given")
    p.add_argument("--subject", type=int, metavar="ID", help="for 'human': an ANSUR II subject of --sex, by id")
    p.add_argument("--proportions", choices=["ansur", "de_leva"], default="ansur",
                   help="for 'human': ansur (from measured dimensions; default) or de_leva (stature-scaled, the "
                        "body of earlier versions)")
    p.add_argument("--up", help="for a URDF: the model's own up axis (z, -z, y, -y, x, -x; default z), turned onto "
                                "the world's z")
    p.add_argument("--forward", help="for a URDF: the model's own forward axis, turned onto the world's x (default "
                                     "x; z when up is x)")
    p.add_argument("--root-position", type=float, nargs=3, metavar=("X", "Y", "Z"), help="for a URDF: where its root "
        "link stands [m]")
    p.add_argument("--root-rpy", type=float, nargs=3, metavar=("R", "P", "Y"), help="for a URDF: a further root "
        "rotation [rad]")
    p.add_argument("--package-dir", action="append", metavar="DIR",
                   help="for a URDF: a folder holding a package its package:// meshes name (the folder above the "
                        "package's); repeatable")
    p.add_argument("--figure", metavar="PNG", help="draw the reference posture and the body's furniture (a seat), "
                                                   "side and top views")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_model)


# Each registers its command's subparser.
COMMANDS = (add_build, add_accept, add_prepare, add_model)
