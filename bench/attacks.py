"""Attacks on ``reach serve``, each beside a victim; prints JSON lines.

Every attack runs against a fresh server (``--workers`` 1 and 2 by default) on a small human atlas (bench/server.py's)
while a victim process asks for stored postures without pause. Each line gives the attack's own outcome, the victim's
p99 and longest wait [ms] and its lost requests (no reply in 5 s), and the server process's largest resident memory
[MB] (its workers apart):

* ``crash``: ``{"op":"health","id":1e999}`` 48 times, then ``health`` (the server must still answer);
* ``deadlines``: six DEALER clients send 10,000-goal refined batches with 0.5 s deadlines: each reply's time past its
  deadline, and its code;
* ``place``: 1,681 candidates x 1,000 targets near the body: the reply, and how long after it the worker answers a
  refined query;
* ``memory``: 100 clients each send 16 requests of about 1 MiB;
* ``heavy``: ``cells`` at level 6, stored 1,000-goal batches, 1 MiB requests of 80,000 unknown keys, 20 of each;
* ``busy_machine``: two CPU-bound processes beside the server; 20 single refined queries: their outcomes and times;
* ``fairness``: one client's 3,000-goal refined batch; another's 20 single refined queries: outcomes and times.

Run: ``.venv/bin/python bench/attacks.py [--workers 1 2] [--only NAME ...] [--hogs 2]`` (``--hogs``: CPU-bound
processes beside the whole run). Traffic goes to 127.0.0.1 only, in bounded loops.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zmq

sys.path.insert(0, str(Path(__file__).parent))
import server as base  # noqa: E402  (bench/server.py: the atlas, the server process, the victim)

from reach.building.atlas import build_atlas  # noqa: E402
from reach.building.config import parse_config  # noqa: E402

GOALS = np.random.default_rng(46).uniform([0.1, -0.6, 0.9], [0.6, 0.0, 1.6], (10_000, 3)).round(4).tolist()
HOG = "import time\nend = time.time() + 120\nwhile time.time() < end: pass\n"


def dealer(address: str) -> zmq.Socket:  # type: ignore[type-arg]
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    return sock


def code_of(reply: bytes) -> str:
    data = json.loads(reply)
    return "ok" if data.get("ok") else data["error"]["code"]


def ask(sock: zmq.Socket, request: dict[str, Any], timeout_ms: int = 30_000) -> tuple[float, dict[str, Any] | None]:  # type: ignore[type-arg]
    t0 = time.perf_counter()
    sock.send_multipart([b"", json.dumps(request).encode()])
    if not sock.poll(timeout_ms):
        return time.perf_counter() - t0, None
    return time.perf_counter() - t0, json.loads(sock.recv_multipart()[-1])


def crash(address: str) -> dict[str, Any]:
    sock = dealer(address)
    for _ in range(48):
        sock.send_multipart([b"", b'{"op":"health","id":1e999}'])
    codes = []
    while len(codes) < 48 and sock.poll(5000):  # a dead server answers no more
        codes.append(code_of(sock.recv_multipart()[-1]))
    _, health = ask(sock, {"op": "health"}, 5000)
    sock.close()
    return {"replies": {c: codes.count(c) for c in set(codes)}, "health_after": health is not None}


def deadlines(address: str) -> dict[str, Any]:
    socks = [dealer(address) for _ in range(6)]
    sent = []
    for k, sock in enumerate(socks):
        sent.append(time.perf_counter())
        sock.send_multipart([b"", json.dumps({"op": "query", "id": k, "effector": "right_hand", "goals": GOALS,
                                              "deadline": 0.5}).encode()])
    late, codes = [], []
    for k, sock in enumerate(socks):
        if sock.poll(60_000):
            reply = sock.recv_multipart()[-1]
            late.append(time.perf_counter() - sent[k] - 0.5)
            codes.append(code_of(reply))
        sock.close()
    return {"replies": {c: codes.count(c) for c in set(codes)}, "past_deadline_max_ms": round(1e3 * max(late), 1),
            "past_deadline_median_ms": round(1e3 * float(np.median(late)), 1)}


def place(address: str) -> dict[str, Any]:
    sock = dealer(address)
    targets = [{"point": [0.35 + 0.01 * (k % 10), -0.25, 1.1 + 0.01 * (k // 100)], "effector": "right_hand"}
               for k in range(1000)]
    took, reply = ask(sock, {"op": "place", "targets": targets, "x": [-1.0, 1.0], "y": [-1.0, 1.0], "yaw": [0, 0],
                             "step": 0.05}, 120_000)
    after, refined = ask(sock, {"op": "query", "effector": "right_hand", "goal": [0.4, -0.3, 1.1]}, 120_000)
    sock.close()
    return {"reply": None if reply is None else ("ok" if reply["ok"] else reply["error"]["code"]),
            "reply_s": round(took, 2), "next_refined_s": round(after, 3),
            "next_refined": None if refined is None else refined.get("refined")}


def memory(address: str) -> dict[str, Any]:
    payload = b'{"op": "health", "pad": "' + b"x" * ((1 << 20) - 64) + b'"}'  # refused (unknown field) once read
    socks = [dealer(address) for _ in range(100)]
    for sock in socks:
        for _ in range(16):
            sock.send_multipart([b"", payload], copy=False)
    answered = 0
    for sock in socks:
        for _ in range(16):
            if sock.poll(30_000):
                sock.recv_multipart()
                answered += 1
        sock.close()
    return {"requests": 1600, "answered": answered}


def heavy(address: str) -> dict[str, Any]:
    sock = dealer(address)
    unknown = {"op": "health", **{f"k{i}": 0 for i in range(80_000)}}
    requests = ([{"op": "cells", "level": 6}] * 20
                + [{"op": "query", "effector": "right_hand", "goals": GOALS[:1000], "refine": False}] * 20
                + [unknown] * 20)
    times: dict[str, list[float]] = {"cells": [], "stored_1000": [], "unknown_keys": []}
    for request, kind in zip(requests, ["cells"] * 20 + ["stored_1000"] * 20 + ["unknown_keys"] * 20, strict=True):
        took, _ = ask(sock, request)
        times[kind].append(took)
    sock.close()
    return {f"{k}_max_ms": round(1e3 * max(v), 1) for k, v in times.items()}


def refined_singles(address: str, count: int = 20) -> dict[str, Any]:
    sock = dealer(address)
    rng = np.random.default_rng(7)
    took, outcomes = [], []
    for goal in rng.uniform([0.2, -0.5, 1.0], [0.5, -0.1, 1.4], (count, 3)).round(3).tolist():
        t, reply = ask(sock, {"op": "query", "effector": "right_hand", "goal": goal}, 30_000)
        took.append(t)
        outcomes.append("lost" if reply is None else reply.get("refined", reply.get("error", {}).get("code")))
    sock.close()
    return {"outcomes": {o: outcomes.count(o) for o in set(outcomes)},
            "median_ms": round(1e3 * float(np.median(took)), 1), "max_ms": round(1e3 * max(took), 1)}


def busy_machine(address: str) -> dict[str, Any]:
    hogs = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(2)]
    try:
        time.sleep(1.0)
        return refined_singles(address)
    finally:
        for h in hogs:
            h.kill()
            h.wait()


def fairness(address: str) -> dict[str, Any]:
    batch = dealer(address)
    batch.send_multipart([b"", json.dumps({"op": "query", "id": "big", "effector": "right_hand",
                                           "goals": GOALS[:3000], "deadline": 600}).encode()])
    time.sleep(0.2)
    out = refined_singles(address)
    batch.close()
    return out


ATTACKS: dict[str, Callable[[str], dict[str, Any]]] = {
    "crash": crash, "deadlines": deadlines, "place": place, "memory": memory, "heavy": heavy,
    "busy_machine": busy_machine, "fairness": fairness,
}


def run(atlas: Path, workers: int, name: str, hogs: int = 0) -> None:
    server, address = base.serve(atlas, workers)
    try:
        base._workers_ready(address, workers)
        ctx = mp.get_context("spawn")
        stop, out = ctx.Event(), ctx.Queue()
        victim = ctx.Process(target=base.watch, args=(address, server.pid, stop, out))
        victim.start()
        time.sleep(0.5)
        try:
            result = ATTACKS[name](address)
        finally:
            stop.set()
            waits, lost, rss = out.get(timeout=120)
            victim.join()
        lat = np.array(waits) * 1e3
        base.emit(bench="attack", attack=name, workers=workers, hogs=hogs, **result,
                  victim_p99_ms=round(float(np.percentile(lat, 99)), 2) if len(lat) else None,
                  victim_max_ms=round(float(lat.max()), 1) if len(lat) else None, victim_lost=lost,
                  server_rss_max_mb=round(rss / 2**20, 1), alive=server.poll() is None)
    finally:
        server.terminate()
        server.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--only", nargs="+", choices=list(ATTACKS), help="these attacks only")
    parser.add_argument("--hogs", type=int, default=0, help="CPU-bound processes kept running beside the whole run")
    args = parser.parse_args()
    hogs = [subprocess.Popen([sys.executable, "-c", HOG.replace("120", "3600")]) for _ in range(args.hogs)]
    try:
        attack_all(args)
    finally:
        for h in hogs:
            h.kill()
            h.wait()


def attack_all(args: argparse.Namespace) -> None:
    base.emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
              pyzmq=zmq.__version__)
    with tempfile.TemporaryDirectory() as tmp:
        atlas = Path(tmp) / "atlas"
        build_atlas(parse_config(base.CONFIG, "bench", "bench"), atlas)
        for workers in args.workers:
            for name in args.only or list(ATTACKS):
                run(atlas, workers, name, args.hogs)


if __name__ == "__main__":
    main()
