"""Serving and viewing an atlas: serve, keys, view."""


from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path
from typing import Any

from reach.answers.defaults import REFINE_BUDGET
from reach.errors import InputError, ReachError
from reach.serving import protocol as P
from reach.tools.commands.common import handover_margin, handover_option, policy_option


def cmd_serve(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.serving.server import READY_WAIT, Server

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    # the server's own log says each compile, timestamped: the command line's line would say it twice
    compiles = logging.getLogger("reach.jit")
    for handler in [h for h in compiles.handlers if getattr(h, "reach_cli", False)]:
        compiles.removeHandler(handler)
    # One core is left to the request loop: on 2 cores the stored answers' p99 under refinement
    # load was 0.52-0.80 ms with one worker, 0.61-1.78 ms with two (bench/server.py; README, Benchmarks).
    workers = max(1, (os.cpu_count() or 1) - 1) if args.workers is None else args.workers
    if workers < 0:
        raise InputError("--workers", f"expected 0 or more worker processes, got {workers}")
    server = Server(args.atlas, args.bind, None if args.pub == "none" else args.pub, policy=args.policy,
                    refine=not args.no_refine, budget=args.budget_ms / 1000.0, curve_secret=args.curve_secret_key,
                    workers=workers, curve_clients=args.curve_clients, chunk=args.chunk,
                    handover=handover_margin(args), miss=args.miss, allow_reload=args.allow_reload,
                    population=args.population)
    server.handle_signals()
    # "serving" means its workers refine: a client connecting on this line gets refined answers at once.
    ready = server.wait_ready()
    if ready < workers:
        print(f"reach: warning: {ready} of {workers} workers ready after {READY_WAIT:g} s; the others are still "
              "starting (health says how many are ready)", file=sys.stderr)
    print(f"serving {args.atlas} on {server.endpoint}" + (f", publishing on {server.pub_endpoint}"
                                                          if server.pub_endpoint else ""), flush=True)
    server.serve_forever()
    print("server stopped", flush=True)
    return 0


def add_serve(sub: Any) -> None:
    """Register ``reach serve``."""
    p = sub.add_parser(
        "serve", help="answer queries over ZeroMQ",
        description="Serve an atlas: JSON requests on a ROUTER socket (REQ or DEALER clients), every choice "
                    "published on a PUB socket. See docs/protocol.md.",
    )
    p.add_argument("atlas", help="atlas folder written by 'reach build'")
    p.add_argument("--bind", default=P.DEFAULT_BIND, help=f"request address (default {P.DEFAULT_BIND})")
    p.add_argument("--pub", default=P.DEFAULT_PUB, help=f"publishing address, or 'none' (default {P.DEFAULT_PUB})")
    policy_option(p)
    p.add_argument("--no-refine", action="store_true", help="answer with stored postures; no IK refinement unless a "
                                                            "request asks")
    p.add_argument("--budget-ms", type=float, default=REFINE_BUDGET * 1000,
                   help="budget of one IK refinement [ms]: work priced in the reference machine's time, so an answer "
                        f"does not depend on the load (default {REFINE_BUDGET * 1000:g})")
    p.add_argument("--curve-secret-key", metavar="FILE", help="encrypt with CURVE, using this server secret-key file "
                                                              "(zmq.auth.create_certificates)")
    p.add_argument("--curve-clients", metavar="DIR", help="with --curve-secret-key: let in only the clients whose "
                                                          "public-key files (*.key) are in DIR")
    p.add_argument("--workers", type=int, metavar="N", help="refinement worker processes (default: one fewer than "
                                                            "the cores, at least 1; 0 refines in the request loop)")
    p.add_argument("--chunk", type=int, default=P.CHUNK_GOALS, metavar="N",
                   help=f"refined goals per worker task at most (default {P.CHUNK_GOALS}); within it a task is sized "
                        "to about 20 ms of measured work, "
                        "so that another client's query waits about that for a busy worker")
    p.add_argument("--allow-reload", metavar="ROOT", help="let clients 'reload' atlases from folders under ROOT "
                                                          "(default: reload is refused)")
    p.add_argument("--population", metavar="FOLDER", help="a population folder (reach build of a config with "
                   "population:) whose members' trees answer the 'accommodation' operation")
    handover_option(p)
    p.set_defaults(func=cmd_serve)


def cmd_keys(args: argparse.Namespace) -> int:
    # the CURVE authenticator only when keys are given
    import zmq.auth

    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    for suffix in ("key", "key_secret"):
        if (folder / f"{args.name}.{suffix}").exists():
            raise InputError(str(folder / f"{args.name}.{suffix}"), "exists; choose another --name or folder (keys "
                "are never overwritten)")
    public, secret = zmq.auth.create_certificates(str(folder), args.name)
    os.chmod(secret, 0o600)
    print(f"public key: {public}\nsecret key: {secret} (keep it private; reach serve --curve-secret-key {secret})")
    return 0


def add_keys(sub: Any) -> None:
    """Register ``reach keys``."""
    p = sub.add_parser("keys", help="write a CURVE key pair", description="Write a CURVE key pair (ZeroMQ "
        "certificate files NAME.key and NAME.key_secret) for 'reach serve --curve-secret-key' and its clients. See "
        "docs/protocol.md.")
    p.add_argument("folder", help="folder to write the two files into")
    p.add_argument("--name", default="server", help="base name of the files (default: server)")
    p.set_defaults(func=cmd_keys)


def cmd_view(args: argparse.Namespace) -> int:
    # loaded when the command runs: `reach --help` starts without the answers' machinery
    from reach.maps.atlas import load_atlas

    try:
        # loaded when the command runs: `reach --help` starts without the answers' machinery
        from reach.tools.view import Viewer
    except ImportError as exc:  # viser is an extra
        raise ReachError(f"reach view needs viser: pip install 'reach-volumes[view]' ({exc})") from exc
    from reach.building.population import is_population

    accommodation = None
    if any(is_population(a) for a in args.atlas):
        from reach.answers.accommodation import ANY, load_members, shares
        from reach.tools.accommodation_report import VIEW_LEVEL, grid

        if len(args.atlas) != 1:
            raise InputError("atlas", "a population folder is viewed alone (its first member's body and volumes, "
                                      "with the population's accommodation)")
        members, weights, _ = load_members(args.atlas[0])
        _, points = grid(members, VIEW_LEVEL)
        accommodation = (points, shares(members, weights, points)[ANY])
        atlases = members[:1]
    else:
        atlases = [load_atlas(a) for a in args.atlas]
    viewer = Viewer(atlases, host=args.host, port=args.port, connect=args.connect,
                    spacing=args.spacing, policy=args.policy, refine=not args.no_refine, accommodation=accommodation)
    print(f"viewing {', '.join(args.atlas)} at {viewer.url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    return 0


def add_view(sub: Any) -> None:
    """Register ``reach view``."""
    p = sub.add_parser(
        "view", help="interactive 3-D view in the browser",
        description="Serve a 3-D view of one or more atlases (viser): volumes per strategy, the body, and a goal to "
                    "drag whose answer (strategy, posture) is shown. Open the printed address in a browser; the page "
                    "works offline.",
    )
    p.add_argument("atlas", nargs="+", help="atlas folder(s); several stand side by side (a population study); or one "
                                            "population folder: its first member, and the population's accommodation "
                                            "as dots coloured by the share of members whose trees hold each point")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--connect", metavar="ADDR", help="take answers from a running 'reach serve' at ADDR, e.g. "
                                                     "tcp://127.0.0.1:5555")
    p.add_argument("--spacing", type=float, default=1.5, help="distance between atlases along y [m] (default 1.5)")
    policy_option(p)
    p.add_argument("--no-refine", action="store_true", help="show stored postures; no IK refinement")
    p.set_defaults(func=cmd_view)


# Each registers its command's subparser.
COMMANDS = (add_serve, add_keys, add_view)
