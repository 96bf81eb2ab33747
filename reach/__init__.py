"""reach: reachable volumes as adaptive octrees (VATrees), after Rodriguez et al.

Units are metres and radians throughout; see the README for the world frame.

Names are resolved lazily (PEP 562) so that ``oracles`` can import
``reach.errors`` without pulling in the whole package, and so that
``import reach`` stays cheap for the CLI.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "FINAL": "reach.maps.tree",
    "INNER": "reach.maps.tree",
    "OUTER": "reach.maps.tree",
    "PARENT": "reach.maps.tree",
    "Answer": "reach.answers.answer",
    "Atlas": "reach.maps.atlas",
    "Box": "reach.maps.box",
    "Config": "reach.building.config",
    "ConfigError": "reach.errors",
    "ModelError": "reach.errors",
    "OracleError": "reach.errors",
    "ReachError": "reach.errors",
    "ReachMap": "reach.maps.protocol",
    "Selector": "reach.answers.select",
    "StoreError": "reach.errors",
    "StrategySpec": "reach.building.config",
    "TreeError": "reach.errors",
    "VATree": "reach.maps.tree",
    "build_atlas": "reach.building.atlas",
    "build_tree": "reach.building.tree",
    "load_atlas": "reach.maps.atlas",
    "load_config": "reach.building.config",
    "load_tree": "reach.maps.store",
    "save_tree": "reach.maps.store",
}

__all__ = sorted([*_EXPORTS, "__version__"])


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'reach' has no attribute {name!r}")
