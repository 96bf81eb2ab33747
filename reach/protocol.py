"""The wire protocol of ``reach serve``: constants, request parsing, replies.

Transport: ZeroMQ. Requests go to a ROUTER socket, so REQ and DEALER clients
are both served; each request is one frame of UTF-8 JSON (after the
envelope: ``[identity, "", payload]`` for REQ, ``[identity, payload]`` or
``[identity, "", payload]`` for DEALER). Every choice is also published on a
PUB socket as ``[effector, json]``. docs/protocol.md is the full reference.

Units: metres and radians; goals are in the atlas's world frame (for the
generated human: z up, x forward, y left, origin on the floor between the
ankles). Nothing received is ever unpickled.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from reach.errors import ProtocolError

VERSION = 1
DEFAULT_BIND = "tcp://127.0.0.1:5555"
DEFAULT_PUB = "tcp://127.0.0.1:5556"
# The frame of every goal and posture: for the generated human, z up, x
# forward, y to the body's left, origin on the floor midway between the ankles.
WORLD_FRAME = "world"
WORLD_AXES = "z up, x forward, y left; origin on the floor midway between the ankles (generated human)"
MAX_MESSAGE_BYTES = 1 << 20  # a request larger than this is refused unread
MAX_BATCH = 10_000  # goals per query
POLL_MS = 100  # server poll timeout: how often it checks for a stop request
PUB_HWM = 1000  # messages queued per subscriber before the PUB socket drops

OPS = ("query", "strategies", "cells", "health", "reload", "hello")
MAX_ID = 2**53  # the largest integer id (doubles hold every integer up to it; JavaScript clients too)
MAX_DEADLINE = 3600.0  # [s] the longest deadline a request may give
MAX_TAG = 256  # characters of a client's tag
MAX_CELLS_LEVEL = 6  # "cells" rasterises at most 2**6 cells per axis

# Error codes, in replies' "error": {"code": ..., "message": ...}.
BAD_FRAMES = "bad_frames"  # wrong number of frames or an empty payload
TOO_LARGE = "too_large"  # message or batch over the limits
BAD_JSON = "bad_json"  # not UTF-8 JSON, or NaN/Infinity literals
BAD_REQUEST = "bad_request"  # not an object, missing or ill-typed fields
UNKNOWN_OP = "unknown_op"
UNKNOWN_EFFECTOR = "unknown_effector"
UNKNOWN_STRATEGY = "unknown_strategy"
RELOAD_FAILED = "reload_failed"
INTERNAL = "internal"  # a bug: the server logs it and keeps serving


@dataclass(frozen=True)
class Request:
    """A parsed request. ``goals`` is (N, d) for queries; ``single`` says whether ``goal`` was used."""

    op: str
    id: Any = None
    effector: str | None = None
    goals: list[list[float]] | None = None
    single: bool = True
    refine: bool | None = None
    path: str | None = None
    level: int = 4
    strategy: str | None = None
    start: dict[str, float] | None = None  # the query's "from": the character's current posture
    deadline: float | None = None  # [s] from receipt, for the whole request
    tag: str | None = None  # the client's own label, echoed on PUB


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not allowed")


def _number_list(value: Any, field: str, request_id: Any) -> list[float]:
    if not isinstance(value, list) or not value or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise ProtocolError(BAD_REQUEST, f"'{field}' must be a list of numbers [m], got {json.dumps(value)[:80]}", request_id)
    try:
        out = [float(v) for v in value]
    except OverflowError:  # an integer beyond a double's range
        out = [math.inf]
    if not all(math.isfinite(v) for v in out):
        raise ProtocolError(BAD_REQUEST, f"'{field}' must hold finite numbers", request_id)
    return out


def parse_request(payload: bytes) -> Request:
    """Parse and validate one request payload; raises ProtocolError."""
    if len(payload) > MAX_MESSAGE_BYTES:
        raise ProtocolError(TOO_LARGE, f"request of {len(payload)} bytes; the limit is {MAX_MESSAGE_BYTES}")
    if not payload:
        raise ProtocolError(BAD_FRAMES, "empty request frame")
    try:
        data = json.loads(payload.decode("utf-8"), parse_constant=_reject_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(BAD_JSON, f"request is not UTF-8 JSON: {exc}") from None
    except RecursionError:
        raise ProtocolError(BAD_JSON, "request JSON is nested too deeply") from None
    if not isinstance(data, dict):
        raise ProtocolError(BAD_REQUEST, f"request must be a JSON object, got {type(data).__name__}")
    rid = data.get("id")
    if isinstance(rid, int) and not isinstance(rid, bool) and abs(rid) > MAX_ID:
        # Echoed as a string: the client can still match the error to its request.
        raise ProtocolError(BAD_REQUEST, "an integer 'id' must be at most 2^53 in magnitude; use a string", str(rid))
    if rid is not None and (isinstance(rid, bool) or not isinstance(rid, (str, int, float))):
        echo = rid if isinstance(rid, bool) else None
        raise ProtocolError(BAD_REQUEST, "'id' must be a JSON string or number", echo)
    op = data.get("op")
    if not isinstance(op, str):
        raise ProtocolError(BAD_REQUEST, "'op' must be a string naming the operation", rid)
    if op not in OPS:
        raise ProtocolError(UNKNOWN_OP, f"unknown op {op!r}; ops are {', '.join(OPS)}", rid)
    allowed = {"query": {"op", "id", "effector", "goal", "goals", "refine", "from", "deadline", "tag"}, "reload": {"op", "id", "path"},
               "cells": {"op", "id", "strategy", "level"}, "hello": {"op", "id", "tag"}}.get(op, {"op", "id"})
    extra = sorted(set(data) - allowed)
    if extra:
        raise ProtocolError(BAD_REQUEST, f"unknown fields {extra} for op {op!r}; allowed: {sorted(allowed)}", rid)
    if op == "reload":
        path = data.get("path")
        if path is not None and not isinstance(path, str):
            raise ProtocolError(BAD_REQUEST, "'path' must be a string", rid)
        return Request(op, rid, path=path)
    if op == "cells":
        level = data.get("level", 4)
        if isinstance(level, bool) or not isinstance(level, int) or not 1 <= level <= MAX_CELLS_LEVEL:
            raise ProtocolError(BAD_REQUEST, f"'level' must be an integer in [1, {MAX_CELLS_LEVEL}]", rid)
        strategy = data.get("strategy")
        if strategy is not None and not isinstance(strategy, str):
            raise ProtocolError(BAD_REQUEST, "'strategy' must be a string", rid)
        return Request(op, rid, level=level, strategy=strategy)
    tag = data.get("tag")
    if tag is not None and (not isinstance(tag, str) or len(tag) > MAX_TAG):
        raise ProtocolError(BAD_REQUEST, f"'tag' must be a string of at most {MAX_TAG} characters", rid)
    if op == "hello":
        return Request(op, rid, tag=tag)
    if op != "query":
        return Request(op, rid)
    deadline = data.get("deadline")
    if deadline is not None and (isinstance(deadline, bool) or not isinstance(deadline, (int, float)) or not 0 < deadline <= MAX_DEADLINE):
        raise ProtocolError(BAD_REQUEST, f"'deadline' must be a number of seconds in (0, {MAX_DEADLINE:g}]", rid)
    effector = data.get("effector")
    if not isinstance(effector, str) or not effector:
        raise ProtocolError(BAD_REQUEST, "'effector' must be a non-empty string", rid)
    refine = data.get("refine")
    if refine is not None and not isinstance(refine, bool):
        raise ProtocolError(BAD_REQUEST, "'refine' must be true or false", rid)
    if ("goal" in data) == ("goals" in data):
        raise ProtocolError(BAD_REQUEST, "give exactly one of 'goal' ([x, y, z]) or 'goals' ([[x, y, z], ...])", rid)
    start = None
    if "from" in data:
        given = data["from"]
        if not isinstance(given, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in given.values()):
            raise ProtocolError(BAD_REQUEST, "'from' must be an object of joint name -> finite number [rad or m]", rid)
        start = {str(k): float(v) for k, v in given.items()}
    if "goal" in data:
        return Request(op, rid, effector, [_number_list(data["goal"], "goal", rid)], True, refine, start=start, deadline=deadline, tag=tag)
    goals = data["goals"]
    if not isinstance(goals, list) or not goals:
        raise ProtocolError(BAD_REQUEST, "'goals' must be a non-empty list of [x, y, z]", rid)
    if len(goals) > MAX_BATCH:
        raise ProtocolError(TOO_LARGE, f"{len(goals)} goals; the limit is {MAX_BATCH} per request", rid)
    parsed = [_number_list(g, f"goals[{i}]", rid) for i, g in enumerate(goals)]
    if len({len(g) for g in parsed}) != 1:
        raise ProtocolError(BAD_REQUEST, "every goal must have the same number of coordinates", rid)
    return Request(op, rid, effector, parsed, False, refine, start=start, deadline=deadline, tag=tag)


def finite(data: Any) -> Any:
    """A JSON-compatible value with every NaN or infinite float replaced by null: JSON has no such numbers."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: finite(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [finite(v) for v in data]
    return data


def encode(data: dict[str, Any]) -> bytes:
    """UTF-8 JSON of a reply (strict: no NaN)."""
    return json.dumps(data, allow_nan=False, separators=(",", ":")).encode()


def ok_reply(body: bytes, request_id: Any) -> bytes:
    """The reply to a request whose result is the already encoded JSON object body.

    Splicing saves encoding the same answer twice (once published, once replied).
    """
    head = b'{"id":' + encode_value(request_id) + b',"ok":true'
    return head + (b"," + body[1:] if body != b"{}" else b"}")


def encode_value(value: Any) -> bytes:
    return json.dumps(value, allow_nan=False).encode()


def error_reply(code: str, message: str, request_id: Any = None) -> bytes:
    return encode({"id": request_id, "ok": False, "error": {"code": code, "message": message}})
