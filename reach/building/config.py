"""Build configurations: YAML files validated into frozen specs.

A configuration names the box B0, the depths, the default oracle and the
strategies, and for bodies the body (see :func:`oracles.bodies.body.load_body`) and
each strategy's ``joints`` and ``tasks`` (see :mod:`oracles.ik.strategy`).
Example (``configs/sphere.yaml``)::

    name: sphere
    box: {min: [-1.0, -1.0, -1.0], max: [1.0, 1.0, 1.0]}   # metres, or: box: auto
    depth: {min: 2, max: 7}
    oracle: {name: sphere, params: {center: [0, 0, 0], radius: 1.0}}
    strategies:
      - {name: sphere, effector: point, priority: 1}

``box: auto`` (or ``box: {auto: {margin: 0.05, floor: auto}}``) derives B0
from the body's size: the union of every strategy's reach bound (a ball
about its fixed anchor: the first moving joint, or a planted foot), plus the
margin [m], and symmetric about y = 0 when a strategy is mirrored. The world
is z-up (a body's ``up`` turns it so). With ``floor: auto`` a strategy's
ball is cut at z = 0 when its floor task keeps the effector above the floor;
``true`` cuts every ball there, ``false`` none.

Strategies are tried in increasing ``priority`` (1 first); the default is
their order in the file. A strategy's ``oracle.params`` are merged over the
default oracle's params, and its ``oracle.name`` replaces the default's.

Every error names the file and the dotted key, and says what was expected.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from oracles.protocol import Diagnosed, Oracle, OracleSpec, Oriented, ReachBound, Tunable, body_params
from reach.building.autobox import derive_box
from reach.building.documents import read_yaml
from reach.building.executor import CHUNK_SIZE
from reach.building.tree import Refine
from reach.errors import ConfigError, ModelError, ReachError, TreeError
from reach.maps.box import Box
from reach.maps.index import MAX_DIRECTIONS
from reach.maps.tree import MAX_DEPTH

if TYPE_CHECKING:
    from oracles.bodies.population import Population

DEFAULT_BODY_ORACLE = "casadi-ik"
TOP_KEYS = {"name", "description", "base", "body", "box", "depth", "oracle", "strategies", "build", "population"}
STRATEGY_KEYS = {"name", "effector", "priority", "oracle", "description", "joints", "tasks", "mirror_of", "directions",
                 "ranges"}
BUILD_KEYS = {"chunk_size", "refine", "twins", "motion_graph"}
REFINE_KEYS = {"centres", "faces", "isolated"}


@dataclass(frozen=True)
class StrategySpec:
    """One way to reach: an effector, a priority and the oracle that decides.

    Attributes:
        name: Unique name; the tree file is ``<name>.npz``.
        effector: What reaches (a frame name such as ``right_hand``).
        priority: Rank among strategies of the same effector; lower is tried first.
        oracle: The oracle deciding reachability for this strategy.
        mirror_of: A strategy whose tree, mirrored about y = 0, may stand for
            this one's when the body is mirror-symmetric.
        directions: Approach directions of the reachability index (0: none; see :mod:`reach.maps.index`).
    """

    name: str
    effector: str
    priority: int
    oracle: OracleSpec
    description: str = ""
    mirror_of: str | None = None
    directions: int = 0


@dataclass(frozen=True)
class Config:
    """A validated build configuration.

    With ``box: auto`` the box (B0) and its ``limit`` are derived from the strategies' oracles (their reach bounds and
    probed extents: IK solves) when first asked for, by a build or a command that draws in the box; reading a config
    solves nothing (``reach evaluate --direct`` never needs it)."""

    name: str
    source: str
    given_box: Box | None  # the config's box: min/max, or None for box: auto (see `box`)
    d_min: int
    d_max: int
    strategies: tuple[StrategySpec, ...]
    chunk_size: int = CHUNK_SIZE
    refine: Refine = field(default_factory=Refine)
    raw: dict[str, Any] = field(default_factory=dict, compare=False)
    # load-time warnings (see Diagnosed), each naming its strategies
    notes: tuple[str, ...] = field(default=(), compare=False)
    auto: dict[str, Any] | None = None  # box: auto's options (margin, floor), or None for a given box
    # ``population:`` (oracles.bodies.population): the config's strategies for each of its members; the config
    # itself is its first member's (reach.building.population)
    population: Population | None = None
    twins: bool = True  # build.twins: a volume's quarter-turn twins share one solve (reach.building.twins)
    motion_graph: bool = True  # build.motion_graph: each tree's motion graph (reach.maps.graph) after it

    @cached_property
    def _derived(self) -> tuple[Box, Box | None]:
        if self.given_box is not None:
            return self.given_box, None
        assert self.auto is not None
        oracles = [s.oracle.create() for s in self.strategies]
        return derive_box(self.source, oracles, self.auto, any(s.mirror_of for s in self.strategies))

    @property
    def box(self) -> Box:
        """B0 [m]: the given box, or box: auto's (derived on first use)."""
        return self._derived[0]

    @property
    def limit(self) -> Box | None:
        """box: auto: the provable bound B0 may grow to when reachable vertices lie on its faces; None for a given
        box."""
        return self._derived[1]

    def with_box(self, box: Box, limit: Box | None = None) -> Config:
        """This config with B0 set, and the bound it may grow to (default: its own; a grown box: auto keeps it)."""
        limit = self.limit if limit is None else limit
        out = replace(self, given_box=box)
        out.__dict__["_derived"] = (box, limit)  # (a cached_property's slot: a frozen dataclass's own __dict__)
        return out

    def strategy(self, name: str) -> StrategySpec:
        for s in self.strategies:
            if s.name == name:
                return s
        raise ConfigError(self.source, "strategies",
                          f"no strategy {name!r}; known: {[s.name for s in self.strategies]}")


class _Checker:
    """Type checks that name the file and key."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, reason: str) -> ConfigError:
        return ConfigError(self.source, key, reason)

    def mapping(self, value: Any, key: str, allowed: set[str],
                required: set[str] = frozenset()) -> dict[str, Any]:  # type: ignore[assignment]
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a mapping, got {type(value).__name__}")
        prefix = f"{key}." if key else ""
        for k in value:
            if k not in allowed:
                raise self.fail(f"{prefix}{k}", f"unknown key; allowed: {', '.join(sorted(allowed))}")
        for k in sorted(required):
            if k not in value:
                raise self.fail(f"{prefix}{k}", "required key is missing")
        return dict(value)

    def integer(self, value: Any, key: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, f"expected an integer, got {value!r}")
        if not lo <= value <= hi:
            raise self.fail(key, f"expected an integer in [{lo}, {hi}], got {value}")
        return value

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(key, f"expected a non-empty string, got {value!r}")
        return value

    def vector(self, value: Any, key: str) -> list[float]:
        if not isinstance(value, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                  for v in value):
            raise self.fail(key, f"expected a list of numbers [m], got {value!r}")
        return [float(v) for v in value]


# The longest strategy name: it names the tree's file, and a name of 250 characters passed the file system's limit
# of 255 bytes with its suffixes (a traceback).
MAX_NAME = 100

def _oracle(check: _Checker, value: Any, key: str, base: OracleSpec | None) -> OracleSpec:
    spec = check.mapping(value, key, {"name", "params"}, set() if base else {"name"})
    params = spec.get("params", {})
    if not isinstance(params, Mapping):
        raise check.fail(f"{key}.params", f"expected a mapping, got {type(params).__name__}")
    name = check.string(spec["name"], f"{key}.name") if "name" in spec else base.name  # type: ignore[union-attr]
    merged = {**(base.params if base and base.name == name else {}), **params}
    return OracleSpec(name, merged)


def parse_config(data: Any, source: str = "<mapping>", default_name: str = "atlas") -> Config:
    """Validate a parsed YAML document into a :class:`Config`."""
    check = _Checker(source)
    top = check.mapping(data, "", TOP_KEYS,
                        {"box", "depth", "strategies"} | (set() if isinstance(data, dict) and "body" in data
                                                          else {"oracle"}))
    name = _name(check, top.get("name", default_name))
    auto = _auto_box(check, top["box"])
    # box: auto gets a stand-in for the checks below; the real one is derived on first use
    box = _box(check, top["box"]) if auto is None else Box(-np.ones(3), np.ones(3))
    d_min, d_max = _depths(check, top["depth"])
    # A body's oracle defaults to casadi-ik, the reference engine; an analytic atlas names its shape.
    default = _oracle(check, top.get("oracle", {"name": DEFAULT_BODY_ORACLE}), "oracle", None)
    population, body = None, top.get("body")
    if "population" in top:
        population, body = _population(check, top)
    raw_strategies = top["strategies"]
    if not isinstance(raw_strategies, list) or not raw_strategies:
        raise check.fail("strategies", "expected a non-empty list of strategies")
    strategies: list[StrategySpec] = []
    for i, item in enumerate(raw_strategies):
        strategies.append(_strategy(check, item, i, default, body, "body" in top, {s.name for s in strategies}))
    chunk, refine, twins, motion_graph = _build_options(check, top.get("build", {}), population is not None)
    oracles = _check_oracles(check, strategies, box.dim)
    _check_directions(check, strategies, oracles)
    notes = _diagnose(strategies, oracles)
    if auto is not None:
        for o in oracles:  # the bound that box: auto sizes B0 within, checked now (it costs no solve)
            if not isinstance(o, ReachBound) or o.reach_bound() is None:
                raise check.fail("box", "box: auto needs body strategies whose reach is bounded (a fixed root, or "
                                        "feet on the floor); give box.min and box.max")
    _check_mirrors(check, strategies, None if auto is not None else box)
    strategies.sort(key=lambda spec: spec.priority)
    return Config(name, source, box if auto is None else None, d_min, d_max, tuple(strategies), chunk, refine,
                  dict(top), notes, auto, population, twins, motion_graph)


def _name(check: _Checker, raw: Any) -> str:
    name = check.string(raw, "name")
    if not name.replace("_", "").replace("-", "").replace(".", "").isalnum() or name.startswith("."):
        # It names the default output folder (out/<name>): no separators, no "..".
        raise check.fail("name", "use letters, digits, '-', '_' and '.' only, not first (it names the folder "
                                 f"out/<name>), got {name!r}")
    return name


def _box(check: _Checker, raw: Any) -> Box:
    box_raw = check.mapping(raw, "box", {"min", "max"}, {"min", "max"})
    lo, hi = check.vector(box_raw["min"], "box.min"), check.vector(box_raw["max"], "box.max")
    if len(lo) not in (2, 3) or len(lo) != len(hi):
        raise check.fail("box", f"min and max must both have 2 or 3 coordinates, got {len(lo)} and {len(hi)}")
    try:
        return Box(np.array(lo), np.array(hi))
    except TreeError as exc:
        raise check.fail("box", str(exc)) from exc


def _depths(check: _Checker, raw: Any) -> tuple[int, int]:
    depth = check.mapping(raw, "depth", {"min", "max"}, {"min", "max"})
    d_max = check.integer(depth["max"], "depth.max", 0, MAX_DEPTH)
    d_min = check.integer(depth["min"], "depth.min", 0, MAX_DEPTH)
    if d_min > d_max:
        raise check.fail("depth.min", f"D_min ({d_min}) must not exceed D_max ({d_max})")
    return d_min, d_max


def _strategy(check: _Checker, item: Any, i: int, default: OracleSpec, body: Any, has_body: bool,
              seen: set[str]) -> StrategySpec:
    """The ``i``-th strategy (``seen``: the names before it)."""
    key = f"strategies[{i}]"
    s = check.mapping(item, key, STRATEGY_KEYS, {"name"})
    sname = check.string(s["name"], f"{key}.name")
    if sname in seen:
        raise check.fail(f"{key}.name", f"duplicate strategy name {sname!r}")
    if not sname.replace("_", "").replace("-", "").isalnum():
        raise check.fail(f"{key}.name", f"use letters, digits, '-' and '_' only (it names a file), got {sname!r}")
    if len(sname) > MAX_NAME:
        raise check.fail(f"{key}.name", f"at most {MAX_NAME} characters (it names a file), got {len(sname)}")
    effector = check.string(s.get("effector", "point"), f"{key}.effector")
    priority = check.integer(s.get("priority", i + 1), f"{key}.priority", 0, 10**6)
    oracle = _oracle(check, s["oracle"], f"{key}.oracle", default) if "oracle" in s else default
    if "joints" in s or "tasks" in s or has_body:
        # A body strategy: the IK oracle receives the body, the effector, the joints and the tasks.
        if body is None:
            raise check.fail(f"{key}.joints", "joints and tasks need a top-level 'body'")
        if "joints" not in s:
            raise check.fail(f"{key}.joints", "required key is missing (the joints this strategy may move)")
        ranges = s.get("ranges")
        if ranges is not None and not isinstance(ranges, Mapping):
            raise check.fail(f"{key}.ranges", "expected joint name or pattern -> [lower, upper] in radians, got "
                                              f"{ranges!r}")
        oracle = OracleSpec(oracle.name, {**oracle.params,
                                          **body_params(body, effector, s["joints"], s.get("tasks"),
                                                        None if ranges is None else dict(ranges))})
    elif "ranges" in s:
        raise check.fail(f"{key}.ranges", "joint ranges need a body strategy (a top-level 'body', joints, tasks)")
    mirror_of = check.string(s["mirror_of"], f"{key}.mirror_of") if "mirror_of" in s else None
    directions = check.integer(s.get("directions", 0), f"{key}.directions", 0, MAX_DIRECTIONS)
    return StrategySpec(sname, effector, priority, oracle, str(s.get("description", "")), mirror_of, directions)


def _build_options(check: _Checker, raw: Any, population: bool = False) -> tuple[int, Refine, bool, bool]:
    """``build:``'s chunk size, refinements of the vertex rule, twins and motion graphs (by default not for a
    population's members: their atlases answer shares and placements, and a motion graph cost a quarter of a member's
    build, 90 CPU s of the demo's four strategies; docs/population.md)."""
    build = check.mapping(raw, "build", BUILD_KEYS)
    chunk = check.integer(build.get("chunk_size", CHUNK_SIZE), "build.chunk_size", 1, 10**7)
    refine_raw = check.mapping(build.get("refine", {}), "build.refine", REFINE_KEYS)
    for k, v in refine_raw.items():
        if not isinstance(v, bool):
            raise check.fail(f"build.refine.{k}", f"expected true or false, got {v!r}")
    flags = {"twins": build.get("twins", True), "motion_graph": build.get("motion_graph", not population)}
    for k, v in flags.items():
        if not isinstance(v, bool):
            raise check.fail(f"build.{k}", f"expected true or false, got {v!r}")
    return chunk, Refine(**refine_raw), flags["twins"], flags["motion_graph"]


def _check_directions(check: _Checker, strategies: list[StrategySpec], oracles: list[Any]) -> None:
    for i, (spec, made) in enumerate(zip(strategies, oracles, strict=True)):
        if spec.directions and not (isinstance(made, Oriented) and isinstance(made, Tunable)
                                    and "direction" in made.orientation_kinds()):
            raise check.fail(f"strategies[{i}].directions", "the reachability index needs an orientation task with "
                                                            "an axis (the effector's "
                             "approach axis whose directions it counts), e.g. {type: orientation, axis: z}")


def _check_mirrors(check: _Checker, strategies: list[StrategySpec], box: Box | None) -> None:
    """Each ``mirror_of`` names another strategy; a given box is symmetric about y = 0 (``box``: None for auto)."""
    names = {spec.name for spec in strategies}
    for i, spec in enumerate(strategies):
        if spec.mirror_of is not None and (spec.mirror_of not in names or spec.mirror_of == spec.name):
            raise check.fail(f"strategies[{i}].mirror_of", "expected the name of another strategy, got "
                                                           f"{spec.mirror_of!r}")
        if spec.mirror_of is not None and box is not None and box.dim == 3 and box.lo[1] != -box.hi[1]:
            raise check.fail(f"strategies[{i}].mirror_of", "mirroring needs a box symmetric about y = 0, got y in "
                                                           f"[{box.lo[1]}, {box.hi[1]}]")


def _population(check: _Checker, top: dict[str, Any]) -> tuple[Population, dict[str, Any]]:
    """The population and the body of its first member (the config as one body stands for its first member)."""
    # loaded when a config has a population: ANSUR II's data are read only then
    from oracles.bodies.population import members, parse_population

    try:
        population = parse_population(top["population"])
        first = members(population)[0]
        return population, first.body(top.get("body"))
    except ModelError as exc:
        raise check.fail(exc.key or "population", exc.reason) from exc


def _diagnose(strategies: list[StrategySpec], oracles: list[Oracle]) -> tuple[str, ...]:
    """Each oracle's load-time findings (see :class:`~oracles.protocol.Diagnosed`), once each, naming the strategies
    it concerns."""
    found: dict[str, list[str]] = {}
    for s, oracle in zip(strategies, oracles, strict=True):
        if isinstance(oracle, Diagnosed):
            for finding in oracle.diagnose():
                found.setdefault(finding, []).append(s.name)
    return tuple(f"{'strategy' if len(names) == 1 else 'strategies'} {', '.join(names)}: {finding}"
                 for finding, names in found.items())


def _check_oracles(check: _Checker, strategies: list[StrategySpec], dim: int) -> list[Oracle]:
    """Build each oracle once so that bad params fail at load time, naming the key.

    Building an oracle validates it (a body oracle builds its body and
    parses its tasks) but solves and compiles nothing.
    """
    out = []
    for i, s in enumerate(strategies):
        try:
            oracle = s.oracle.create()
        except ModelError as exc:
            # A body oracle's error names where in the body or strategy it lies: name it as the config writes it.
            key = (exc.key if exc.key and exc.key.split(".")[0].split("[")[0] == "body"
                   else f"strategies[{i}].{exc.key or 'oracle'}")
            raise check.fail(key, f"{exc.source}: {exc.reason}" if exc.source else exc.reason) from exc
        except ReachError as exc:
            raise check.fail(f"strategies[{i}].oracle", str(exc)) from exc
        if oracle.dim != dim:
            raise check.fail("box", f"box is {dim}-D but strategy {s.name!r} uses a {oracle.dim}-D oracle")
        out.append(oracle)
    return out


def _auto_box(check: _Checker, value: Any) -> dict[str, Any] | None:
    """Options of a derived box (``box: auto`` or ``box: {auto: {margin: m, floor: auto}}``), or None for a given
    one."""
    if value == "auto":
        return {"margin": 0.05, "floor": "auto"}
    if isinstance(value, Mapping) and "auto" in value:
        check.mapping(value, "box", {"auto"})
        opts = check.mapping(value["auto"] if value["auto"] is not True else {}, "box.auto", {"margin", "floor"})
        margin = opts.get("margin", 0.05)
        if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not 0 <= margin <= 2:
            raise check.fail("box.auto.margin", f"expected a number of metres in [0, 2], got {margin!r}")
        floor = opts.get("floor", "auto")
        if floor not in (True, False, "auto"):
            raise check.fail("box.auto.floor", f"expected auto, true or false, got {floor!r}")
        return {"margin": float(margin), "floor": floor}
    return None


def load_config(path: str | Path) -> Config:
    """Read and validate a YAML configuration file."""
    path = Path(path)
    return parse_config(read_yaml(path), str(path), path.stem)
