"""The answers' defaults a command line names before anything is loaded (``reach --help`` imports this alone, not the
selector and its scientific stack: see reach.answers.select for what each means)."""

from __future__ import annotations

import math

# what a goal the trees hold but no refinement reaches answers (see reach.answers.select's module docstring)
MISSES = ("unreachable", "within")
MISS = "unreachable"
REFINE_BUDGET = 0.02  # [s] default budget of one refinement (a frame at 50 Hz; work, priced in seconds)
HANDOVER = math.radians(5.0)  # [rad] a joint this near a limit passes the goal on (see reach.answers.select)
