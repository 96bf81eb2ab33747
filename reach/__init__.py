"""reach: reachable volumes as adaptive octrees (VATrees), after Rodriguez et al.

Units are metres and radians throughout; see the README for the world frame.
"""

from reach.build import build_tree
from reach.config import Config, StrategySpec, load_config
from reach.errors import ConfigError, ModelError, OracleError, ReachError, StoreError, TreeError
from reach.select import Answer, Selector
from reach.store import Atlas, load_atlas, load_tree, save_tree
from reach.tree import FINAL, INNER, OUTER, PARENT, Box, VATree

__version__ = "0.1.0"

__all__ = [
    "FINAL",
    "INNER",
    "OUTER",
    "PARENT",
    "Answer",
    "Atlas",
    "Box",
    "Config",
    "ConfigError",
    "ModelError",
    "OracleError",
    "ReachError",
    "Selector",
    "StoreError",
    "StrategySpec",
    "TreeError",
    "VATree",
    "__version__",
    "build_tree",
    "load_atlas",
    "load_config",
    "load_tree",
    "save_tree",
]
