"""Server benchmarks; prints JSON lines.

* Round-trip latency (median, p99) of single-goal queries from one REQ
  client: with the stored posture (``refine: false``) and with IK refinement.
* The same for a bare pyzmq ROUTER echo server answering with a message of
  the size of the server's reply: the floor on this machine. Requests to the
  two alternate, so that both see the same machine noise.
* Throughput with 1, 4 and 16 concurrent clients (stored postures).
* A query with the default options (refinement on) of an analytic atlas,
  which needs no IK, from a server with 2 workers, against the echo in the
  same run: such a query never leaves the server's loop.
* With refinement workers (``--workers``): the stored-posture p99 while 2
  clients ask for refined postures; a client's single refined queries alone
  and while another client's 10,000-goal refined batch runs (fairness); ``health`` behind a 2,000-goal refined
  batch; refined throughput with 1 and 2 workers; a 10,000-goal refined
  batch; the time SIGTERM takes to stop a server in the middle of a refined
  batch.
* Stored-posture latency while a client reloads the atlas again and again
  (``--allow-reload``): the load runs in the background.

The atlas is a small human atlas (right arm and upper body, D_max 3) built
in a temporary folder. Servers run in their own processes.

Run: ``.venv/bin/python bench/server.py [--requests N]``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from reach.building.atlas import build_atlas
from reach.building.config import parse_config

ARM = ["right_shoulder_*", "right_elbow_*", "right_forearm_*", "right_wrist_*"]
CONFIG = {
    "body": {"human": {"sex": "male", "percentile": 50}},
    "box": {"min": [-0.5, -1.0, 0.6], "max": [0.9, 0.4, 2.1]}, "depth": {"min": 1, "max": 3},
    "oracle": {"name": "casadi-ik", "params": {"restarts": 1, "secondary": False}},
    "strategies": [
        {"name": "right_arm", "effector": "right_hand", "priority": 1, "joints": ARM, "tasks": [{"type": "reach"}]},
        {"name": "right_upper_body", "effector": "right_hand", "priority": 2,
         "joints": [*ARM, "right_clavicle_*", "lumbar_*", "thoracic_*", "neck_*"], "tasks": [{"type": "reach"}]},
    ],
}

SPHERE = {
    "box": {"min": [-1, -1, -1], "max": [1, 1, 1]}, "depth": {"min": 2, "max": 6},
    "oracle": {"name": "sphere", "params": {"radius": 0.9}},
    "strategies": [{"name": "sphere", "effector": "point", "priority": 1}],
}

ECHO = """
import sys, zmq
ctx = zmq.Context(); s = ctx.socket(zmq.ROUTER); s.bind("tcp://127.0.0.1:*")
print(s.getsockopt(zmq.LAST_ENDPOINT).decode(), flush=True)
reply = b"x" * int(sys.argv[1])
while True:
    frames = s.recv_multipart()
    s.send_multipart(frames[:-1] + [reply])
"""


REFINER = """
import json, sys, numpy as np, zmq
sock = zmq.Context().socket(zmq.REQ); sock.connect(sys.argv[1])
goals = np.random.default_rng(int(sys.argv[2])).uniform([0.1, -0.6, 0.9], [0.6, 0.0, 1.6], (1000, 3))
i = 0
while True:
    sock.send(json.dumps({"op": "query", "effector": "right_hand", "goal": goals[i % 1000].tolist()}).encode())
    sock.recv()
    i += 1
"""


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def start(cmd: list[str]) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()  # type: ignore[union-attr]
    address = line.split(" on ")[1].split(",")[0].strip() if " on " in line else line.strip()
    return proc, address


def latencies(addresses: list[str], payloads: list[bytes]) -> list[np.ndarray]:
    """Round trips to each address, interleaved request by request so that all see the same machine noise."""
    socks = []
    for address in addresses:
        sock = zmq.Context.instance().socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(address)
        socks.append(sock)
    for p in payloads[:50]:  # warm up
        for sock in socks:
            sock.send(p)
            sock.recv()
    out: list[list[float]] = [[] for _ in socks]
    for p in payloads:
        for sock, times in zip(socks, out, strict=True):
            t0 = time.perf_counter()
            sock.send(p)
            sock.recv()
            times.append(time.perf_counter() - t0)
    for sock in socks:
        sock.close()
    return [np.array(t) for t in out]


def throughput(address: str, payloads: list[bytes], clients: int, seconds: float = 3.0) -> float:
    counts = [0] * clients
    stop = time.perf_counter() + seconds

    def run(k: int) -> None:
        sock = zmq.Context.instance().socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(address)
        i = 0
        while time.perf_counter() < stop:
            sock.send(payloads[i % len(payloads)])
            sock.recv()
            i += 1
        counts[k] = i
        sock.close()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(clients)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(counts) / (time.perf_counter() - t0)


def stats(name: str, lat: np.ndarray, **extra: object) -> dict[str, float]:
    med, p99 = float(np.median(lat)) * 1e3, float(np.percentile(lat, 99)) * 1e3
    emit(bench="latency", case=name, requests=len(lat), median_ms=round(med, 4), p99_ms=round(p99, 4), **extra)
    return {"median": med, "p99": p99}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=3000)
    parser.add_argument("--chunk", type=int, default=None, help="the servers' --chunk (goals per worker task; "
                                                                "default: the server's)")
    parser.add_argument("--only", choices=["workers", "attacks"], help="run only the benchmarks with workers, or "
        "only the attacks")
    args = parser.parse_args()
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         pyzmq=zmq.__version__)
    with tempfile.TemporaryDirectory() as tmp:
        atlas = Path(tmp) / "atlas"
        build_atlas(parse_config(CONFIG, "bench", "bench"), atlas)
        rng = np.random.default_rng(0)
        goals = rng.uniform([0.1, -0.6, 0.9], [0.6, 0.0, 1.6], (args.requests, 3))
        stored = [json.dumps({"op": "query", "id": i, "effector": "right_hand", "goal": g.tolist(),
                              "refine": False}).encode() for i, g in enumerate(goals)]
        refined = [json.dumps({"op": "query", "id": i, "effector": "right_hand", "goal": g.tolist(),
                               "refine": True}).encode() for i, g in enumerate(goals)]
        CHUNK[:] = [] if args.chunk is None else ["--chunk", str(args.chunk)]
        if args.only is None:
            one_server_bench(atlas, stored, refined, args.requests)
            analytic_bench(Path(tmp) / "sphere", args.requests)
            reload_bench(atlas, stored)
        if args.only != "attacks":
            workers_bench(atlas, goals, stored)
        for workers in (1, 0):
            attacks_bench(atlas, workers)
        overrun_bench(atlas)
        heavy_bench(atlas)


def one_server_bench(atlas: Path, stored: list[bytes], refined: list[bytes], requests: int) -> None:
    """Stored and refined latency against the echo, and throughput, from one server with its default workers."""
    server, address = start([sys.executable, "-m", "reach.tools.cli", "serve", str(atlas), "--bind",
                             "tcp://127.0.0.1:*", "--pub", "tcp://127.0.0.1:*", "--budget-ms", "20"])
    echo = None
    try:
        _ready(address)  # the workers have loaded the atlas: nothing else runs while we measure
        echo, echo_address, reply_size = echo_beside(address, stored[0])
        lat, lat_echo = latencies([address, echo_address], stored)
        s = stats("stored_posture", lat, request_bytes=len(stored[0]), reply_bytes=reply_size)
        e = stats("echo", lat_echo, reply_bytes=reply_size)
        r = stats("refined", latencies([address], refined[: max(200, requests // 5)])[0])
        for n in (1, 4, 16):
            emit(bench="throughput", clients=n, requests_per_s=round(throughput(address, stored, n)))
        emit(bench="throughput", clients=1, case="echo", requests_per_s=round(throughput(echo_address, stored, 1)))
    finally:
        for proc in (server, echo):
            if proc is not None:
                proc.terminate()
                proc.wait()
    emit(bench="goals", stored_p99_over_echo_p99=round(s["p99"] / e["p99"], 3), stored_p99_ms=round(s["p99"], 4),
         refined_p99_ms=round(r["p99"], 4))


def analytic_bench(atlas: Path, requests: int) -> None:
    """Default-option queries of an analytic atlas (no IK) from a server with workers, against the echo."""
    build_atlas(parse_config(SPHERE, "sphere", "sphere"), atlas)
    goals = np.random.default_rng(1).uniform(-1, 1, (requests, 3))
    payloads = [json.dumps({"op": "query", "id": i, "effector": "point", "goal": g.tolist()}).encode()
                for i, g in enumerate(goals)]
    server, address = serve(atlas, 2)
    echo = None
    try:
        _workers_ready(address, 2)  # no worker starting up beside the measure
        echo, echo_address, size = echo_beside(address, payloads[0])
        lat, lat_echo = latencies([address, echo_address], payloads)
        a, e = stats("analytic_default_options_2_workers", lat, reply_bytes=size), stats("echo_analytic", lat_echo,
            reply_bytes=size)
        emit(bench="goals", analytic_default_p99_over_echo_p99=round(a["p99"] / e["p99"], 3))
    finally:
        for proc in (server, echo):
            if proc is not None:
                proc.terminate()
                proc.wait()


def reload_bench(atlas: Path, stored: list[bytes]) -> None:
    """Stored answers alone, then while another client reloads the atlas back to back (no workers, so only the load
    competes)."""
    server, address = start([sys.executable, "-m", "reach.tools.cli", "serve", str(atlas), "--bind",
                             "tcp://127.0.0.1:*", "--pub", "none",
                             "--workers", "0", "--no-refine", "--allow-reload", str(atlas.parent)])
    stop = threading.Event()
    took: list[float] = []

    def reload_forever() -> None:
        sock = zmq.Context.instance().socket(zmq.REQ)
        sock.connect(address)
        while not stop.is_set():
            t0 = time.perf_counter()
            sock.send(json.dumps({"op": "reload", "path": atlas.name}).encode())
            assert json.loads(sock.recv())["ok"]
            took.append(time.perf_counter() - t0)
        sock.close(linger=0)

    try:
        alone = stats("stored_alone_no_workers", latencies([address], stored)[0])
        reloader = threading.Thread(target=reload_forever)
        reloader.start()
        during = stats("stored_during_back_to_back_reloads", latencies([address], stored)[0])
        stop.set()
        reloader.join()
        emit(bench="reload", reloads=len(took), reload_median_s=round(float(np.median(took)), 3),
             stored_p99_during_over_alone=round(during["p99"] / alone["p99"], 3))
    finally:
        server.terminate()
        server.wait()


def echo_beside(address: str, payload: bytes) -> tuple[subprocess.Popen, str, int]:
    """A bare echo server whose reply has the size of the server's reply to payload: its process, address and that
    size."""
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.connect(address)
    sock.send(payload)
    size = len(sock.recv())
    sock.close()
    echo, echo_address = start([sys.executable, "-c", ECHO, str(size)])
    return echo, echo_address, size


CHUNK: list[str] = []  # the servers' --chunk option, when given


def serve(atlas: Path, workers: int, *extra: str) -> tuple[subprocess.Popen, str]:
    return start([sys.executable, "-m", "reach.tools.cli", "serve", str(atlas), "--bind", "tcp://127.0.0.1:*",
                  "--pub", "none", "--budget-ms", "20", "--workers", str(workers), *CHUNK, *extra])


def _ready(address: str) -> None:
    """Wait until every worker has loaded the atlas: a refined query answers ok."""
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.connect(address)
    for _ in range(4):
        sock.send(json.dumps({"op": "query", "effector": "right_hand", "goals": [[0.4, -0.3, 1.2]] * 8}).encode())
        sock.recv()
    sock.close(linger=0)


def _workers_ready(address: str, workers: int) -> None:
    """Wait until the server's workers have all loaded the atlas (health's workers_ready)."""
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.connect(address)
    for _ in range(600):
        sock.send(b'{"op": "health"}')
        if json.loads(sock.recv())["workers_ready"] >= workers:
            break
        time.sleep(0.1)
    sock.close(linger=0)


def _idle(address: str, seconds: float = 120.0) -> None:
    """Wait until the server has no pending request (an abandoned batch ran out)."""
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.connect(address)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        sock.send(b'{"op": "health"}')
        if json.loads(sock.recv())["pending"] == 0:
            break
        time.sleep(0.2)
    sock.close(linger=0)


def _batch(address: str, goals: np.ndarray, deadline: float = 3600) -> zmq.Socket:
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    sock.send_multipart([b"",
                         json.dumps({"op": "query", "id": "batch", "effector": "right_hand", "goals": goals.tolist(),
                                     "deadline": deadline}).encode()])
    return sock


def mixed(address: str, stored: list[bytes], workers: int) -> None:
    """Stored answers alone, then while 2 client processes ask for refined postures, from a server with ``workers``."""
    alone = latencies([address], stored[:1000])[0]
    # The refining clients are processes of their own: threads here would
    # share this process's interpreter lock with the client being measured.
    refiners = [subprocess.Popen([sys.executable, "-c", REFINER, address, str(k)]) for k in range(2)]
    time.sleep(1.0)
    loaded = latencies([address], stored[:1000])[0]
    for proc in refiners:
        proc.kill()
        proc.wait()
    a, b = stats(f"stored_alone_{workers}_workers", alone), stats(f"stored_while_2_clients_refine_{workers}_workers",
        loaded)
    emit(bench="goals", workers=workers, mixed_p99_ms=round(b["p99"], 4),
         mixed_over_alone_p99=round(b["p99"] / a["p99"], 3))


def workers_bench(atlas: Path, goals: np.ndarray, stored: list[bytes]) -> None:
    health = json.dumps({"op": "health"}).encode()
    server, address = serve(atlas, 1)
    try:
        _ready(address)
        mixed(address, stored, 1)
    finally:
        server.terminate()
        server.wait()
    server, address = serve(atlas, 2)
    try:
        _ready(address)
        mixed(address, stored, 2)
        refined = [json.dumps({"op": "query", "id": i, "effector": "right_hand", "goal": g.tolist()}).encode()
                   for i, g in enumerate(goals[:300])]
        single_alone = latencies([address], refined)[0]
        huge = _batch(address, np.tile(goals, (1 + 10_000 // len(goals), 1))[:10_000])
        time.sleep(0.5)
        single_behind = latencies([address], refined)[0]
        huge.close(linger=0)  # the batch's client goes away; its work is dropped by its deadline, shared meanwhile
        a1, b1 = stats("refined_single_alone",
                       single_alone), stats("refined_single_during_another_clients_10000_goal_batch", single_behind)
        emit(bench="goals", fair_p99_over_alone_p99=round(b1["p99"] / a1["p99"], 3))
        _idle(address)
        big = _batch(address, np.tile(goals, (1 + 2000 // len(goals), 1))[:2000])
        time.sleep(0.2)
        behind = latencies([address], [health] * 50)[0]
        stats("health_behind_2000_goal_refined_batch", behind)
        big.poll(600_000)
        big.close(linger=0)
        t0 = time.perf_counter()
        huge = _batch(address, np.tile(goals, (1 + 10_000 // len(goals), 1))[:10_000])
        huge.poll(600_000)
        reply = json.loads(huge.recv_multipart()[-1])
        huge.close(linger=0)
        outcomes = [x["refined"] for x in reply["answers"]]
        emit(bench="batch", goals=10_000, workers=2, seconds=round(time.perf_counter() - t0, 2),
             refined_ok=outcomes.count("ok"), other={k: outcomes.count(k) for k in set(outcomes) - {"ok"}})
        big = _batch(address, np.tile(goals, (1 + 2000 // len(goals), 1))[:2000])
        time.sleep(0.5)
        t0 = time.perf_counter()
        server.send_signal(15)
        server.wait(timeout=30)
        emit(bench="sigterm_under_refined_batch", seconds=round(time.perf_counter() - t0, 3), status=server.returncode)
        big.close(linger=0)
    finally:
        if server.poll() is None:
            server.kill()
    rates = {}
    for n in (1, 2):
        server, address = serve(atlas, n)
        try:
            _ready(address)
            t0 = time.perf_counter()
            sock = _batch(address, goals[:1000])
            sock.poll(600_000)
            sock.recv_multipart()
            sock.close(linger=0)
            rates[n] = 1000 / (time.perf_counter() - t0)
            emit(bench="refined_throughput", workers=n, goals_per_s=round(rates[n], 1))
        finally:
            server.terminate()
            server.wait()
    emit(bench="goals", refined_throughput_2_over_1=round(rates[2] / rates[1], 3))


def reply_code(reply: bytes) -> str:
    """``ok`` or the error's code, reading a large reply's head only (parsing 13 MB took the watcher's CPU)."""
    if len(reply) > 1 << 16 and reply.find(b'"ok":true', 0, 200) >= 0:
        return "ok"
    found = json.loads(reply)
    return "ok" if found["ok"] else str(found["error"]["code"])


def overrun_bench(atlas: Path, runs: int = 5) -> None:
    """A worker past its request's deadline: a 20 s motion at 240 Hz with a 50 ms deadline, then at once a
    refined query on the only worker; how much longer that query takes than on an idle worker is the time the
    worker went on planning after the deadline (before: about 100 s)."""
    server, address = serve(atlas, 1)
    _workers_ready(address, 1)
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    query = {"op": "query", "effector": "right_hand", "goal": [0.45, -0.25, 1.2], "refine": True}

    def ask(request: dict[str, Any]) -> tuple[float, str]:
        t0 = time.perf_counter()
        sock.send_multipart([b"", json.dumps(request).encode()])
        reply = json.loads(sock.recv_multipart()[-1])
        code = reply["error"]["code"] if not reply["ok"] else reply.get("outcome") or reply.get("refined") or "ok"
        return time.perf_counter() - t0, str(code)

    try:
        idle = float(np.median([ask({**query, "id": k})[0] for k in range(7)]))
        over, codes = [], []
        for k in range(runs):
            motion = {"op": "motion", "id": 100 + k, "effector": "right_hand", "goal": [0.4, -0.3, 1.1], "rate": 240,
                      "timing": {"duration": 20}, "deadline": 0.05}  # 4,800 frames to hold
            _, code = ask(motion)
            codes.append(code)
            after, _ = ask({**query, "id": 200 + k})
            over.append(max(0.0, after - idle))
    finally:
        sock.close(linger=0)
        server.terminate()
        server.wait(timeout=30)
    emit(bench="server_deadline_overrun", motion_replies=codes, idle_refined_ms=round(idle * 1e3, 1),
         overrun_ms_max=round(max(over) * 1e3, 1), overrun_ms=[round(o * 1e3, 1) for o in over])


def heavy_bench(atlas: Path, repeats: int = 10) -> None:
    """Another client's stored queries while one client sends, one after the other, ``repeats``
    placements near their limit (1,000 targets x 1,681 candidates) and then ``repeats`` stored batches of 10,000 goals
    (both answered in the worker): the watcher's median, p99 and longest wait in each phase, and alone."""
    server, address = serve(atlas, 1)
    _workers_ready(address, 1)
    goals = np.random.default_rng(35).uniform([0.1, -0.7, 0.8], [0.6, 0.0, 1.6], (10_000, 3)).round(4).tolist()
    target = {"point": [0.5, -0.2, 1.1], "effector": "right_hand"}
    phases = {"alone": None,
              "place": {"op": "place", "targets": [target] * 1000, "x": [-1.0, 1.0], "y": [-1.0, 1.0], "yaw": [0, 0],
                        "step": 0.05},
              "stored_batch": {"op": "query", "effector": "right_hand", "goals": goals, "refine": False}}
    ctx = mp.get_context("spawn")
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    try:
        for phase, request in phases.items():
            stop, out = ctx.Event(), ctx.Queue()
            watcher = ctx.Process(target=watch, args=(address, server.pid, stop, out))
            watcher.start()
            time.sleep(1.0)
            codes: dict[str, int] = {}
            t0 = time.perf_counter()
            for k in range(repeats if request is not None else 0):
                sock.send_multipart([b"", json.dumps({**request, "id": k}).encode()])
                code = reply_code(sock.recv_multipart()[-1]) if sock.poll(120_000) else "lost"
                codes[code] = codes.get(code, 0) + 1
            if request is None:
                time.sleep(5.0)
            seconds = time.perf_counter() - t0
            stop.set()
            waits, lost, _ = out.get(timeout=60)
            watcher.join()
            lat = np.array(waits) * 1e3
            emit(bench="server_heavy", phase=phase, requests=repeats if request else 0, replies=codes,
                 seconds=round(seconds, 2),
                 watcher_queries=len(waits), watcher_lost=lost, median_ms=round(float(np.median(lat)), 3),
                 p99_ms=round(float(np.percentile(lat, 99)), 3), longest_ms=round(float(lat.max()), 1))
    finally:
        sock.close(linger=0)
        server.terminate()
        server.wait(timeout=30)


def watch(address: str, pid: int, stop: Any, out: Any, patience: float = 5.0, started: Any = None) -> None:
    """The attacks' watcher (a process of its own): stored queries without pause until ``stop``; puts its waits [s],
    the requests it lost (no reply in ``patience`` s) and the server's largest resident memory [bytes] on ``out``;
    sets ``started`` (an Event) once its first query is answered."""
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    payload = json.dumps({"op": "query", "effector": "right_hand", "goal": [0.4, -0.3, 1.1], "refine": False}).encode()
    waits: list[float] = []
    lost = memory = 0
    while not stop.is_set():
        t0 = time.perf_counter()
        sock.send(payload)
        if sock.poll(int(patience * 1000)):
            sock.recv()
            waits.append(time.perf_counter() - t0)
            if started is not None:
                started.set()
        else:
            lost += 1
            sock.close(linger=0)
            sock = zmq.Context.instance().socket(zmq.REQ)
            sock.setsockopt(zmq.LINGER, 0)
            sock.connect(address)
        with open(f"/proc/{pid}/status") as status:
            memory = max(memory, int(next(x for x in status if x.startswith("VmRSS:")).split()[1]) * 1024)
    sock.close(linger=0)
    out.put((waits, lost, memory))


def attacks_bench(atlas: Path, workers: int) -> None:
    """Attacks from one client while another asks for stored postures without pause: the watcher's
    longest wait and p99, the requests it lost (no reply in 5 s), the server process's largest resident memory
    (its workers apart), and the replies' codes."""
    server, address = serve(atlas, workers)
    _workers_ready(address, workers)
    pid = server.pid
    goals = np.random.default_rng(35).uniform([0.1, -0.7, 0.8], [0.6, 0.0, 1.6], (10_000, 3)).round(4).tolist()
    target = {"point": [0.5, -0.2, 1.1], "effector": "right_hand"}
    attacks = [
        {"op": "query", "effector": "right_hand", "goals": goals, "deadline": 0.5},  # an expired refined batch
        {"op": "query", "effector": "right_hand", "goals": goals, "refine": False},  # a stored batch
        {"op": "motion", "effector": "right_hand", "goal": [0.4, -0.3, 1.1], "rate": 240, "deadline": 0.05},
        {"op": "motion", "effector": "right_hand", "goal": [0.4, -0.3, 1.1], "timing": {"tmu": 1e300}},
        {"op": "place", "targets": [target] * 1000, "x": [-1.0, 1.0], "y": [-1.0, 1.0], "yaw": [0, 0], "step": 0.05},
    ] * 4
    if workers:  # batches held for an hour (without workers the loop would refine them for as long)
        attacks += [{"op": "query", "effector": "right_hand", "goals": goals, "deadline": 3600}] * 20
    # The watcher runs in a process of its own: in a thread beside the attacker, its waits counted the attacker's
    # own parsing of 13 MB replies under the GIL (up to half a second).
    ctx = mp.get_context("spawn")
    stop, out = ctx.Event(), ctx.Queue()
    watcher = ctx.Process(target=watch, args=(address, pid, stop, out))
    watcher.start()
    attacker = zmq.Context.instance().socket(zmq.DEALER)
    attacker.setsockopt(zmq.LINGER, 0)
    attacker.connect(address)
    codes: dict[str, int] = {}
    try:
        for k, attack in enumerate(attacks):
            attacker.send_multipart([b"", json.dumps({**attack, "id": k}).encode()])
        answered = 0
        while answered < len(attacks) and attacker.poll(120_000):
            code = reply_code(attacker.recv_multipart()[-1])
            codes[code] = codes.get(code, 0) + 1
            answered += 1
            if answered == len(attacks) - 2 and workers:  # the two held batches the server took: not waited for
                break
    finally:
        stop.set()
        waits, lost, memory = out.get(timeout=60)
        watcher.join()
        attacker.close(linger=0)
        server.terminate()
        server.wait(timeout=30)
    lat = np.array(waits) * 1e3
    emit(bench="server_attacks", workers=workers, attacks=len(attacks), replies=codes, watcher_queries=len(waits),
         watcher_lost=lost,
         longest_wait_ms=round(float(lat.max()), 1), watcher_p99_ms=round(float(np.percentile(lat, 99)), 2),
         server_rss_max_mb=round(memory / 2**20, 1))


if __name__ == "__main__":
    main()
