"""What a worker runs for each operation the workers answer (zguide's Majordomo: a service is a worker).

Each operation's :class:`~reach.serving.protocol.Service` names its hook here;
a hook takes the worker's :class:`Context`, the task as the server encoded it
(``reach.serving.workers.Task.encode``) and its deadline on the
``time.perf_counter`` clock, and returns the frames of its reply. An error
raised is the worker's ``failed: CODE: message``, its code by
:func:`failure_code`. Adding an operation the workers answer is its row in
the table of operations, its hook here and its handler (:mod:`reach.serving.handlers`).
"""

from __future__ import annotations

import importlib
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from reach.answers.answer import orientation_of
from reach.answers.evaluate import Target
from reach.answers.place import Space, rank
from reach.answers.select import Selector
from reach.errors import ReachError, UnknownEffector
from reach.maps.atlas import Atlas
from reach.maps.protocol import Policy
from reach.motion.planner import Planner
from reach.motion.rig import with_bones
from reach.motion.timing import Timing
from reach.serving import protocol as P


@dataclass
class Context:
    """What a worker holds for its tasks: the atlas's selector (its oracles' refine variants) and a motion planner."""

    selector: Selector
    planner: Planner


def hook(name: str) -> Callable[[Context, dict[str, Any], float], list[bytes]]:
    """A worker's hook by its Service's ``run``: a function of this module, or ``module:function`` elsewhere (an
    operation a plugin or a test adds; its module is importable in the worker, which inherits ``sys.path``)."""
    module, _, attr = name.rpartition(":")
    found = getattr(importlib.import_module(module) if module else sys.modules[__name__], attr, None)
    if not callable(found):
        raise ValueError(f"no worker hook {name!r}")
    return found  # type: ignore[no-any-return]


def failure_code(exc: Exception) -> str:
    """The reply's error code for an exception a hook raised: its own ``code`` (a motion's), an unknown effector's,
    a bad request's for any other ReachError, else ``internal``."""
    code = getattr(exc, "code", None)
    if isinstance(code, str) and code in P.WORKER_ERRORS:
        return code
    if isinstance(exc, UnknownEffector):
        return P.UNKNOWN_EFFECTOR
    return P.BAD_REQUEST if isinstance(exc, ReachError) else P.INTERNAL


def run_query(ctx: Context, job: dict[str, Any], deadline: float) -> list[bytes]:
    """A chunk of a query's goals: one answer's JSON per goal."""
    answers = ctx.selector.select_many(job["effector"], np.array(job["goals"]), job["refine"], start=job["from"],
                                       miss=job["miss"],
                                       orientation=orientation_of(job["orientation"]), deadline=deadline)
    return [a.to_json() for a in answers]


def run_motion(ctx: Context, job: dict[str, Any], deadline: float) -> list[bytes]:
    """A motion: its summary (what the server publishes), then the whole motion."""
    opts = job["options"]
    motion = ctx.planner.plan(job["effector"], np.array(job["goals"][0]), job["from"], rate=opts["rate"],
                              timing=Timing.from_dict(opts["timing"]), miss=opts["miss"], deadline=deadline,
                              back=bool(opts.get("return", False)))
    data = motion.to_dict()
    if opts.get("bones"):
        data = with_bones(data, motion, ctx.planner.body(motion.strategy))
    return [P.encode(motion.summary()), P.encode(data)]


def run_place(ctx: Context, job: dict[str, Any], deadline: float) -> list[bytes]:
    """A placement's result, one frame."""
    return [P.encode(placements(ctx.selector.atlas, job["options"]["fields"], ctx.selector.policy, deadline))]


def place_space(fields: dict[str, Any]) -> tuple[list[Target], Space]:
    """A ``place`` request's targets and candidates, its size checked (an InputError past MAX_PLACE_POINTS): before
    the request is queued, and again in the worker."""
    targets = [Target(t["name"], tuple(t["point"]), t["effector"]) for t in fields["targets"]]
    space = Space(tuple(fields["x"]), tuple(fields["y"]), tuple(fields["z"]),
                  (math.radians(fields["yaw"][0]), math.radians(fields["yaw"][1])),
                  fields["step"], math.radians(fields["yaw_step"]), max_candidates=P.MAX_PLACE_POINTS // len(targets))
    return targets, space


def placements(atlas: Atlas, fields: dict[str, Any], policy: Policy = "vertex",
               deadline: float | None = None) -> dict[str, Any]:
    """A ``place`` request's result (see docs/protocol.md): the fields as the protocol parsed them (degrees for
    ``yaw`` and ``yaw_step``), the placements of the served body ranked by its trees."""
    targets, space = place_space(fields)
    ranking = rank([atlas], targets, space, policy=policy, deadline=deadline)
    return {"candidates": len(ranking.placements),
            "ranked": [ranking.row(k, targets) for k in range(min(fields["top"], len(ranking.placements)))]}
