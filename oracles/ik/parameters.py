"""A body's numbers as parameters of a strategy's programs: one compiled program for every body of one shape.

A strategy's programs are CasADi expressions of the posture. The body enters them only as numbers: its joints' and
frames' offsets, its segments' masses and centres, its reference posture, and what the tasks take from it (the
support polygon, the capsules, the segments the posture task lifts). With :class:`BodyParameters` lifted, each of
those numbers that is not 0, 1 or -1 becomes an entry of a parameter vector, so two bodies of one shape (the same
joints, frames, capsules and tasks, the same zeros and unit entries: any two members of a population) have
programs equal symbol for symbol, differing in that vector's value. A population then builds one program a strategy,
compiles it once (the jit cache is keyed by the program's graph) and answers every member with it. Unlifted, the
numbers stay constants, as in a program made for one body.

The entries 0, 1 and -1 stay constants (the rotations of the generated humans are all identities, and an axis or a
zero offset kept constant keeps the expressions small), and are the body's *signature* with the arrays' names and
shapes: bodies of one signature share programs.
"""

from __future__ import annotations

import copy
import hashlib
import math
from collections.abc import Mapping

import casadi as ca
import numpy as np

from oracles.bodies.kinematics import Stacked

TRIVIAL = (0.0, 1.0, -1.0)  # entries kept constant: they shape the expressions (a zero term, a unit factor)


SNAP = 1e-12  # an entry this near 0, 1 or -1 is that value: rounding (a foot's height 4e-17 at one body, 0 at another)


class BodyParameters:
    """Named numeric arrays of one body, as CasADi expressions: lifted (parameters) or constants.

    A vector is a column, a matrix itself, a number 1 x 1; entries within ``SNAP`` of 0, 1 or -1 are snapped to it.

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

    def __init__(self, arrays: Mapping[str, np.ndarray] | Stacked, lift: bool, fixed: frozenset[str] = frozenset(),
                 dense: frozenset[str] = frozenset()) -> None:
        self.lift = lift
        # All arrays as one flat vector, snapped, masked and hashed at once: a member's ~1,000 small arrays one at a
        # time cost 15 ms a strategy.
        stacked = arrays if isinstance(arrays, Stacked) else Stacked(arrays)
        self._shapes, flat = stacked.shapes, stacked.flat.copy()
        for t in TRIVIAL:
            flat[np.abs(flat - t) < SNAP] = t
        sizes = [r * c for r, c in self._shapes.values()]
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        self._start = dict(zip(self._shapes, starts[:-1].tolist(), strict=True))
        mask = ~np.isin(flat, TRIVIAL)
        for k in (fixed | dense) & self._shapes.keys():
            mask[self._start[k] : self._start[k] + math.prod(self._shapes[k])] = k in dense
        self._flat, self._mask = flat, mask
        self.values = flat[mask]
        self._index = np.cumsum(mask) - 1  # the parameter of each lifted entry
        # the names and shapes as one string and one array: repr() of ~400 (name, shape) pairs took 0.7 ms a strategy
        digest = hashlib.sha256("\n".join(self._shapes).encode())
        digest.update(np.array(list(self._shapes.values()), np.int64).tobytes())
        digest.update(np.packbits(mask).tobytes())
        digest.update(np.where(mask, 0.0, flat).tobytes())
        self.signature = digest.hexdigest()[:24]
        self.symbols = ca.SX.sym("body", int(self.values.size)) if lift else ca.SX.zeros(0, 1)
        self._cache: dict[str, ca.SX] = {}

    def adopted(self, other: BodyParameters) -> BodyParameters | None:
        """These numbers lifted where ``other``'s are (its signature), or None when they cannot be: the arrays' names
        and shapes differ, or an entry ``other`` keeps constant has another value here. A body number 0 or 1 by chance
        (ANSUR II man 11103's pelvis 1.000 m high, woman 25596's frame offsets of 0: 5 of 6,068 subjects) then is a
        parameter of the programs the other bodies share, not a constant of programs of its own."""
        theirs = other._mask
        if not (self.lift and other.lift) or self._shapes != other._shapes or \
                not np.array_equal(self._flat[~theirs], other._flat[~theirs]):
            return None
        out = copy.copy(self)
        out._mask, out._index, out.signature = theirs, other._index, other.signature
        out.values = self._flat[theirs]
        out.symbols = ca.SX.sym("body", int(out.values.size))
        out._cache = {}
        return out

    def __contains__(self, name: str) -> bool:
        return name in self._shapes

    @property
    def names(self) -> list[str]:
        return list(self._shapes)

    def number(self, name: str) -> np.ndarray:
        """The array's value for this body (as a column or matrix)."""
        a, n = self._start[name], math.prod(self._shapes[name])
        return self._flat[a : a + n].reshape(self._shapes[name])

    def sx(self, name: str) -> ca.SX:
        """The array as an expression: its lifted entries parameters, the others constants."""
        found = self._cache.get(name)
        if found is None:
            value = self.number(name)
            if not self.lift:
                found = ca.SX(value)
            else:
                a, n = self._start[name], math.prod(self._shapes[name])
                mask = self._mask[a : a + n].reshape(value.shape)
                found = ca.SX(np.where(mask, 0.0, value))
                rows, cols = np.nonzero(mask)  # row by row, as the flat vector
                for r, c, k in zip(rows.tolist(), cols.tolist(), self._index[a : a + n][mask.ravel()].tolist(),
                                   strict=True):
                    found[r, c] = self.symbols[k]
            self._cache[name] = found
        return found

    def vector(self, name: str) -> ca.SX | np.ndarray:
        """A vector as the programs take it: lifted, :meth:`sx`; else the numbers themselves (n,), as a program made
        for one body always took them."""
        return self.sx(name) if self.lift else self.number(name).ravel()
