"""The ANSUR II survey: its measured people, and the regression of any of their dimensions on the others.

Data: 39 dimensions of the 4,082 men and 1,986 women of the public ANSUR II working data (Gordon et al. 2014,
NATICK/TR-15/007), carried in ``data/ansur2.csv.gz`` with their provenance (``data/README.md``).

Names are the survey's own (``acromialheight``, ``buttockkneelength`` ...). Here every length is in metres and
``weightkg`` in kilograms (the survey's files give millimetres and tenths of a kilogram).

Regression: each sex's dimensions taken as one multivariate normal (mean and covariance of the sample), a dimension
not given is its conditional mean on those given (the least-squares linear regression on them, fitted on that
sex's whole sample); its residual standard deviation is the conditional one. With stature alone given, a body has
"the mean proportions at that stature".
"""

from __future__ import annotations

import csv
import gzip
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np

from oracles.errors import ModelError

Sex = Literal["male", "female"]
DATA = Path(__file__).parent / "data" / "ansur2.csv.gz"

# The dimensions carried (the survey's names), in the file's column order.
COLUMNS = (
    "stature",
    "acromialheight",
    "cervicaleheight",
    "trochanterionheight",
    "lateralfemoralepicondyleheight",
    "lateralmalleolusheight",
    "wristheight",
    "acromionradialelength",
    "radialestylionlength",
    "handlength",
    "forearmhandlength",
    "forearmcenterofgriplength",
    "thumbtipreach",
    "span",
    "biacromialbreadth",
    "sittingheight",
    "eyeheightsitting",
    "buttockkneelength",
    "buttockpopliteallength",
    "poplitealheight",
    "kneeheightsitting",
    "overheadfingertipreachsitting",
    "footlength",
    "weightkg",
    "chestbreadth",
    "chestdepth",
    "waistbreadth",
    "waistdepth",
    "hipbreadth",
    "bicepscircumferenceflexed",
    "forearmcircumferenceflexed",
    "wristcircumference",
    "thighcircumference",
    "calfcircumference",
    "headbreadth",
    "headlength",
    "neckcircumference",
    "handbreadth",
    "buttockdepth",
    "shoulderelbowlength",
)
# The dimensions that set a body's reach (a list of the survey's reach dimensions): what `reach model` prints first.
REACH = (
    "stature",
    "acromialheight",
    "acromionradialelength",
    "radialestylionlength",
    "handlength",
    "biacromialbreadth",
    "sittingheight",
    "eyeheightsitting",
    "buttockkneelength",
    "buttockpopliteallength",
    "poplitealheight",
    "kneeheightsitting",
    "footlength",
    "weightkg",
)
MASS = "weightkg"
# Plausible bounds of a given dimension, as a multiple of the survey's range for that sex: a value far outside is a
# unit slip (millimetres for metres) more often than a person.
SLACK = 0.5


@dataclass(frozen=True)
class Sample:
    """One sex's subjects: ids, their dimensions (rows; metres, kilograms), and the sample's mean and covariance."""

    sex: Sex
    ids: np.ndarray
    values: np.ndarray
    mean: np.ndarray
    cov: np.ndarray

    def column(self, name: str) -> np.ndarray:
        return self.values[:, COLUMNS.index(name)]

    def subject(self, subject: int) -> dict[str, float]:
        """A subject's own measures, by id."""
        rows = np.flatnonzero(self.ids == subject)
        if not len(rows):
            raise ModelError(f"no {self.sex} subject {subject} in ANSUR II (ids {int(self.ids.min())}-"
                             f"{int(self.ids.max())}, not every id used)", key="human.ansur.subject")
        return dict(zip(COLUMNS, (float(v) for v in self.values[rows[0]]), strict=True))

    def predict(self, given: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
        """Every dimension: the given ones as they are, the others their conditional mean on the given ones.

        Returns (values, residual SD) keyed by name; a given dimension's SD is 0.
        """
        unknown = sorted(set(given) - set(COLUMNS))
        if unknown:
            raise ModelError(f"unknown ANSUR II dimension {unknown[0]!r}; known: {', '.join(COLUMNS)}",
                             key=f"human.{unknown[0]}")
        g = [COLUMNS.index(k) for k in given]
        u = [i for i in range(len(COLUMNS)) if i not in g]
        x = np.array([given[COLUMNS[i]] for i in g], float)
        mean, sd = self.mean.copy(), np.zeros(len(COLUMNS))
        if g:
            s_gg = self.cov[np.ix_(g, g)]
            s_ug = self.cov[np.ix_(u, g)]
            gain = np.linalg.solve(s_gg, s_ug.T).T
            mean[u] = self.mean[u] + gain @ (x - self.mean[g])
            mean[g] = x
            resid = self.cov[np.ix_(u, u)] - gain @ s_ug.T
            sd[u] = np.sqrt(np.clip(np.diag(resid), 0.0, None))
        else:
            sd = np.sqrt(np.diag(self.cov))
        return (dict(zip(COLUMNS, map(float, mean), strict=True)), dict(zip(COLUMNS, map(float, sd), strict=True)))

    def check(self, name: str, value: float) -> None:
        """A given dimension within the survey's range widened by SLACK, or a one-line error naming it."""
        col = self.column(name)
        lo, hi = float(col.min()), float(col.max())
        span = hi - lo
        # Widened by SLACK of the span, but never below half the survey's smallest: a wide range's widening reached
        # below zero (a mass of -13 kg built a body whose centre of mass was NaN).
        low, high = max(lo - SLACK * span, 0.5 * lo), hi + SLACK * span
        if not (math.isfinite(value) and low <= value <= high):
            unit = "kg" if name == MASS else "m"
            raise ModelError(f"expected {unit} near ANSUR II's {self.sex} range [{lo:.3f}, {hi:.3f}] {unit} (from "
                             f"{low:.3f} to {high:.3f}), got {value!r}", key=f"human.{name}")


@lru_cache(maxsize=2)
def sample(sex: Sex) -> Sample:
    """One sex's subjects from the carried data (read once a process: the data never change)."""
    if sex not in ("male", "female"):
        raise ModelError(f"sex must be 'male' or 'female', got {sex!r}", key="human.sex")
    ids, rows = [], []
    with gzip.open(DATA, "rt", newline="") as fh:
        for row in csv.DictReader(fh):
            if row["sex"] == sex:
                ids.append(int(row["subject"]))
                rows.append([float(row[c]) for c in COLUMNS])
    values = np.array(rows) / 1000.0  # millimetres to metres; weightkg's tenths of a kilogram to kilograms
    values[:, COLUMNS.index(MASS)] *= 100.0
    return Sample(sex, np.array(ids), values, values.mean(axis=0), np.cov(values, rowvar=False))
