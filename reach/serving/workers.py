"""The server's refinement workers: processes behind a ROUTER socket (zguide's load-balancing broker).

Refining a posture by IK takes milliseconds to the budget's end; the
server's request loop must not wait for it. Each worker process loads the
atlas and holds its own oracles (their "refine" variants); it connects a
DEALER to the broker's back-end ROUTER, says it is ready, and then answers
one task at a time: a chunk of a query's goals, with the query's effector,
``from`` and deadline. The broker (:class:`Pool`, in the server's loop) keeps
a queue of tasks per client and the ready workers, least recently used
first, and hands each ready worker the next task of the next client in turn
(round robin), so that one client's large batch shares the workers with the
others' queries instead of holding them.

Tasks are JSON, results are the answers' own JSON: nothing is pickled. A
worker dies with the server (the parent-death signal), and one whose task's
deadline has passed before it starts answers ``expired`` at once.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import signal
import tempfile
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zmq

READY = b"READY"
# Workers run at a nice of 5 below the request loop: the loop, asleep on its
# sockets, wakes ahead of them for a stored answer, and they still get their
# share of a machine other processes keep busy. At Linux's idle class
# (SCHED_IDLE), as before, two CPU-bound processes beside a one-worker server
# left refined queries 1.0 s at the median and 2 of 16 timed out (docs/decisions/0018);
# at nice 5 they took 8 ms (max 20), all ok, and another client's stored
# queries waited 9 ms at p99 (docs/decisions/0018).
NICE = 5
EXPIRED = b"expired"
# the back-end socket's folder in the temporary directory: reach-serve-<server pid>-<random>
FOLDER_PREFIX = "reach-serve-"
FAILED = b"failed:"
# [s] a refined goal's estimated worker time until one is measured (the default refinement budget,
# reach.answers.select.REFINE_BUDGET)
GOAL_COST = 0.02
# [s] the worker time a task of refined goals is sized to: another client's query waits about this for a busy worker
TASK_SECONDS = 0.02
MEASURED_SHARE = 0.25  # the weight of the latest task in the running estimate of a refined goal's cost
# [s] past its task's deadline, a worker that has not answered is reported as stalled (health's workers_stalled)
STALL_GRACE = 1.0
STORED_COST = 1.5e-4  # [s] a stored answer's (1.4-1.8 s for 10,000 in the loop)


@dataclass
class Task:
    """A chunk of one request's goals."""

    request: int  # the server's sequence number of the request
    part: int  # which chunk of it
    effector: str
    goals: list[list[float]]
    start: dict[str, float] | None
    deadline: float  # time.monotonic() after which the work is abandoned
    miss: str | None = None  # the request's (see reach.answers.select); None: the selector's
    client: bytes = b""  # who asked (the request's routing identity): the queues are served in turn
    op: str = "query"  # the operation (its row of reach.serving.protocol.OPERATIONS names the worker's hook)
    options: dict[str, Any] | None = None  # a motion's rate, timing and miss; a placement's fields
    # a query's, as the request gives it (its chunk's)
    orientation: dict[str, list[float]] | list[dict[str, list[float]]] | None = None
    refine: bool = True  # a query's goals refined, or their stored answers only (a large batch, out of the loop)
    whole_cost: float | None = None  # [s] a request answered whole (its Service's cost); None: a chunk of goals
    run: str = "run_query"  # the worker's hook (its Service's run): a function of reach.serving.services or module:name

    def cost(self, goal_seconds: float = GOAL_COST) -> float:
        """Estimated worker seconds, charged to the client when the task starts (the time it took replaces it):
        ``goal_seconds`` a refined goal (a stored answer's ``STORED_COST``), or a whole request's ``whole_cost``."""
        if self.whole_cost is not None:
            return self.whole_cost
        return (goal_seconds if self.refine else STORED_COST) * len(self.goals)

    def encode(self) -> bytes:
        return json.dumps({"op": self.op, "effector": self.effector, "goals": self.goals, "from": self.start,
                           "deadline": self.deadline, "miss": self.miss, "options": self.options,
                           "orientation": self.orientation, "refine": self.refine, "run": self.run}).encode()


class Tasks:
    """A request's chunks as tasks, made one at a time as the workers take them.

    Args:
        make: The task of a part.
        parts: How many parts.
        request, client, deadline: As every one of its tasks has them.
    """

    def __init__(self, make: Callable[[int], Task], parts: int, request: int, client: bytes, deadline: float) -> None:
        self.make, self.next, self.parts, self.request, self.client, self.deadline = (make, 0, parts, request, client,
            deadline)

    def __len__(self) -> int:
        return self.parts - self.next

    def take(self) -> Task:
        task = self.make(self.next)
        self.next += 1
        return task


@dataclass
class Pool:
    """The broker's side of the workers: their processes, the back-end socket, the task queue."""

    context: zmq.Context
    atlas: Path
    options: dict[str, Any]  # the selector's keyword arguments (see reach.answers.select.Selector)
    size: int
    backend: Any = None
    processes: list[Any] = field(default_factory=list)
    idle: deque[bytes] = field(default_factory=deque)
    queues: dict[bytes, deque[Task | Tasks]] = field(default_factory=dict)  # per client
    busy: dict[bytes, Task] = field(default_factory=dict)
    # Worker seconds each client with work has had (estimated at dispatch, then as measured): the next task is
    # the queued one of the client that has had the least, so that one client's long motions cannot starve
    # another's single query (a round robin of tasks did, each motion taking seconds).
    served: dict[bytes, float] = field(default_factory=dict)
    # worker -> (dispatch time, estimate charged)
    started: dict[bytes, tuple[float, float]] = field(default_factory=dict)
    # A refined goal's worker seconds, as measured on the last tasks: refined together (the selector's passes, a batched
    # engine's starts) a goal costs less in a larger task, so the chunks follow what the goals cost here.
    goal_seconds: float = GOAL_COST

    def __post_init__(self) -> None:
        remove_stale_folders()
        self._folder = tempfile.mkdtemp(prefix=f"{FOLDER_PREFIX}{os.getpid()}-")
        self._address = f"ipc://{self._folder}/refine"
        self.backend = self.context.socket(zmq.ROUTER)
        self.backend.setsockopt(zmq.LINGER, 0)
        self.backend.bind(self._address)
        self.restarts = 0
        for k in range(self.size):
            self.processes.append(self._start(k))

    def _start(self, k: int) -> Any:
        """Worker k, a fresh interpreter (no copy of the server's sockets), known to the broker as ``w<k>``."""
        p = mp.get_context("spawn").Process(target=work,
                                            args=(self._address, str(self.atlas), self.options, f"w{k}".encode()),
                                            daemon=True)
        p.start()
        return p

    def revive(self) -> list[Task]:
        """Replace the workers that died (a crash must not shrink the pool); returns the tasks they held."""
        lost = []
        for k, p in enumerate(self.processes):
            if p.is_alive():
                continue
            identity = f"w{k}".encode()
            if identity in self.busy:
                lost.append(self.busy.pop(identity))
                self.started.pop(identity, None)
            self.idle = deque(w for w in self.idle if w != identity)
            p.join(timeout=0)
            self.processes[k] = self._start(k)
            self.restarts += 1
        return lost

    def submit(self, task: Task | Tasks) -> None:
        """Queue a task, or a request's tasks made one at a time as workers take them (a 10,000-goal batch sent
        one goal a task made 10,000 tasks in the loop at once: 0.4 s)."""
        if task.client not in self.served:
            # A client new to the pool starts level with the least served one: it is next, but gets no credit to
            # monopolise the workers with.
            self.served[task.client] = min(self.served.values(), default=0.0)
        self.queues.setdefault(task.client, deque()).append(task)
        self.dispatch()

    def cancel(self, request: int) -> None:
        """Drop the queued tasks of a request (tasks already in a worker finish and are ignored)."""
        for client, queue in list(self.queues.items()):
            kept = deque(t for t in queue if t.request != request)
            if kept:
                self.queues[client] = kept
            else:
                del self.queues[client]

    @property
    def queued(self) -> int:
        """Tasks waiting for a worker."""
        return sum(len(t) if isinstance(t, Tasks) else 1 for q in self.queues.values() for t in q)

    def dispatch(self) -> None:
        now = time.monotonic()
        while self.idle and self.queues:
            # The least served client first; ties in the order clients came (dicts keep it).
            client = min(self.queues, key=lambda c: self.served.get(c, 0.0))
            queue = self.queues[client]
            head = queue[0]
            if isinstance(head, Tasks) and head.deadline < now:
                queue.popleft()  # abandoned: none of its parts is made
                task = None
            elif isinstance(head, Tasks):
                task = head.take()
                if not len(head):
                    queue.popleft()
            else:
                task = head
                queue.popleft()
            if not queue:
                del self.queues[client]
            if task is None or task.deadline < now:
                continue  # abandoned: the request has been answered already
            worker = self.idle.popleft()
            self.busy[worker] = task
            estimate = task.cost(self.goal_seconds)
            self.served[client] = self.served.get(client, 0.0) + estimate
            self.started[worker] = (now, estimate)
            self.backend.send_multipart([worker, task.encode()])
        self._forget()

    def _forget(self) -> None:
        """Drop the served time of clients with nothing queued or running (a client's identity is not kept for ever)."""
        active = set(self.queues) | {t.client for t in self.busy.values()}
        for client in [c for c in self.served if c not in active]:
            del self.served[client]

    def receive(self) -> tuple[Task, list[bytes]] | None:
        """One message from a worker: the finished task and its result frames (None for a worker saying it is ready).

        The result is one answer's JSON per goal, or one frame ``expired`` or ``failed: ...``.
        """
        worker, *payload = self.backend.recv_multipart()
        self.idle.append(worker)
        task = self.busy.pop(worker, None)
        began = self.started.pop(worker, None)
        if task is not None and began is not None:
            took = time.monotonic() - began[0]
            if task.client in self.served:
                self.served[task.client] += took - began[1]  # the estimate replaced by the time it took
            answered = bool(payload) and payload != [EXPIRED] and not payload[0].startswith(FAILED)
            if task.whole_cost is None and task.refine and task.goals and answered:
                self.goal_seconds += MEASURED_SHARE * (took / len(task.goals) - self.goal_seconds)
        self.dispatch()
        if payload == [READY] or task is None:
            return None
        return task, payload

    def chunk(self, most: int) -> int:
        """Refined goals per task: as many as take about ``TASK_SECONDS`` at their measured cost, 1 to ``most``."""
        return max(1, min(most, int(TASK_SECONDS / max(self.goal_seconds, 1e-6))))

    @property
    def ready(self) -> int:
        """Workers that answer: idle, or busy on a task whose deadline has not long passed."""
        return len(self.idle) + len(self.busy) - len(self.stalled)

    @property
    def stalled(self) -> list[bytes]:
        """Workers holding a task more than STALL_GRACE past its deadline: stopped (SIGSTOP), starved or hung. A
        worker stops at its task's deadline (reach.answers.select and the planner read it), so a live one is never
        here for long."""
        now = time.monotonic()
        return [w for w, t in self.busy.items() if t.deadline + STALL_GRACE < now]

    def close(self) -> None:
        """Stop the workers at once (they hold nothing worth saving) and close the socket."""
        for p in self.processes:
            if p.is_alive():
                p.kill()
        for p in self.processes:
            p.join(timeout=1.0)
        self.backend.close(linger=0)
        try:
            os.unlink(os.path.join(self._folder, "refine"))
            os.rmdir(self._folder)
        except OSError:
            pass


def remove_stale_folders(root: str | None = None) -> list[str]:
    """Remove the back-end folders of servers that no longer run (a SIGKILLed server leaves its own); returns them."""
    root = root or tempfile.gettempdir()
    gone = []
    for entry in Path(root).glob(f"{FOLDER_PREFIX}*"):
        pid = entry.name[len(FOLDER_PREFIX) :].split("-")[0]
        if pid.isdigit() and _alive(int(pid)):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        gone.append(str(entry))
    return gone


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


def work(address: str, atlas: str, options: dict[str, Any], identity: bytes) -> None:
    """A worker process: refine the tasks the broker sends until it dies with the server."""
    # Only a worker process needs the answers' machinery; the broker's side of this module (Pool) starts without it.
    from reach.answers.select import Selector
    from reach.building.executor import die_with_parent
    from reach.maps.atlas import load_atlas
    from reach.motion.planner import Planner
    from reach.serving import services

    die_with_parent()
    os.nice(NICE)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group; the server decides
    selector = Selector(load_atlas(atlas), **{**options, "refine": True}).warm_up()
    # One refinement per effector before READY: what a first refinement builds lazily is built before the server says
    # it serves (the first refined query timed out, the second took 2.3 s).
    for effector in selector.effectors:
        stored = selector.atlas.maps[selector.strategies_for(effector)[0]].stored()
        if stored is not None and len(stored.ids):
            selector.select_many(effector, stored.points[:1], True, deadline=time.perf_counter() + 5.0)
    context = services.Context(selector, Planner(selector))

    sock = zmq.Context().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.ROUTING_ID, identity)
    sock.connect(address)
    sock.send(READY)
    while True:
        payload = sock.recv()
        job = json.loads(payload)
        if time.monotonic() > job["deadline"]:
            sock.send(EXPIRED)
            continue
        # The task's deadline, on the clock the planner and the selector read: they stop there (a worker
        # planned on for 100 s after its request had been answered).
        deadline = time.perf_counter() + (job["deadline"] - time.monotonic())
        try:
            # The task names its hook: the worker needs no table of operations (an operation added by a plugin too).
            sock.send_multipart(services.hook(job["run"])(context, job, deadline))
        # The broker answers a failure with an error (or, for a query, with stored answers).
        except Exception as exc:  # noqa: BLE001
            code = services.failure_code(exc)
            sock.send(FAILED + (f" {code}: {exc}" if code != "internal"
                                else f" internal: {type(exc).__name__}: {exc}").encode())
