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
    "FINAL": "reach.tree",
    "INNER": "reach.tree",
    "OUTER": "reach.tree",
    "PARENT": "reach.tree",
    "Answer": "reach.select",
    "Atlas": "reach.store",
    "Box": "reach.tree",
    "Config": "reach.config",
    "ConfigError": "reach.errors",
    "ModelError": "reach.errors",
    "OracleError": "reach.errors",
    "ReachError": "reach.errors",
    "Selector": "reach.select",
    "StoreError": "reach.errors",
    "StrategySpec": "reach.config",
    "TreeError": "reach.errors",
    "VATree": "reach.tree",
    "build_atlas": "reach.atlas",
    "build_tree": "reach.build",
    "load_atlas": "reach.store",
    "load_config": "reach.config",
    "load_tree": "reach.store",
    "save_tree": "reach.store",
}

__all__ = sorted([*_EXPORTS, "__version__"])


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'reach' has no attribute {name!r}")
