"""A body's numbers as parameters of a strategy's programs: one compiled program for every body of one shape.

A strategy's programs are CasADi expressions of the posture. The body enters them only as numbers: its joints' and
frames' offsets, its segments' masses and centres, its reference posture, and what the tasks take from it (the
support polygon, the capsules, the segments the posture task lifts). With :class:`BodyParameters` lifted, each of
those numbers that is not 0, 1 or -1 becomes an entry of a parameter vector, so two bodies of one shape (the same
joints, frames, capsules and tasks, the same zeros and unit entries: any two members of a population) have
programs equal symbol for symbol, differing in that vector's value. A population then builds one program a strategy,
compiles it once (the jit cache is keyed by the program's graph) and answers every member with it (issue 47,
item 4). Unlifted, the numbers stay constants, as in a program made for one body.

The entries 0, 1 and -1 stay constants (the rotations of the generated humans are all identities, and an axis or a
zero offset kept constant keeps the expressions small), and are the body's *signature* with the arrays' names and
shapes: bodies of one signature share programs.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping

import casadi as ca
import numpy as np

TRIVIAL = (0.0, 1.0, -1.0)  # entries kept constant: they shape the expressions (a zero term, a unit factor)


SNAP = 1e-12  # an entry this near 0, 1 or -1 is that value: rounding (a foot's height 4e-17 at one body, 0 at another)


def _column(value: np.ndarray) -> np.ndarray:
    """An array as a program sees it: a vector as a column, a matrix as itself, a number as 1 x 1; entries within
    ``SNAP`` of a trivial value snapped to it."""
    a = np.array(value, float)
    a = a.reshape(-1, 1) if a.ndim <= 1 else a
    for t in TRIVIAL:
        a[np.abs(a - t) < SNAP] = t
    return a


class BodyParameters:
    """Named numeric arrays of one body, as CasADi expressions: lifted (parameters) or constants.

    Args:
        arrays: The arrays by name, in a fixed order (the order of the parameter vector).
        lift: Whether the non-trivial entries become parameters.
        fixed: Names of arrays never lifted: their every entry is part of the signature (a value the programs' code
            reads as a number, not as an expression).
        dense: Names of arrays lifted whole, zeros and ones too: numbers whose zeros are a body's, not its shape's
            (a capsule shrunk to a sphere at one body and a segment at the next).

    Attributes:
        symbols: The parameter vector (n, 1) (empty unlifted).
        values: Its value for this body (n,).
        signature: What two bodies must share for one program to serve both (a hex digest).
    """

    def __init__(self, arrays: Mapping[str, np.ndarray], lift: bool, fixed: frozenset[str] = frozenset(),
                 dense: frozenset[str] = frozenset()) -> None:
        self.lift = lift
        self._arrays = {k: _column(v) for k, v in arrays.items()}
        self.signature, self.values, self._masks = layout(self._arrays, fixed, dense)
        self.symbols = ca.SX.sym("body", int(self.values.size)) if lift else ca.SX.zeros(0, 1)
        self._cache: dict[str, ca.SX] = {}
        self._offsets: dict[str, int] = {}
        k = 0
        for name, mask in self._masks.items():
            self._offsets[name] = k
            k += int(mask.sum())

    def __contains__(self, name: str) -> bool:
        return name in self._arrays

    def number(self, name: str) -> np.ndarray:
        """The array's value for this body (as a column or matrix)."""
        return self._arrays[name]

    def sx(self, name: str) -> ca.SX:
        """The array as an expression: its lifted entries parameters, the others constants."""
        found = self._cache.get(name)
        if found is None:
            value = self._arrays[name]
            if not self.lift:
                found = ca.SX(value)
            else:
                mask = self._masks[name]
                found = ca.SX(np.where(mask, 0.0, value))
                rows, cols = np.nonzero(mask)
                k = self._offsets[name]
                for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
                    found[r, c] = self.symbols[k]
                    k += 1
            self._cache[name] = found
        return found

    def vector(self, name: str) -> ca.SX | np.ndarray:
        """A vector as the programs take it: lifted, :meth:`sx`; else the numbers themselves (n,), as a program made
        for one body always took them."""
        return self.sx(name) if self.lift else self._arrays[name].ravel()


def layout(arrays: Mapping[str, np.ndarray], fixed: frozenset[str] = frozenset(), dense: frozenset[str] = frozenset()
           ) -> tuple[str, np.ndarray, dict[str, np.ndarray]]:
    """The signature, the lifted values (in order) and each array's mask of lifted entries (none of ``fixed``'s, all
    of ``dense``'s)."""
    digest = hashlib.sha256()
    values, masks = [], {}
    for name, value in arrays.items():
        a = _column(value)  # (idempotent)
        mask = (np.zeros(a.shape, bool) if name in fixed else np.ones(a.shape, bool) if name in dense
                else ~np.isin(a, TRIVIAL))
        masks[name] = mask
        values.append(a[mask])  # row by row, as sx() places the symbols
        digest.update(f"{name}{a.shape}".encode())
        digest.update(np.packbits(mask).tobytes())
        digest.update(np.where(mask, 0.0, a).tobytes())
    flat = np.concatenate(values) if values else np.zeros(0)
    return digest.hexdigest()[:24], flat, masks
