"""How deep one refined query goes: the project's calls from the server's socket to the solver's step.

A server without workers (the loop refines) answers one refined query from a client; at the first batched step
(``oracles.ik.batch.run_starts``) the stack is read. Printed as one JSON line: the project's frames from the
socket's poll to the step (``calls``), the files they lie in, how often the stack moves from one file to another
(``switches``) and the frames themselves. Usage::

    python bench/calls.py [ATLAS] [--effector right_hand] [--goal X Y Z]
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import oracles.ik.batch as batch  # noqa: E402
from reach.serving.client import Client  # noqa: E402
from reach.serving.server import Server  # noqa: E402

PACKAGES = ("reach", "oracles")


def ours(filename: str) -> str | None:
    """A frame's file relative to the repository when it is the project's own (reach/, oracles/), else None."""
    path = Path(filename).resolve()
    try:
        rel = path.relative_to(ROOT)
    except ValueError:
        return None
    return str(rel) if rel.parts and rel.parts[0] in PACKAGES else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas", nargs="?", default="out/demo")
    parser.add_argument("--effector", default="right_hand")
    parser.add_argument("--goal", nargs=3, type=float, default=[0.45, -0.25, 1.2])
    args = parser.parse_args()

    seen: list[list[tuple[str, int, str]]] = []
    real = batch.run_starts

    def traced(*a, **k):  # type: ignore[no-untyped-def]
        if not seen:
            stack = traceback.extract_stack()[:-1]
            seen.append([(f, s.lineno or 0, s.name) for s in stack if (f := ours(s.filename))])
        return real(*a, **k)

    server = Server(args.atlas, "tcp://127.0.0.1:*", None, workers=0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        with Client(server.endpoint, timeout=120_000) as client:
            client.query(args.effector, args.goal)  # the solvers built and compiled: not this measure's
            for mod in [m for m in sys.modules.values() if getattr(m, "run_starts", None) is real]:
                mod.run_starts = traced  # type: ignore[attr-defined]
            reply = client.query(args.effector, [g + 1e-3 for g in args.goal])
    finally:
        server.stop()
        thread.join(timeout=10)
    if not seen:
        print(json.dumps({"error": "no batched step was taken", "reply": reply}))
        return
    frames = seen[0]
    start = next((k for k, (f, _, _) in enumerate(frames) if f.startswith("reach/serving/")), 0)
    frames = frames[start:]
    files = [f for f, _, _ in frames]
    switches = sum(1 for a, b in zip(files, files[1:], strict=False) if a != b)
    print(json.dumps({"bench": "calls", "atlas": args.atlas, "calls": len(frames),
                      "files": len(dict.fromkeys(files)), "switches": switches,
                      "files_entered_twice": sorted({f for f in files if sum(1 for k in range(len(files))
                                                     if files[k] == f and (k == 0 or files[k - 1] != f)) > 1}),
                      "refined": reply.get("refined") if isinstance(reply, dict) else None,
                      "frames": [f"{f}:{n} {name}" for f, n, name in frames]}, default=str))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
