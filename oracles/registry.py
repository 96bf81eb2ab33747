"""Find oracles by name.

Built-in oracles are listed here by import path, so that asking for the
sphere never imports CasADi. Other packages add oracles through the entry-point
group ``reach.oracles``; each entry point names a factory that takes the
spec's params as keyword arguments and returns an :class:`~oracles.protocol.Oracle`.
The registry knows names, not the protocol: :meth:`oracles.protocol.OracleSpec.create`
asks it, so neither module imports the other back.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

from oracles.errors import OracleError

ENTRY_POINT_GROUP = "reach.oracles"

BUILTIN: dict[str, str] = {
    "circle": "oracles.shapes:circle",
    "sphere": "oracles.shapes:sphere",
    "ball": "oracles.shapes:Ball",
    "box": "oracles.shapes:BoxOracle",
    "torus": "oracles.shapes:Torus",
    "union": "oracles.shapes:union",
    "intersection": "oracles.shapes:intersection",
    "difference": "oracles.shapes:difference",
    "casadi-ik": "oracles.ik.oracle:IKOracle.from_params",
    "dls": "oracles.ik.oracle:dls",
}


def _load(target: str) -> Callable[..., Any]:
    module, _, attr = target.partition(":")
    found: Any = importlib.import_module(module)
    for part in attr.split("."):  # a class's factory method, e.g. IKOracle.from_params
        found = getattr(found, part)
    return found  # type: ignore[no-any-return]


def available() -> list[str]:
    """Names of every oracle: built-in ones and those from entry points."""
    names = set(BUILTIN)
    names.update(ep.name for ep in entry_points(group=ENTRY_POINT_GROUP))
    return sorted(names)


def factory(name: str) -> Callable[..., Any]:
    """The factory registered under name."""
    if name in BUILTIN:
        return _load(BUILTIN[name])
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name == name:
            return ep.load()  # type: ignore[no-any-return]
    raise OracleError(f"unknown oracle {name!r}; available: {', '.join(available())}", key="name")


def create(name: str, params: dict[str, Any]) -> Any:
    """Build the oracle registered under name from its factory's keyword arguments (an Oracle)."""
    make = factory(name)
    try:
        return make(**params)
    except TypeError as exc:
        raise OracleError(f"oracle {name!r}: bad parameters {sorted(params)}: {exc}", key="params") from exc
