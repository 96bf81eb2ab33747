"""What the command line's commands share: options, executors, goals and printing."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from reach.answers.defaults import HANDOVER, MISS, MISSES
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


def executor_factory(args: argparse.Namespace, chunk_size: int) -> tuple[Any, Any, str]:
    """The executor factory the build options ask for, the Dask client if any, and a description."""

    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.building.executor import DaskExecutor, InlineExecutor, ProcessExecutor

    workers = args.workers or os.cpu_count() or 1
    client = dask_client(args, workers)
    if client is not None:
        how = f"Dask scheduler {args.scheduler}" if args.scheduler else f"Dask LocalCluster, {workers} workers"
        return (lambda spec: DaskExecutor(spec, client, chunk_size)), client, how
    if workers == 1:
        return (lambda spec: InlineExecutor(spec, chunk_size)), None, "inline"
    return (lambda spec: ProcessExecutor(spec, workers, chunk_size)), None, f"{workers} processes"


def dask_client(args: argparse.Namespace, workers: int) -> Any:
    """The Dask client ``--scheduler ADDR`` or ``--dask`` (a LocalCluster of ``workers`` processes) asks for; None
    without either."""
    if not (args.scheduler or args.dask):
        return None
    # Dask only when work runs on it
    from distributed import Client, LocalCluster

    if args.scheduler:
        return Client(args.scheduler)
    return Client(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None))


def add_executor_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-j", "--workers", type=int, help="worker processes (default: all cores; 1 runs inline)")
    p.add_argument("--dask", action="store_true", help="run on a Dask LocalCluster of --workers processes")
    p.add_argument("--scheduler", metavar="ADDR", help="run on the Dask cluster at ADDR, e.g. tcp://10.0.0.5:8786")


def goals_file(source: str, with_atlas: bool, values: list[str]) -> tuple[str | None, list[list[float]]]:
    """``--goals FILE`` (or ``-``, standard input): one goal a line, X Y [Z] [m] separated by commas or spaces; blank
    lines, ``#`` comments and a header line of words are skipped. The positional values then hold the atlas alone
    (nothing with --connect)."""
    if len(values) != (1 if with_atlas else 0):
        raise InputError("goal", "with --goals, give the atlas alone" if with_atlas
                                 else "with --goals and --connect, give no goal on the command line")
    try:
        text = sys.stdin.read() if source == "-" else Path(source).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError("--goals", f"cannot read {source}: {exc}") from None
    goals: list[list[float]] = []
    seen = False  # a line with content came before (only the first may be a header)
    for k, line in enumerate(text.splitlines(), start=1):
        goal = _goal_line(source, k, line, header=not seen)
        seen = seen or goal is not None
        if goal:
            goals.append(goal)
    if not goals:
        raise InputError("--goals", f"{source} holds no goal")
    return (values[0] if with_atlas else None), goals


def goal_values(values: list[str], with_atlas: bool) -> tuple[str | None, list[float]]:
    expected = "ATLAS X Y [Z]" if with_atlas else "X Y [Z] (with --connect)"
    need = (3, 4) if with_atlas else (2, 3)
    if len(values) not in need:
        raise InputError("goal", f"query takes {expected}, got {len(values)} values")
    atlas = values[0] if with_atlas else None
    coords = values[1:] if with_atlas else values
    try:
        return atlas, [float(v) for v in coords]
    except ValueError as exc:
        raise InputError("goal", f"coordinates must be numbers in metres ({exc})") from exc


def from_posture(value: str | None) -> dict[str, float] | None:
    """--from: a JSON object of joint name -> value, or a file holding one."""
    if value is None:
        return None
    text = Path(value).read_text() if not value.lstrip().startswith("{") and Path(value).is_file() else value
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise InputError("--from", "expected a JSON object of joint name -> value [rad or m] or a file holding one "
                                   f"({exc})") from exc
    if not isinstance(data, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                             for v in data.values()):
        raise InputError("--from", f"expected a JSON object of joint name -> number, got {text[:80]!r}")
    return {str(k): float(v) for k, v in data.items()}


def _goal_line(source: str, k: int, line: str, header: bool) -> list[float] | None:
    """The goal on line k of a goals file: None for a blank line or a comment, [] for a header of words where
    ``header`` (no line with content came before it)."""
    fields = line.split("#")[0].replace(",", " ").split()
    if not fields:
        return None
    shown = line.strip()[:80]
    try:
        goal = [float(f) for f in fields]
    except ValueError:
        if header:
            return []
        raise InputError("--goals", f"{source} line {k}: expected X Y [Z] in metres, got {shown!r}") from None
    if len(goal) not in (2, 3) or not all(math.isfinite(v) for v in goal):
        raise InputError("--goals", f"{source} line {k}: expected 2 or 3 finite numbers, got {shown!r}")
    return goal
