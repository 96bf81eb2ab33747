"""Attacks replayed against a server with workers and one without (tests of the whole).

Each attack comes from one DEALER client while another client keeps asking ``health`` and stored queries
between its requests. The assertions count, never time: every attack and every watcher's request is answered,
``health`` is answered before the attacker's next request is sent, no reply is ``internal``, and the process's
resident memory grows by less than a bound.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import zmq

from reach.serving import protocol as P
from reach.serving.handlers import HANDLERS
from tests.test_server import HUMAN, Running, _atlas

pytestmark = pytest.mark.slow  # a server with a refinement worker, and hundreds of requests

MEMORY_BOUND = 400 * 2**20  # [bytes] growth of this process (server, workers' broker and clients) over the attacks
GOALS = np.random.default_rng(35).uniform([0.1, -0.7, 0.8], [0.6, 0.0, 1.6], (10_000, 3)).round(4).tolist()


def _rss() -> int:
    with open("/proc/self/status") as status:
        line = next(s for s in status if s.startswith("VmRSS:"))
    return int(line.split()[1]) * 1024


def _dealer(endpoint: str) -> zmq.Socket:  # type: ignore[type-arg]
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 120_000)
    sock.connect(endpoint)
    return sock


def _payloads(workers: int) -> list[tuple[str, bytes]]:
    """The attacks: (what, payload), in the order they are sent."""
    def req(**fields: object) -> bytes:
        return json.dumps(fields).encode()

    out = [
        ("an expired 10,000-goal refined batch",
         req(op="query", id=1, effector="right_hand", goals=GOALS, deadline=0.2)),
        ("a stored 10,000-goal batch", req(op="query", id=2, effector="right_hand", goals=GOALS, refine=False)),
        ("a motion timed past its bound",
         req(op="motion", id=3, effector="right_hand", goal=[0.4, -0.3, 1.1], rate=240, timing={"tmu": 36})),
        ("a motion at 240 Hz past its deadline",
         req(op="motion", id=4, effector="right_hand", goal=[0.4, -0.3, 1.1], rate=240, deadline=1e-6)),
        ("timing 1e300", req(op="motion", id=5, effector="right_hand", goal=[0.4, -0.3, 1.1], timing={"tmu": 1e300})),
        ("past_30 1e300 to a far goal",
         req(op="motion", id=6, effector="right_hand", goal=[3.0, 0.0, 1.0], timing={"past_30": 1e300})),
        ("place at its limit",
         req(op="place", id=7, targets=[{"point": [0.5, -0.2, 1.1], "effector": "right_hand"}] * 1000,
                                   x=[-1.0, 1.0], y=[-1.0, 1.0], yaw=[0, 0], step=0.05)),
        ("place with a denormal step",
         req(op="place", id=8, targets=[{"point": [0.5, -0.2, 1.1], "effector": "right_hand"}], x=[0, 1],
                                           y=[0, 1], step=1e-320)),
        ("place over +-1e308",
         req(op="place", id=9, targets=[{"point": [0.5, -0.2, 1.1], "effector": "right_hand"}], x=[-1e308, 1e308],
                                   y=[0, 1])),
        ("a root quaternion of 1e300", req(op="query", id=10, effector="right_hand", goal=[0.4, -0.3, 1.1],
                                           **{"from": {"root_qx": 1e300, "root_qy": 0, "root_qz": 0, "root_qw": 1}})),
        ("an orientation of 1e200",
         req(op="query", id=11, effector="right_hand", goal=[0.4, -0.3, 1.1],
             orientation={"direction": [1e200, 0, 0]})),
        ("a NUL in a reload path", req(op="reload", id=12, path="a\u0000b")),
        ("a request over 1 MiB", b'{"op": "health", "pad": "' + b"x" * (P.MAX_MESSAGE_BYTES + 10) + b'"}'),
    ]
    # 10,000-goal refined batches with an hour's deadline (a hundred held 580 MB): past the client's share of the
    # workers' queue they are refused, not held. (Without workers the loop would refine each for 500 s.)
    if workers:
        out += [(f"a held batch {k}", req(op="query", id=100 + k, effector="right_hand", goals=GOALS, deadline=3600))
                for k in range(HELD)]
    return out


HELD = 12


@pytest.fixture(scope="module")
def human(tmp_path_factory):
    return _atlas(tmp_path_factory, "human_abuse", HUMAN)


@pytest.mark.parametrize("workers", [0, 1])
def test_the_attacks_leave_the_server_answering_bounded_and_without_internal_errors(human, workers):
    r = Running(human, budget=0.05, workers=workers)
    attacker, watcher = _dealer(r.server.endpoint), _dealer(r.server.endpoint)
    before = _rss()
    replies: dict[object, dict] = {}
    payloads = _payloads(workers)
    try:
        for what, payload in payloads:
            attacker.send_multipart([b"", payload])
            # The watcher's health and stored query are answered before the attacker's next request goes.
            watcher.send_multipart([b"", b'{"op": "health", "id": "h"}'])
            watcher.send_multipart([b"", b'{"op": "query", "id": "s", "effector": "right_hand", "goal": [0.4, -0.3, '
                                         b'1.1], "refine": false}'])
            got = [json.loads(watcher.recv_multipart()[-1]) for _ in range(2)]
            assert {g["id"] for g in got} == {"h", "s"} and all(g["ok"] for g in got), what
        # Every attack is answered but the held batches the server took (its share of the queue: refined for an hour).
        expected = {json.loads(p)["id"] if p.startswith(b'{"op"') and len(p) < P.MAX_MESSAGE_BYTES else None
                    for _, p in payloads}
        held = {100 + k for k in range(HELD)} if workers else set()
        while not expected <= set(replies) | held or len(held & set(replies)) < len(held) - 2:
            reply = json.loads(attacker.recv_multipart()[-1])
            replies[reply["id"]] = reply
        grown = _rss() - before
        health = HANDLERS["health"].answer(r.server, None)  # type: ignore[arg-type]
    finally:
        attacker.close(linger=0)
        watcher.close(linger=0)
        r.stop()
    codes = {rid: (rep["error"]["code"] if not rep["ok"] else "ok") for rid, rep in replies.items()}
    assert P.INTERNAL not in codes.values(), codes
    if workers:
        # its stored answers alone take longer than its deadline (0.3 ms a goal): refused at once,
        # not answered 13.7 s late.
        assert codes[1] == P.TIMEOUT and "more than the deadline" in replies[1]["error"]["message"]
    else:
        # The loop refines in turn while the deadline allows, then answers from the store: most marked timeout.
        refined = [a["refined"] for a in replies[1]["answers"]]
        assert codes[1] == "ok" and refined.count("ok") + refined.count("failed") < 100
        assert refined.count("timeout") > 5000
    assert codes[2] == "ok" and len(replies[2]["answers"]) == 10_000
    assert codes[3] == codes[5] == P.BAD_REQUEST and "timing" in replies[3]["error"]["message"]
    # its hand's path is short: the coefficient never applies
    assert codes[6] == "ok" and replies[6]["outcome"] == "nearest"
    assert codes[4] == P.TIMEOUT
    assert codes[7] == "ok" and codes[8] == codes[9] == codes[10] == codes[11] == P.BAD_REQUEST, codes
    assert codes[12] == P.FORBIDDEN and codes[None] == P.TOO_LARGE  # this server allows no reload
    if workers:
        held = [codes.get(100 + k) for k in range(HELD)]
        # Two batches are this client's share (fewer while its earlier batches are still held): the rest are refused.
        assert held.count(P.BUSY) >= HELD - 2 and held.count(None) == HELD - held.count(P.BUSY), held
        assert health["pending"] <= 2
    assert grown < MEMORY_BOUND, grown / 2**20
