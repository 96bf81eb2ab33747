"""Attacks on ``reach serve``, each beside a victim; prints JSON lines.

Every attack runs against a fresh server (``--workers`` 1 and 2 by default) on a small human atlas (bench/server.py's)
while a victim process asks for stored postures without pause. Each line gives the attack's own outcome, the victim's
p99 and longest wait [ms] and its lost requests (no reply in 2.5 s), and the server process's largest resident memory
[MB] (its workers apart). Where work was accepted, ``workers_free_ms`` is how long after the last reply the server's
workers were all idle again (``health``'s ``workers_busy``):

* ``crash``: ``{"op":"health","id":1e999}`` 48 times, then ``health`` (the server must still answer);
* ``deadlines``: six DEALER clients send 10,000-goal refined batches with 0.5 s deadlines: each reply's time past its
  deadline, and its code;
* ``accepted``: the same with 3.5 s deadlines, which the server accepts: each reply's time past its deadline;
* ``place``: 1,681 candidates x 1,000 targets near the body: the reply, and how long after it the worker answers a
  refined query;
* ``place_deadline``: the same layout 0.4 m wide at a 1 cm step with a 0.3 s deadline (a second's work): the reply's
  time past the deadline;
* ``place_identical``: 1,000 identical targets over 1,681 candidates: the reply and its time;
* ``place_too_large``: a ``place`` over its size sent while a 10,000-goal batch holds the workers: its reply's time;
* ``memory``: 100 clients each send 16 requests of about 1 MiB;
* ``accommodation``: a server with a population of 100 members (the atlas 100 times); 20 clients each send 10
  ``accommodation`` requests at its limit (1,000 goals x 200 trees) at once;
* ``heavy``: ``cells`` at level 6, stored 1,000-goal batches, 1 MiB requests of 80,000 unknown keys, 20 of each;
* ``busy_machine``: two CPU-bound processes beside the server; 20 single refined queries: their outcomes and times;
* ``fairness``: one client's 3,000-goal refined batch; another's 20 single refined queries: outcomes and times;
* ``files``: bad files given to ``reach serve --population`` and ``reach model`` (population manifests nested, without
  a name, with weights of 10^400, Infinity, 1e999 or 1e308, a 5,000-character name, a FIFO, a link to /dev/zero; YAML
  numbers of 4,301 and 400 digits (a depth, a dimension); masses of 0 and -13 kg; a population's negative dimension;
  URDFs with a 40,000-character mesh path, 100,000 nested elements, an external DTD, a parameter entity): exit code,
  stderr lines, time and peak memory, each limited to 10 s.

Run: ``.venv/bin/python bench/attacks.py [--workers 1 2] [--only NAME ...] [--hogs 2]`` (``--hogs``: CPU-bound
processes beside the whole run). Traffic goes to 127.0.0.1 only, in bounded loops.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
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


def health(sock: zmq.Socket) -> dict[str, Any]:  # type: ignore[type-arg]
    _, reply = ask(sock, {"op": "health"}, 10_000)
    assert reply is not None, "the server did not answer health"
    return reply


def workers_free(address: str, since: float, seconds: float = 60.0) -> float | None:
    """Milliseconds from ``since`` until the server's workers are all idle (health polled every 10 ms); None from a
    server whose ``health`` does not say (before ``workers_busy``)."""
    sock = dealer(address)
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            busy = health(sock).get("workers_busy")
            if busy is None:
                return None
            if not busy:
                break
            time.sleep(0.01)
    finally:
        sock.close()
    return round(1e3 * (time.perf_counter() - since), 1)


def batches(address: str, deadline: float) -> dict[str, Any]:
    """Six clients' 10,000-goal refined batches with ``deadline``: each reply's time past it, and its code."""
    socks = [dealer(address) for _ in range(6)]
    sent = []
    for k, sock in enumerate(socks):
        sent.append(time.perf_counter())
        sock.send_multipart([b"", json.dumps({"op": "query", "id": k, "effector": "right_hand", "goals": GOALS,
                                              "deadline": deadline}).encode()])
    late, codes = [], []
    for k, sock in enumerate(socks):
        if sock.poll(60_000):
            reply = sock.recv_multipart()[-1]
            late.append(time.perf_counter() - sent[k] - deadline)
            codes.append(code_of(reply))
        sock.close()
    return {"replies": {c: codes.count(c) for c in set(codes)}, "past_deadline_max_ms": round(1e3 * max(late), 1),
            "past_deadline_median_ms": round(1e3 * float(np.median(late)), 1),
            "workers_free_ms": workers_free(address, time.perf_counter())}


def deadlines(address: str) -> dict[str, Any]:
    return batches(address, 0.5)


def accepted(address: str) -> dict[str, Any]:
    return batches(address, 3.5)


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


def layout(identical: bool = False) -> list[dict[str, Any]]:
    """1,000 targets near the body's right hand: a grid 9 cm x 10 cm, or one point 1,000 times."""
    return [{"point": [0.35, -0.25, 1.1] if identical else [0.35 + 0.01 * (k % 10), -0.25, 1.1 + 0.01 * (k // 100)],
             "effector": "right_hand"} for k in range(1000)]


def place_deadline(address: str) -> dict[str, Any]:
    sock = dealer(address)
    t0 = time.perf_counter()
    took, reply = ask(sock, {"op": "place", "targets": layout(), "x": [-0.2, 0.2], "y": [-0.2, 0.2], "yaw": [0, 0],
                             "step": 0.01, "deadline": 0.3}, 120_000)
    sock.close()
    return {"reply": None if reply is None else ("ok" if reply["ok"] else reply["error"]["code"]),
            "past_deadline_ms": round(1e3 * (took - 0.3), 1),
            "workers_free_ms": _less(workers_free(address, t0), 300.0)}


def _less(value: float | None, by: float) -> float | None:
    return None if value is None else round(value - by, 1)


def place_identical(address: str) -> dict[str, Any]:
    sock = dealer(address)
    took, reply = ask(sock, {"op": "place", "targets": layout(identical=True), "x": [-0.2, 0.2], "y": [-0.2, 0.2],
                             "yaw": [0, 0], "step": 0.01, "deadline": 30}, 120_000)
    sock.close()
    return {"reply": None if reply is None else ("ok" if reply["ok"] else reply["error"]["code"]),
            "reply_s": round(took, 2)}


def place_too_large(address: str) -> dict[str, Any]:
    batch = dealer(address)
    batch.send_multipart([b"", json.dumps({"op": "query", "effector": "right_hand", "goals": GOALS,
                                           "deadline": 3.5}).encode()])
    time.sleep(0.3)
    sock = dealer(address)
    took, reply = ask(sock, {"op": "place", "targets": layout(), "x": [-1.0, 1.0], "y": [-1.0, 1.0], "yaw": [0, 0],
                             "step": 0.01}, 120_000)
    batch.poll(60_000)
    sock.close()
    batch.close()
    return {"reply": None if reply is None else ("ok" if reply["ok"] else reply["error"]["code"]),
            "reply_ms": round(1e3 * took, 1)}


def flood(address: str, payload: bytes, clients: int, each: int) -> dict[str, int]:
    """``clients`` DEALERs each send ``payload`` ``each`` times at once; the replies' codes, counted."""
    socks = [dealer(address) for _ in range(clients)]
    for sock in socks:
        for _ in range(each):
            sock.send_multipart([b"", payload], copy=False)
    codes = []
    for sock in socks:
        for _ in range(each):
            if sock.poll(30_000):
                codes.append(code_of(sock.recv_multipart()[-1]))
        sock.close()
    return {c: codes.count(c) for c in set(codes)}


def memory(address: str) -> dict[str, Any]:
    payload = b'{"op": "health", "pad": "' + b"x" * ((1 << 20) - 64) + b'"}'  # refused (unknown field) once read
    return {"requests": 1600, "replies": flood(address, payload, 100, 16)}


def accommodation(address: str) -> dict[str, Any]:
    request = json.dumps({"op": "accommodation", "effector": "right_hand", "goals": GOALS[:1000]}).encode()
    t0 = time.perf_counter()
    replies = flood(address, request, 20, 10)
    return {"requests": 200, "replies": replies, "all_answered_s": round(time.perf_counter() - t0, 2)}


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
    "crash": crash, "deadlines": deadlines, "accepted": accepted, "place": place, "place_deadline": place_deadline,
    "place_identical": place_identical, "place_too_large": place_too_large, "memory": memory,
    "accommodation": accommodation, "heavy": heavy, "busy_machine": busy_machine, "fairness": fairness,
}
MEMBERS = 100  # the accommodation attack's population: the atlas this many times


def run(atlas: Path, workers: int, name: str, hogs: int = 0) -> None:
    extra = ["--population", str(atlas.parent / "population")] if name == "accommodation" else []
    server, address = base.serve(atlas, workers, *extra)
    try:
        base._workers_ready(address, workers)
        ctx = mp.get_context("spawn")
        stop, out, started = ctx.Event(), ctx.Queue(), ctx.Event()
        victim = ctx.Process(target=base.watch, args=(address, server.pid, stop, out, 2.5, started))
        victim.start()
        started.wait(60)  # its interpreter up (seconds beside the hogs) and its first query answered
        time.sleep(0.2)
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
    parser.add_argument("--only", nargs="+", choices=[*ATTACKS, "files"], help="these attacks only")
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
        population(atlas, Path(tmp) / "population")
        for workers in args.workers:
            for name in [n for n in args.only or list(ATTACKS) if n != "files"]:
                run(atlas, workers, name, args.hogs)
        if not args.only or "files" in args.only:
            files(atlas)


# Runs a command with a 10 s limit and prints its exit code, its stderr's lines, its time and its peak memory (the
# largest of its process tree's waited processes).
RUN = """
import json, resource, subprocess, sys, time
t = time.perf_counter()
try:
    done = subprocess.run(sys.argv[1:], capture_output=True, text=True, timeout=10)
    code, err = done.returncode, done.stderr
except subprocess.TimeoutExpired as exc:
    code, err = "timeout", (exc.stderr or b"").decode(errors="replace")
lines = [x for x in err.splitlines() if x.strip()]
print(json.dumps({"exit": code, "lines": len(lines), "first": lines[0][:160] if lines else "",
                  "seconds": round(time.perf_counter() - t, 2),
                  "rss_mb": round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1)}))
"""


def file_cases(tmp: Path, atlas: Path) -> dict[str, list[str]]:
    """Files a user or an attacker hands the CLI: each case's command line (the file written here)."""
    reach = [sys.executable, "-m", "reach.tools.cli"]
    cases: dict[str, list[str]] = {}
    doc = {"format": 1, "name": "p", "members": [{"name": "m0", "atlas": "m0", "sex": "male", "weight": 1.0}]}
    members = {
        "nested": "[" * 100_000 + "]" * 100_000,
        "no_name": json.dumps({**doc, "members": [{"atlas": "m0", "sex": "male", "weight": 1.0}]}),
        "weight_10e400": json.dumps(doc).replace("1.0", "1" + "0" * 400),
        "weight_infinity": json.dumps(doc).replace("1.0", "Infinity"),
        "weight_1e999": json.dumps(doc).replace("1.0", "1e999"),
        "weight_1e308": json.dumps(doc).replace("1.0", "1e308"),
        "name_5000": json.dumps(doc).replace('"name": "m0"', '"name": "' + "m" * 5000 + '"'),
    }
    for name, text in {**members, "fifo": "", "dev_zero": ""}.items():
        folder = tmp / f"population_{name}"
        folder.mkdir()
        (folder / "m0").symlink_to(atlas)
        manifest = folder / "population.json"
        if name == "fifo":
            os.mkfifo(manifest)
        elif name == "dev_zero":
            manifest.symlink_to("/dev/zero")
        else:
            manifest.write_text(text)
        cases[f"population_{name}"] = [*reach, "serve", str(atlas), "--population", str(folder), "--workers", "0",
                                       "--bind", "tcp://127.0.0.1:*", "--pub", "none"]
    base_config = f"base: {Path(__file__).resolve().parent.parent / 'configs' / 'human.yaml'}\n"
    configs = {
        "yaml_4301_digits": "depth: {min: 1, max: " + "9" * 4301 + "}\n",
        "dimension_400_digits": "body: {human: {acromialheight: 1" + "0" * 400 + ".5}}\n",
        "mass_0": "body: {human: {mass: 0}}\n",
        "mass_minus_13": "body: {human: {mass: -13}}\n",
        "population_acromialheight_minus_1": "population: {ansur: {n: 2, seed: 0}}\n"
                                             "body: {human: {acromialheight: -1}}\n",
    }
    for name, text in configs.items():
        path = tmp / f"{name}.yaml"
        path.write_text(base_config + text)
        cases[name] = [*reach, "model", str(path)]
    joint = ('<link name="a"/><link name="b"><collision><geometry><mesh filename="{mesh}"/></geometry></collision>'
             '</link>'
             '<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
             '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>')
    urdfs = {
        "urdf_mesh_path_40000": '<robot name="r">' + joint.format(mesh="m" * 40_000 + ".stl") + "</robot>",
        "urdf_nested": '<robot name="r">' + "<a>" * 100_000 + "</a>" * 100_000 + "</robot>",
        "urdf_external_dtd": '<?xml version="1.0"?><!DOCTYPE robot SYSTEM "file:///etc/hostname"><robot name="r">'
                             + joint.format(mesh="x.stl") + "</robot>",
        "urdf_parameter_entity": '<?xml version="1.0"?><!DOCTYPE robot [<!ENTITY % p SYSTEM "file:///etc/hostname"> '
                                 '%p;]><robot name="r">' + joint.format(mesh="x.stl") + "</robot>",
    }
    for name, text in urdfs.items():
        path = tmp / f"{name}.urdf"
        path.write_text(text)
        cases[name] = [*reach, "model", str(path)]
    return cases


def files(atlas: Path) -> None:
    """Each file case (``file_cases``): its exit code (2 expected), stderr lines (1), time and peak memory."""
    with tempfile.TemporaryDirectory() as tmp:
        for name, command in file_cases(Path(tmp), atlas).items():
            got = json.loads(subprocess.run([sys.executable, "-c", RUN, *command], capture_output=True, text=True,
                                            check=True).stdout)
            base.emit(bench="attack_file", case=name, **got)


def population(atlas: Path, folder: Path) -> None:
    """A population folder whose MEMBERS members are all ``atlas`` (links to it)."""
    folder.mkdir()
    members = []
    for k in range(MEMBERS):
        (folder / f"m{k}").symlink_to(atlas)
        members.append({"name": f"m{k}", "atlas": f"m{k}", "sex": "male", "weight": 1.0})
    (folder / "population.json").write_text(json.dumps({"format": 1, "name": "attacks", "members": members}))


if __name__ == "__main__":
    main()
