"""What the command line's commands share: options, executors, goals and printing."""

from __future__ import annotations

import argparse
import json
import math
import os
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
