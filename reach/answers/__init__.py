"""Answers from maps: which strategy reaches a goal and how (select), placements, target evaluations and audits
against the oracle."""
