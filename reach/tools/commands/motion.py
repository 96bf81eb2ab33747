"""``reach motion``: the timed reach motion to a goal, planned here or by a server, as JSON, BVH or glTF."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from reach.errors import InputError
from reach.serving import protocol as P
from reach.tools.commands.common import from_posture, goal_values, policy_option, print_json

MOTION_FILES = (".json", ".bvh", ".glb", ".gltf")  # reach motion -o: by the file's extension
ANIMATION_FILES = (".bvh", ".glb", ".gltf")  # ... those written from the motion's bones (its rig)


def _write_animation(path: str, kind: str, bones: Any) -> None:
    """A motion's rig (:class:`reach.motion.rig.Rig`) as BVH or glTF."""
    if kind == ".bvh":
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.motion.bvh import write_bvh

        write_bvh(bones, path)
    else:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.motion.gltf import write_gltf

        write_gltf(bones, path)


def cmd_motion(args: argparse.Namespace) -> int:
    """The reach motion to a goal, from a posture: a summary on stdout, the frames in ``-o FILE.json``."""
    atlas, goal = goal_values(args.values, args.connect is None)
    if len(goal) != 3:
        raise InputError("goal", f"a motion's goal has 3 coordinates [m], got {len(goal)}")
    start = from_posture(args.start)
    kind = Path(args.output).suffix.lower() if args.output else None
    if kind is not None and kind not in MOTION_FILES:
        raise InputError("-o", f"{args.output}: expected a {', '.join(MOTION_FILES)} file")
    timing = {"duration": args.duration} if args.duration is not None else None
    data = (_served_motion(args, goal, start, timing, kind) if args.connect
            else _planned_motion(args, atlas, goal, start, timing, kind))
    if kind == ".json":
        Path(args.output).write_text(json.dumps(data, indent=1) + "\n")
    summary = {k: v for k, v in data.items() if k != "frames"}
    if args.json:
        print_json(summary)
    else:
        _print_summary(summary, args)
    return 0


def _print_summary(summary: dict[str, Any], args: argparse.Namespace) -> None:
    """A motion's summary as lines for a person."""
    if summary["outcome"] == "reached":
        where = f"reaches {summary['goal']}"
    else:
        where = f"goes towards {summary['goal']}, out of reach, ending at {[round(v, 4) for v in summary['point']]}"
    print(f"{summary['effector']} {where} with strategy {summary['strategy']} in {summary['duration']:.3f} s "
          f"({summary['frame_count']} frames at {args.rate:g} Hz; {summary['waypoints']} stored postures on the way, "
          f"{summary['held']} frames held)")
    if summary.get("within") is not None:
        print(f"  the end posture stops {1000 * summary['within']:.1f} mm short of the goal")
    if summary["timing_tmu"]:
        print("  MTM-1: " + ", ".join(f"{k} {v:.1f} TMU" for k, v in summary["timing_tmu"].items()))
    if args.output:
        print(f"frames written to {args.output}")


def _served_motion(args: argparse.Namespace, goal: list[float], start: dict[str, float] | None,
                   timing: dict[str, float] | None, kind: str | None) -> dict[str, Any]:
    """``reach motion --connect``: the server's motion (and its rig, written as an animation file when asked)."""
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.serving.client import Client

    with Client(args.connect, timeout=args.timeout) as client:
        fields = {"effector": args.effector, "goal": goal, "rate": args.rate, "miss": args.miss,
                  "return": args.back}
        fields.update({k: v for k, v in (("from", start), ("timing", timing)) if v is not None})
        if kind in ANIMATION_FILES:
            fields["bones"] = True  # the server's body gives the skeleton
        data = {k: v for k, v in client.call("motion", **fields).items() if k not in ("ok", "id")}
    if kind in ANIMATION_FILES:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.motion.rig import Rig

        _write_animation(args.output, kind, Rig.from_dict(data.pop("rig", None)))
    return data


def _planned_motion(args: argparse.Namespace, atlas: str | None, goal: list[float], start: dict[str, float] | None,
                    timing: dict[str, float] | None, kind: str | None) -> dict[str, Any]:
    """``reach motion ATLAS``: the motion planned here (and its rig, written as an animation file when asked)."""
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.answers.select import Selector
    from reach.maps.atlas import load_atlas
    from reach.motion.planner import Planner
    from reach.motion.timing import Timing

    # The solvers are built (warm_up) before planning starts, so the end posture's budget is not spent on them.
    planner = Planner(Selector(load_atlas(atlas), policy=args.policy).warm_up(args.effector))  # type: ignore[arg-type]
    motion = planner.plan(args.effector, goal, start, rate=args.rate,
                          timing=Timing.from_dict(timing, "--duration"), miss=args.miss, back=args.back)
    data = motion.to_dict()
    if kind in ANIMATION_FILES:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.motion.rig import rig

        _write_animation(args.output, kind, rig(motion, planner.body(motion.strategy)))
    return data


def add_motion(sub: Any) -> None:
    """Register ``reach motion``."""
    p = sub.add_parser(
        "motion", help="the timed reach motion to a goal",
        description="Plan the reach motion of an effector to the goal X Y Z (metres, atlas world frame) from a "
                    "posture (the reference by default): "
        "the strategy chosen as a query chooses it, MTM-1 timing, minimum-jerk, collision-free frames holding feet "
        "and balance.",
    )
    p.usage = ("reach motion [options] --effector EFFECTOR ATLAS X Y Z\n"
               "       reach motion [options] --effector EFFECTOR --connect ADDR X Y Z")
    p.add_argument("values", nargs="+", metavar="ATLAS X Y Z",
                   help="atlas folder (omitted with --connect) and goal [m]")
    p.add_argument("--effector", required=True, help="the effector that reaches, e.g. right_hand")
    p.add_argument("--connect", metavar="ADDR", help="ask the server at ADDR instead of reading an atlas")
    p.add_argument("--from", dest="start", metavar="POSTURE", help="the first frame's posture: a JSON object of "
        "joint name -> value [rad or m], or a file holding one")
    p.add_argument("--rate", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument("--duration", type=float, help="the motion's duration [s] instead of MTM-1's")
    p.add_argument("--return", dest="back", action="store_true",
                   help="then back to the start, the way there reversed (a squat descends and rises)")
    p.add_argument("--miss", choices=["nearest", "error"], default="nearest", help="a goal out of reach: move "
        "towards the nearest reachable point (default), or fail")
    p.add_argument("-o", "--output", metavar="FILE", help="write the frames: .json (time, posture, root, effector), "
                                                          ".bvh (Biovision hierarchy), "
                   ".glb or .gltf (glTF 2.0: skinned capsules and their animation)")
    policy_option(p)
    p.add_argument("--timeout", type=int, default=P.REQUEST_TIMEOUT_MS, help="with --connect: ms to wait for the "
        f"reply (default {P.REQUEST_TIMEOUT_MS})")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_motion)
