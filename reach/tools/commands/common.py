"""What the command line's commands share: options, executors, goals and printing."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from reach.answers.select import HANDOVER, MISS, MISSES
from reach.errors import InputError
from reach.maps.protocol import DEFAULT_POLICY, POLICIES


def print_json(data: Any) -> None:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.serving.protocol import finite

    print(json.dumps(finite(data), indent=2, sort_keys=True, allow_nan=False))


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled as SIGINT is."""


def on_terminate(signum: int, frame: Any) -> None:
    raise Terminated


def handover_option(p: argparse.ArgumentParser, where: str = "") -> None:
    p.add_argument("--handover-deg", type=float, default=math.degrees(HANDOVER), metavar="DEG",
                   help=f"{where}a strategy whose posture has joints within DEG of their limits hands the goal to "
                        f"the next that reaches it with fewer (default {math.degrees(HANDOVER):g}; 0: the paper's "
                        "plain priority)")
    p.add_argument("--miss", choices=MISSES, default=MISS,
                   help="a goal the trees hold but no refinement reaches answers 'unreachable' with the nearest "
                        "point a stored posture reaches (default), or 'within': reachable, with the distance the "
                        "posture stops short")


def handover_margin(args: argparse.Namespace) -> float:
    if not (math.isfinite(args.handover_deg) and args.handover_deg >= 0):
        raise InputError("--handover-deg", f"expected 0 or more degrees, got {args.handover_deg}")
    return math.radians(args.handover_deg)


def policy_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy", default=DEFAULT_POLICY, choices=POLICIES, help="how boundary cells answer (default: "
        f"{DEFAULT_POLICY})")
