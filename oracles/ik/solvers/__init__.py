"""The solvers an IK oracle may hold, by the name a spec's ``solver`` key gives.

One file a solver (:class:`~oracles.ik.solvers.protocol.Solver`): adding one is its file here and its line in
:data:`SOLVERS`, by import path, so that asking for one never imports the others' libraries.
"""

from __future__ import annotations

import importlib
import inspect
from typing import Any

from oracles.errors import OracleError
from oracles.ik.solvers.protocol import Room, Solver

SOLVERS: dict[str, str] = {
    "batch": "oracles.ik.solvers.batched:Batched",  # every goal x start together; the default
    "fatrop": "oracles.ik.solvers.interior:fatrop",
    "ipopt": "oracles.ik.solvers.interior:ipopt",
    "dls": "oracles.ik.solvers.dls:DampedLeastSquares",
}


def make(name: str, room: Room, options: dict[str, Any], oracle: str = "casadi-ik") -> Solver:
    """The solver ``name`` for ``room``, with its own ``options`` (a spec's keys beyond the body's and the search's);
    an unknown name or option is an :class:`~oracles.errors.OracleError` naming it."""
    if not isinstance(name, str) or name not in SOLVERS:
        raise OracleError(f"solver must be one of {sorted(SOLVERS)}, got {name!r}", oracle=oracle, key="solver")
    module, _, attr = SOLVERS[name].partition(":")
    factory = getattr(importlib.import_module(module), attr)
    accepted = [p for p in inspect.signature(factory).parameters if p != "room"]
    extra = sorted(set(options) - set(accepted)) if "polish" not in accepted else []
    if extra:
        known = ", ".join(a for a in accepted if a != "polish")
        raise OracleError(f"solver {name!r} takes no option {', '.join(extra)}; it takes {known or 'none'}",
                          oracle=oracle, key=extra[0])
    try:
        return factory(room, **options)  # type: ignore[no-any-return]
    except TypeError as exc:
        raise OracleError(f"solver {name!r}: bad options {sorted(options)}: {exc}", oracle=oracle,
                          key="solver") from exc
