"""The kinds of a VATree's nodes (the paper's section 3): outside the volume, inside it, subdivided, or a boundary
leaf at the finest depth."""

OUTER, INNER, PARENT, FINAL = 0, 1, 2, 3
KIND_NAMES = ("outer", "inner", "parent", "final")
