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

import itertools
import json
import math
from collections.abc import Callable
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
POLL_MS = 50  # server poll timeout: how often it checks for a stop request
PUB_HWM = 1000  # messages queued per subscriber before the PUB socket drops
# goals per worker task at most (reach serve --chunk); within it a task is sized by its measured cost
# (reach.serving.workers.Pool.chunk)
CHUNK_GOALS = 64
REQUEST_TIMEOUT_MS = 2500  # a client's wait for each reply [ms] (zguide's Lazy Pirate)
REQUEST_RETRIES = 3  # a client's attempts before it gives up

MAX_ID = 2**53  # the largest integer id (doubles hold every integer up to it; JavaScript clients too)
MAX_DEADLINE = 3600.0  # [s] the longest deadline a request may give
MAX_TAG = 256  # characters of a client's tag
MAX_NAME = 256  # characters of an effector's, strategy's or joint's name
MAX_CELLS_LEVEL = 6  # "cells" rasterises at most 2**6 cells per axis
MAX_FROM = 1024  # joints in a query's "from"
MAX_TARGETS = 1000  # targets of a "place"
MAX_TOP = 100  # placements a "place" returns
MAX_CLIENT_GOALS = 20_000  # goals one client may have queued for the workers (two full batches); more get `busy`
MAX_QUEUED_GOALS = 100_000  # goals all clients together may have queued (about 60 MB held: 580 bytes a goal, measured)
MAX_CLIENT_REQUESTS = 100  # requests one client may have queued for the workers (motions, small queries)
# Requests the server's socket queues per client before it stops reading that client (4 MiB at most): the bound of
# what clients make the loop hold unread is clients x RCVHWM MiB (at 16, 100 clients took it from 410 MB to 2 GB).
RCVHWM = 4
MAX_PLACE_POINTS = 2_000_000  # candidates x targets of one "place" (about 2 s of a worker's time at the limit)
MAX_ACCOMMODATION_GOALS = 1000  # goals of one "accommodation"
# tree lookups (goals x members x their trees) of one "accommodation", answered in the loop: at the trees' 16 M points/s
# (bench/tree.py) about 15 ms, the loop's share of one stored batch
MAX_ACCOMMODATION_LOOKUPS = 200_000
# Stored answers (no IK) a query may ask of the loop itself (0.15 ms each: 15 ms); a larger batch goes to the workers
# (at 1,000, a batch held the loop 150 ms and another client waited up to 229 ms).
STORED_IN_LOOP = 100

MISSES = ("unreachable", "within")  # reach.answers.select.MISSES (the protocol imports nothing heavy)
MOTION_MISSES = ("nearest", "error")  # reach.motion.planner.MOTION_MISSES
MAX_RATE = 240.0  # [Hz] reach.motion.planner.MAX_RATE
MAX_TIMING = 16  # keys in a motion's "timing"

# Error codes, in replies' "error": {"code": ..., "message": ...}.
BAD_FRAMES = "bad_frames"  # wrong number of frames or an empty payload
TOO_LARGE = "too_large"  # message or batch over the limits
BAD_JSON = "bad_json"  # not UTF-8 JSON, NaN/Infinity literals, or a number past a double's range (1e999)
BAD_REQUEST = "bad_request"  # not an object, missing or ill-typed fields
UNKNOWN_OP = "unknown_op"
UNKNOWN_EFFECTOR = "unknown_effector"
UNKNOWN_STRATEGY = "unknown_strategy"
RELOAD_FAILED = "reload_failed"
FORBIDDEN = "forbidden"  # an operation the server was not started to allow (reload without --allow-reload)
UNREACHABLE = "unreachable"  # a motion to a goal no strategy reaches, asked with miss "error"
NO_MOTION = "no_motion"  # no motion found that holds every task at every frame
TIMEOUT = "timeout"  # a motion not planned by its deadline
BUSY = "busy"  # the client (or all clients together) has as much work queued as the server holds; retry later
INTERNAL = "internal"  # a bug: the server logs it and keeps serving
# a worker's failure answers with these; others are bugs
WORKER_ERRORS = (BAD_REQUEST, UNREACHABLE, NO_MOTION, UNKNOWN_EFFECTOR, TIMEOUT)


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not allowed")


def _finite_float(text: str) -> float:
    """A JSON number as a float, refused when it overflows: ``1e999`` is valid JSON that Python reads as infinity,
    which no reply can encode (an infinite id once ended the loop)."""
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"the number {text[:40]} is out of a double's range")
    return value


def loads(text: str | bytes) -> Any:
    """Strict JSON for anything a client sends: no NaN or Infinity literals, no number that overflows a double."""
    return json.loads(text, parse_constant=_reject_constant, parse_float=_finite_float)


class Invalid(ValueError):
    """A field's value is wrong: the message says what was expected; ``code`` is the reply's error code."""

    def __init__(self, message: str, code: str = BAD_REQUEST) -> None:
        super().__init__(message)
        self.code = code


def _string(limit: int) -> Callable[[Any], str]:
    def check(value: Any) -> str:
        if not isinstance(value, str) or not value or len(value) > limit:
            raise Invalid(f"a non-empty string of at most {limit} characters")
        return value
    return check


def _bool(value: Any) -> bool:
    if not isinstance(value, bool):
        raise Invalid("true or false")
    return value


def _number(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise Invalid("a number")
    try:
        out = float(value)
    except OverflowError:  # an integer beyond a double's range
        out = math.inf
    if not math.isfinite(out):
        raise Invalid("a finite number")
    return out


def _point(value: Any) -> list[float]:
    if not isinstance(value, list) or not value or len(value) > 3:
        raise Invalid(f"a list of 2 or 3 numbers [m], got {json.dumps(value)[:80]}")
    try:
        return [_number(v) for v in value]
    except Invalid:
        raise Invalid(f"a list of finite numbers [m], got {json.dumps(value)[:80]}") from None


def _each(values: list[Any], check: Callable[[Any], Any], says: str = "") -> list[Any]:
    """check of every item of a list; the error of the first bad one names its index."""
    out = []
    for i, item in enumerate(values):
        try:
            out.append(check(item))
        except Invalid as exc:
            raise Invalid(f"[{i}] {says}{exc}", exc.code) from None
    return out


def _plain_points(value: list[Any]) -> list[list[float]] | None:
    """The goals as floats when every one is a list of 2 or 3 finite JSON numbers of one length; else None (the
    item-by-item check then names the first bad one). A twentieth of its time: it held the loop 0.2 s for 10,000
    goals (now about 7 ms: every step a builtin's loop, in C)."""
    if set(map(type, value)) != {list}:
        return None
    widths = set(map(len, value))
    if len(widths) != 1 or not widths <= {2, 3}:
        return None
    flat = list(itertools.chain.from_iterable(value))
    if not set(map(type, flat)) <= {float, int}:  # not bool, a subclass of int
        return None
    try:
        numbers = list(map(float, flat))
    except OverflowError:  # an integer beyond a double's range
        return None
    if not all(map(math.isfinite, numbers)):
        return None
    return list(map(list, zip(*[iter(numbers)] * widths.pop(), strict=True)))


def _points(value: Any) -> list[list[float]]:
    if not isinstance(value, list) or not value:
        raise Invalid("a non-empty list of [x, y, z] [m]")
    if len(value) > MAX_BATCH:
        raise Invalid(f"{len(value)} goals; the limit is {MAX_BATCH} per request", TOO_LARGE)
    plain = _plain_points(value)
    if plain is not None:
        return plain
    out = _each(value, _point, "must be ")
    if len({len(g) for g in out}) != 1:
        raise Invalid("goals with the same number of coordinates each")
    return out


def _accommodation_goals(value: Any) -> list[list[float]]:
    if isinstance(value, list) and len(value) > MAX_ACCOMMODATION_GOALS:
        raise Invalid(f"{len(value)} goals; the limit is {MAX_ACCOMMODATION_GOALS} per accommodation", TOO_LARGE)
    return _points(value)


def _choice(options: tuple[str, ...]) -> Callable[[Any], str]:
    def check(value: Any) -> str:
        if value not in options:
            raise Invalid(f"one of {', '.join(options)}")
        return str(value)
    return check


def _deadline(value: Any) -> float:
    seconds = _number(value)
    if not 0 < seconds <= MAX_DEADLINE:
        raise Invalid(f"a number of seconds in (0, {MAX_DEADLINE:g}]")
    return seconds


def _level(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_CELLS_LEVEL:
        raise Invalid(f"an integer in [1, {MAX_CELLS_LEVEL}]")
    return value


def _posture(value: Any) -> dict[str, float]:
    if not isinstance(value, dict) or len(value) > MAX_FROM:
        raise Invalid(f"an object of at most {MAX_FROM} joint name -> finite number [rad or m]")
    try:
        return {_string(MAX_NAME)(k): _number(v) for k, v in value.items()}
    except Invalid:
        raise Invalid("an object of joint name -> finite number [rad or m]") from None


def check_orientation(value: Any) -> dict[str, list[float]] | list[dict[str, list[float]]]:
    """One orientation for every goal, or a list of them, one per goal (of one kind)."""
    if isinstance(value, list):
        if not value or len(value) > MAX_BATCH:
            raise Invalid(f"a list of 1 to {MAX_BATCH} orientations, one per goal")
        out = _each(value, _one_orientation)
        if len({next(iter(o)) for o in out}) != 1:
            raise Invalid("orientations of one kind: all directions or all quaternions")
        return out
    return _one_orientation(value)


def _one_orientation(value: Any) -> dict[str, list[float]]:
    kinds = ("direction", "quaternion")
    if not isinstance(value, dict) or len(value) != 1 or next(iter(value)) not in kinds:
        raise Invalid('an object with one of "direction": [x, y, z] (the effector\'s approach axis in the world) or '
                      '"quaternion": [qx, qy, qz, qw]')
    kind, raw = next(iter(value.items()))
    n = 3 if kind == "direction" else 4
    if not isinstance(raw, list) or len(raw) != n:
        raise Invalid(f"{kind}: a list of {n} finite numbers")
    try:
        numbers = [_number(v) for v in raw]
    except Invalid:
        raise Invalid(f"{kind}: a list of {n} finite numbers") from None
    if math.hypot(*numbers) < 1e-9:
        raise Invalid(f"{kind}: not zero")
    return {kind: numbers}


def _targets(value: Any) -> list[dict[str, Any]]:
    if not isinstance(value, list) or not value or len(value) > MAX_TARGETS:
        raise Invalid(f'a list of 1 to {MAX_TARGETS} targets, each '
                      f'{{"point": [x, y, z], "effector": name, "name": optional}}')
    out = []
    for i, t in enumerate(value):
        if not isinstance(t, dict) or not {"point", "effector"} <= set(t) or set(t) - {"point", "effector", "name"}:
            raise Invalid(f'[{i}] an object with "point" [x, y, z] m and "effector" (and optionally "name")')
        try:
            point = _point(t["point"])
            effector = _string(MAX_NAME)(t["effector"])
            name = _string(MAX_NAME)(t.get("name", f"t{i}"))
        except Invalid as exc:
            raise Invalid(f"[{i}] {exc}") from None
        if len(point) != 3:
            raise Invalid(f"[{i}] point: 3 numbers [m]")
        out.append({"point": point, "effector": effector, "name": name})
    return out


def _range(value: Any) -> list[float]:
    if not isinstance(value, list) or len(value) != 2:
        raise Invalid("[min, max]")
    lo, hi = _number(value[0]), _number(value[1])
    if lo > hi:
        raise Invalid("[min, max] with min <= max")
    return [lo, hi]


def _positive(value: Any) -> float:
    v = _number(value)
    if v <= 0:
        raise Invalid("a number > 0")
    return v


def _top(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_TOP:
        raise Invalid(f"an integer in [1, {MAX_TOP}]")
    return value


def _rate(value: Any) -> float:
    rate = _number(value)
    if not 1.0 <= rate <= MAX_RATE:
        raise Invalid(f"frames per second in [1, {MAX_RATE:g}]")
    return rate


def _timing(value: Any) -> dict[str, float]:
    if not isinstance(value, dict) or len(value) > MAX_TIMING:
        raise Invalid("an object of coefficient name -> finite number (see reach.motion.timing.Timing)")
    try:
        return {_string(MAX_NAME)(k): _number(v) for k, v in value.items()}
    except Invalid:
        raise Invalid("an object of coefficient name -> finite number (see reach.motion.timing.Timing)") from None


@dataclass(frozen=True)
class Field:
    """One field of a request: its JSON name, its type as the document names it, and its check.

    Attributes:
        name: The JSON key.
        kind: The type and unit, as docs/protocol.md shows it.
        check: Returns the parsed value or raises :class:`Invalid` saying what was expected.
        doc: One line for the operations table.
        required: Whether the request must give it.
        default: The value when it is absent.
    """

    name: str
    kind: str
    check: Callable[[Any], Any]
    doc: str
    required: bool = False
    default: Any = None


@dataclass(frozen=True)
class Service:
    """How the workers answer an operation (zguide's Majordomo: a service is a worker): its operation's handler
    (:mod:`reach.serving.handlers`) hands a request over, a worker answers each task with
    ``reach.serving.services.<run>(context, job, deadline)`` (or ``module:function``, see
    :func:`reach.serving.services.hook`), named here so that this module imports nothing of the workers.

    Attributes:
        run: The worker's hook.
        cost: The worker seconds a whole request is charged before it is measured (fair shares between clients);
            None: a chunk of goals, charged by its goals at their measured cost.
    """

    run: str
    cost: float | None = None


@dataclass(frozen=True)
class Operation:
    """One request operation, declared once: the parser, the client and the document's table follow from it, and
    its handler (:data:`reach.serving.handlers.HANDLERS`, by its name) answers it.

    Attributes:
        name: The ``op``.
        fields: Its fields beyond ``op`` and ``id``, with their bounds.
        doc: What it does, one line.
        worker: How the workers answer it (:class:`Service`); None: the server's loop alone does.
        check: Cross-field rules after each field is parsed (raise :class:`Invalid`); may fill derived values.
    """

    name: str
    fields: tuple[Field, ...]
    doc: str
    worker: Service | None = None
    check: Callable[[dict[str, Any]], None] | None = None


def _one_goal_or_many(args: dict[str, Any]) -> None:
    if (args["goal"] is None) == (args["goals"] is None):
        raise Invalid("give exactly one of 'goal' ([x, y, z]) or 'goals' ([[x, y, z], ...])")
    args["single"] = args["goal"] is not None
    if args["single"]:
        args["goals"] = [args["goal"]]
    if isinstance(args.get("orientation"), list) and len(args["orientation"]) != len(args["goals"]):
        raise Invalid("'orientation' must be one object for every goal or a list of one per goal: "
                      f"{len(args['orientation'])} for {len(args['goals'])} goals")


TAG = Field("tag", "string", _string(MAX_TAG), f"the client's label (at most {MAX_TAG} characters), published with "
                                               "its choices")
OPERATIONS: dict[str, Operation] = {op.name: op for op in (
    Operation("query", (
        Field("effector", "string", _string(MAX_NAME), "the effector's frame, e.g. `right_hand`", required=True),
        Field("goal", "[x, y, z] m", _point, "one goal in the world frame"),
        Field("goals", "[[x, y, z], ...] m", _points, f"a batch of at most {MAX_BATCH} goals (instead of `goal`)"),
        Field("refine", "bool", _bool, "refine by IK at the exact goal (default: the server's)"),
        Field("from", "{joint: rad or m}", _posture, "the character's current posture; refinement starts from it"),
        Field("deadline", "s", _deadline, f"answer within this many seconds of arrival (0 to {MAX_DEADLINE:g})"),
        Field("miss", "string", _choice(MISSES), "a goal the trees hold but no refinement reaches: `unreachable` or "
                                                 "`within` (default: the server's)"),
        Field("orientation", "{direction: [x, y, z]} or {quaternion: [qx, qy, qz, qw]}, or a list of one per goal",
              check_orientation,
              "hold the goals' effector orientation: its approach axis's world direction, or its rotation; only "
              "strategies with an `orientation` task answer, always refined"),
        TAG,
    ), "which strategy reaches each goal, and in which posture", worker=Service("run_query"), check=_one_goal_or_many),
    Operation("motion", (
        Field("effector", "string", _string(MAX_NAME), "the effector's frame, e.g. `right_hand`", required=True),
        Field("goal", "[x, y, z] m", _point, "the goal in the world frame", required=True),
        Field("from", "{joint: rad or m}", _posture, "the character's current posture, the first frame (default: the "
                                                     "reference posture)"),
        Field("rate", "Hz", _rate, f"frames per second, 1 to {MAX_RATE:g}", default=30.0),
        Field("timing", "{name: number}", _timing, "overrides of the movement-time law: `tmu`, `past_30`, `stoop`, "
                                                   "`foot`, `drop`, `tilt`, `lift`, `duration`"),
        Field("miss", "string", _choice(MOTION_MISSES), "a goal out of reach: `nearest` (move towards the nearest "
                                                        "reachable point) or `error`",
              default="nearest"),
        Field("bones", "bool", _bool, "also the motion as bones (`rig`: each bone's offset and rotation per frame, Y "
                                      "up), "
              "from which a client writes BVH or glTF", default=False),
        Field("return", "bool", _bool, "then back to the first frame, the way there reversed (a squat descends and "
                                       "rises), as long again", default=False),
        Field("deadline", "s", _deadline, f"answer within this many seconds of arrival (0 to {MAX_DEADLINE:g})"),
        TAG,
    ), "the timed motion from a posture to the answer's posture: frames of posture, root and effector",
        # A motion's cost: the README's planning times, 0.1-2 s.
        worker=Service("run_motion", cost=0.5)),
    Operation("place", (
        Field("targets", "[{point, effector, name}]", _targets, f"the layout's targets [m] (at most {MAX_TARGETS})",
              required=True),
        Field("x", "[min, max] m", _range, "range of the body's x", required=True),
        Field("y", "[min, max] m", _range, "range of the body's y", required=True),
        Field("z", "[min, max] m", _range, "range of its height (default [0, 0])", default=[0.0, 0.0]),
        Field("yaw", "[min, max] deg", _range, "range of its heading (default [-180, 180])", default=[-180.0, 180.0]),
        Field("step", "m", _positive, "position step (default 0.05)", default=0.05),
        Field("yaw_step", "deg", _positive, "heading step (default 15)", default=15.0),
        Field("top", "int", _top, f"placements returned, 1 to {MAX_TOP} (default 10)", default=10),
        Field("deadline", "s", _deadline, f"answer within this many seconds of arrival (0 to {MAX_DEADLINE:g}; "
                                          "default 60)"),
    ), "where to place the body to reach the targets: placements ranked by the trees (candidates x targets at most "
       f"{MAX_PLACE_POINTS:,})",
        # A placement's cost: 1.9-2.8 s at its limit (its measurement not found again: as first
        # written).
        worker=Service("run_place", cost=1.0)),
    Operation("accommodation", (
        Field("effector", "string", _string(MAX_NAME), "the effector's frame, e.g. `right_hand`", required=True),
        Field("goals", "[[x, y, z], ...] m", _accommodation_goals, f"at most {MAX_ACCOMMODATION_GOALS} goals in the "
                                                                   "members' world frame", required=True),
        Field("relative_to", "string", _string(MAX_NAME), "a frame of the members' bodies (`back`, `right_acromion`, "
                                                          "`eyes`, ...): the goals are offsets from it on each "
                                                          "member's own body, in the world's axes"),
    ), "the share of the served population (`reach serve --population`) whose trees hold each goal, with its 95 % "
       "interval, and per strategy"),
    Operation("strategies", (), "the atlas's strategies, effectors, boxes and world frame"),
    Operation("cells", (
        Field("strategy", "string", _string(MAX_NAME), "one strategy (default: all)"),
        Field("level", "int", _level, f"cells per axis 2**level, 1 to {MAX_CELLS_LEVEL}", default=4),
    ), "centres of each strategy's reachable cells on a regular grid"),
    Operation("health", (), "status and counters"),
    Operation("hello", (TAG,), "publish `hello` with the tag: a subscriber's sync"),
    Operation("reload", (Field("path", "string", _string(4096), "the atlas folder, under the server's "
                                                                "`--allow-reload` root (default: the one served)"),),
              "load an atlas and serve it (only with `reach serve --allow-reload ROOT`)"),
    Operation("version", (), "the protocol's version, the server's and its operations"),
)}
OPS = tuple(OPERATIONS)


@dataclass(frozen=True)
class Request:
    """A parsed request: its operation, id and checked fields (every declared field, None when absent)."""

    op: str
    id: Any
    args: dict[str, Any]

    def __getitem__(self, name: str) -> Any:
        return self.args[name]


def parse_request(payload: bytes) -> Request:
    """Parse and validate one request payload against the table of operations; raises ProtocolError."""
    data = _request_object(payload)
    rid = _request_id(data)
    name = data.get("op")
    if not isinstance(name, str):
        raise ProtocolError(BAD_REQUEST, "'op' must be a string naming the operation", rid)
    op = OPERATIONS.get(name)
    if op is None:
        raise ProtocolError(UNKNOWN_OP, f"unknown op {name!r}; ops are {', '.join(OPS)}", rid)
    allowed = {"op", "id", *(f.name for f in op.fields)}
    if not data.keys() <= allowed:
        # Named a few at most: a 1 MiB request of 90,000 unknown keys was sorted and echoed whole, in the loop.
        extra = [k for k in data if k not in allowed]
        named = ", ".join(repr(k[:40]) for k in extra[:5]) + (f" and {len(extra) - 5} more" if len(extra) > 5 else "")
        raise ProtocolError(BAD_REQUEST, f"unknown fields {named} for op {name!r}; allowed: {sorted(allowed)}", rid)
    try:
        args = _fields(op, data)
    except Invalid as exc:
        raise ProtocolError(exc.code, str(exc), rid) from None
    return Request(name, rid, args)


def _request_object(payload: bytes) -> dict[str, Any]:
    """A request payload as its JSON object, within the size limit; raises ProtocolError."""
    if len(payload) > MAX_MESSAGE_BYTES:
        raise ProtocolError(TOO_LARGE, f"request of {len(payload)} bytes; the limit is {MAX_MESSAGE_BYTES}")
    if not payload:
        raise ProtocolError(BAD_FRAMES, "empty request frame")
    try:
        data = loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(BAD_JSON, f"request is not UTF-8 JSON: {exc}") from None
    except RecursionError:
        raise ProtocolError(BAD_JSON, "request JSON is nested too deeply") from None
    if not isinstance(data, dict):
        raise ProtocolError(BAD_REQUEST, f"request must be a JSON object, got {type(data).__name__}")
    return data


def _request_id(data: dict[str, Any]) -> Any:
    """A request's ``id`` (None when it has none), a JSON string or a number a double holds; raises ProtocolError."""
    rid = data.get("id")
    if isinstance(rid, int) and not isinstance(rid, bool) and abs(rid) > MAX_ID:
        # Echoed as a string: the client can still match the error to its request.
        raise ProtocolError(BAD_REQUEST, "an integer 'id' must be at most 2^53 in magnitude; use a string", str(rid))
    if rid is not None and (isinstance(rid, bool) or not isinstance(rid, (str, int, float))):
        echo = rid if isinstance(rid, bool) else None
        raise ProtocolError(BAD_REQUEST, "'id' must be a JSON string or number", echo)
    return rid


def _fields(op: Operation, data: dict[str, Any]) -> dict[str, Any]:
    """A request's fields checked by its operation's table (defaults where omitted); raises Invalid."""
    args: dict[str, Any] = {}
    for f in op.fields:
        if f.name not in data:
            if f.required:
                raise Invalid(f"'{f.name}' is required: {f.doc}")
            args[f.name] = f.default
            continue
        try:
            args[f.name] = f.check(data[f.name])
        except Invalid as exc:
            raise Invalid(f"'{f.name}' must be {exc}", exc.code) from None
    if op.check is not None:
        op.check(args)
    return args


def operations_table() -> str:
    """The Markdown table of operations that docs/protocol.md holds (a test keeps the two equal)."""
    rows = ["| op | fields | what it answers | in workers |", "| --- | --- | --- | --- |"]
    for op in OPERATIONS.values():
        fields = "<br>".join(f"`{f.name}`{'*' if f.required else ''} ({f.kind}): {f.doc}" for f in op.fields) or "none"
        rows.append(f"| `{op.name}` | {fields} | {op.doc} | {'yes' if op.worker else 'no'} |")
    return "\n".join(rows)


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
    # One copy of the body (a 10,000-goal batch's is 13 MB): its slice is a view, not a bytes object.
    return b"".join([head, b",", memoryview(body)[1:]]) if body != b"{}" else head + b"}"


def batch_body(bodies: list[bytes]) -> bytes:
    """A batch's result ``{"answers": [...]}`` from its encoded answers."""
    return b'{"answers":[' + b",".join(bodies) + b"]}"


def ok_batch_reply(bodies: list[bytes], request_id: Any) -> bytes:
    """``ok_reply(batch_body(bodies), request_id)`` in one copy of the answers (a 10,000-goal batch's are 13 MB;
    each copy cost the loop about 13 ms)."""
    parts = [b'{"id":' + encode_value(request_id) + b',"ok":true,"answers":[']
    for body in bodies:
        parts += (body, b",")
    if bodies:
        parts.pop()
    parts.append(b"]}")
    return b"".join(parts)


def encode_value(value: Any) -> bytes:
    return json.dumps(value, allow_nan=False).encode()


def error_reply(code: str, message: str, request_id: Any = None) -> bytes:
    """An error reply; it cannot raise: an id or message that does not encode is replaced (the error path runs
    outside any other catch, so a raise here would end the loop)."""
    try:
        return encode({"id": request_id, "ok": False, "error": {"code": code, "message": message}})
    except (TypeError, ValueError, RecursionError):
        safe = request_id if isinstance(request_id, str) else None
        return json.dumps({"id": safe, "ok": False, "error": {"code": code, "message": repr(message)[:2000]}},
                          ensure_ascii=True).encode()


if __name__ == "__main__":
    print(operations_table())
