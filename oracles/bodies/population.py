"""A population: who is in it, as bodies built from measured dimensions.

A config's ``population:`` names its members, each a generated human (:func:`oracles.bodies.body.human_body`) from
ANSUR II (:mod:`oracles.bodies.ansur`). One of:

* ``{ansur: {n: 40, sex: mixed, female_share: 0.5, seed: 0}}``: ``n`` subjects drawn at random without replacement
  (``sex``: ``male``, ``female`` or ``mixed``; a mixed draw takes ``round(n * female_share)`` women and the rest
  men: a target mix of the sexes, not the survey's 33 % women). Each member is the subject's whole record.
* ``{ansur: {all: true, female_share: 0.5}}``: every subject of the survey (4,082 men, 1,986 women), each sex
  weighted so that women make ``female_share`` of the population (default: the survey's own mix, unweighted).
* ``{boundary: {sex: both, coverage: 0.95, components: 3}}``: boundary manikins. Per sex, the reach-relevant
  dimensions (:data:`BOUNDARY`) are standardised and their principal components taken (of the correlation
  matrix); the manikins are the centre and points on the ellipsoid of the first ``components`` components that
  holds ``coverage`` of a multivariate normal (radius sqrt(chi2_k(coverage))): the 2k axis ends and, for k >= 2,
  the 2^k diagonal directions. Each manikin's dimensions are the components mapped back; the rest are regressed on
  them. The method: Bittner, A. C. (1987), *Computerized accommodated percentage evaluation (CAPE) model for
  cockpit analysis and other exclusion studies*, and Meindl, R. S. et al. (1993), *An alternative to
  percentiles*; its use for reach: Parkinson, M. B. & Reed, M. P. (2010), *Creating virtual user populations by
  analysis of anthropometric data*, Int J Ind Ergon 40:106-111. None of the three was available to read here; the
  method is as these works are commonly summarised, and ``bench/population.py`` checks what matters: the
  manikins of a sex span 95 % or more of that sex's thumb-tip reaches.

Every member carries the config body's other keys (``posture: seated``, ``seat``, ``proportions``): a seated
member's seat is fitted to that member, as any seated body's is.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from oracles.bodies.ansur import COLUMNS, sample
from oracles.errors import ModelError

# The dimensions a boundary family spans: those that set where a hand reaches, standing and seated.
BOUNDARY = ("stature", "acromialheight", "thumbtipreach", "span", "sittingheight", "eyeheightsitting",
            "buttockkneelength", "acromionradialelength", "radialestylionlength", "handlength", "biacromialbreadth")
MAX_MEMBERS = 10_000  # a drawn population's largest n: the survey holds 6,068 people
POPULATION_KEYS = {"ansur", "boundary"}
ANSUR_KEYS = {"n", "sex", "female_share", "seed", "all"}
BOUNDARY_KEYS = {"sex", "coverage", "components"}
SEXES = ("male", "female")


@dataclass(frozen=True)
class Member:
    """One person of a population: a name (a folder name), the ``human`` keys of its body, its sex and weight."""

    name: str
    human: dict[str, Any] = field(hash=False)
    sex: str
    weight: float = 1.0

    def body(self, base: dict[str, Any] | None) -> dict[str, Any]:
        """The member's body spec: the config body's ``human`` keys that are not who it is (posture, seat,
        proportions), with the member's."""
        base = dict(base or {"human": {}})
        if "human" not in base:
            raise ModelError("a population is of generated humans: the body must be {human: {...}} (its posture, "
                             "seat and proportions apply to every member), not a URDF", key="body")
        given = dict(base["human"] or {})
        sized = sorted(set(given) - {"posture", "seat", "proportions"})
        if sized:
            # who a member is comes from the survey: a size given here would be dropped without a word
            raise ModelError(f"a population's members take their sex and size from their own record: give only "
                             f"posture, seat and proportions here, not {', '.join(sized)}",
                             key=f"body.human.{sized[0]}")
        human = {k: v for k, v in given.items() if k in ("posture", "seat", "proportions")}
        base["human"] = {**human, **self.human}
        return base


@dataclass(frozen=True)
class Population:
    """A parsed ``population:``: how its members are chosen (see the module's docstring)."""

    kind: str  # "sample", "all" or "boundary"
    n: int = 0
    sex: str = "mixed"
    female_share: float | None = None
    seed: int = 0
    coverage: float = 0.95
    components: int = 3

    def to_dict(self) -> dict[str, Any]:
        if self.kind == "boundary":
            return {"boundary": {"sex": self.sex, "coverage": self.coverage, "components": self.components}}
        out: dict[str, Any] = {"all": True} if self.kind == "all" else {"n": self.n, "sex": self.sex,
                                                                          "seed": self.seed}
        if self.female_share is not None:
            out["female_share"] = self.female_share
        return {"ansur": out}


def _fail(key: str, reason: str) -> ModelError:
    return ModelError(reason, key=f"population.{key}" if key else "population")


def _keys(value: Any, key: str, allowed: set[str]) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _fail(key, f"expected a mapping with keys among {sorted(allowed)}, got {value!r}")
    strange = sorted(set(value) - allowed)
    if strange:
        raise _fail(f"{key}.{strange[0]}" if key else strange[0], f"unknown key; expected one of {sorted(allowed)}")
    return value


def _number(value: Any, key: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (lo <= value <= hi):
        raise _fail(key, f"expected a number in [{lo}, {hi}], got {value!r}")
    return float(value)


def _integer(value: Any, key: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not (lo <= value <= hi):
        raise _fail(key, f"expected an integer in [{lo}, {hi}], got {value!r}")
    return int(value)


def parse_population(raw: Any) -> Population:
    """A ``population:`` mapping validated; errors name the key and what was expected."""
    raw = _keys(raw, "", POPULATION_KEYS)
    if len(raw) != 1:
        raise _fail("", f"expected exactly one of {sorted(POPULATION_KEYS)}, got {sorted(raw) or 'none'}")
    if "boundary" in raw:
        b = _keys(raw["boundary"] or {}, "boundary", BOUNDARY_KEYS)
        sex = b.get("sex", "both")
        if sex not in ("male", "female", "both"):
            raise _fail("boundary.sex", f"expected male, female or both, got {sex!r}")
        return Population("boundary", sex=sex, coverage=_number(b.get("coverage", 0.95), "boundary.coverage", 0.5,
                                                                0.999),
                          components=_integer(b.get("components", 3), "boundary.components", 1, 4))
    a = _keys(raw["ansur"], "ansur", ANSUR_KEYS)
    share = None if a.get("female_share") is None else _number(a["female_share"], "ansur.female_share", 0.0, 1.0)
    if a.get("all"):
        if a["all"] is not True:
            raise _fail("ansur.all", f"expected true, got {a['all']!r}")
        extra = sorted(set(a) - {"all", "female_share"})
        if extra:
            raise _fail(f"ansur.{extra[0]}", "the whole survey takes only female_share besides all")
        return Population("all", female_share=share)
    if "n" not in a:
        raise _fail("ansur.n", "expected how many subjects to draw (n), or all: true")
    sex = a.get("sex", "mixed")
    if sex not in ("male", "female", "mixed"):
        raise _fail("ansur.sex", f"expected male, female or mixed, got {sex!r}")
    if sex != "mixed" and share is not None:
        raise _fail("ansur.female_share", f"a mix of the sexes needs sex: mixed, not {sex!r}")
    return Population("sample", n=_integer(a["n"], "ansur.n", 1, MAX_MEMBERS), sex=sex,
                      female_share=share, seed=_integer(a.get("seed", 0), "ansur.seed", 0, 2**32 - 1))


def members(population: Population) -> list[Member]:
    """The members, in a fixed order (the same spec gives the same members, named the same)."""
    if population.kind == "boundary":
        sexes = SEXES if population.sex == "both" else (population.sex,)
        return [m for sex in sexes for m in boundary_manikins(sex, population.coverage, population.components)]
    if population.kind == "all":
        counts = {sex: len(sample(sex).ids) for sex in SEXES}  # type: ignore[arg-type]
        total = sum(counts.values())
        share = counts["female"] / total if population.female_share is None else population.female_share
        weight = {"female": share * total / counts["female"], "male": (1 - share) * total / counts["male"]}
        return [_subject(sex, int(i), weight[sex]) for sex in SEXES for i in sample(sex).ids]  # type: ignore[arg-type]
    rng = np.random.default_rng(population.seed)
    if population.sex == "mixed":
        share = 0.5 if population.female_share is None else population.female_share
        women = round(population.n * share)
        wanted = {"female": women, "male": population.n - women}
    else:
        wanted = {population.sex: population.n}
    out = []
    for sex in SEXES:
        k = wanted.get(sex, 0)
        ids = sample(sex).ids  # type: ignore[arg-type]
        if k > len(ids):
            raise _fail("ansur.n", f"{k} {sex} subjects asked; ANSUR II has {len(ids)}")
        out += [_subject(sex, int(i)) for i in np.sort(rng.choice(ids, size=k, replace=False))] if k else []
    return out


def _subject(sex: str, subject: int, weight: float = 1.0) -> Member:
    return Member(f"{sex}_{subject}", {"ansur": {"sex": sex, "subject": subject}}, sex, weight)


def directions(components: int) -> np.ndarray:
    """Unit directions in the first ``components`` standardised components: axis ends, then diagonals (k >= 2)."""
    eye = np.eye(components)
    out = [s * e for e in eye for s in (1.0, -1.0)]
    if components >= 2:
        out += [np.array(signs) / math.sqrt(components) for signs in itertools.product((1.0, -1.0),
                                                                                           repeat=components)]
    return np.array(out)


def boundary_manikins(sex: str, coverage: float = 0.95, components: int = 3) -> list[Member]:
    """One sex's boundary family: the centre, then the points on the ``coverage`` ellipsoid (see the module)."""
    from scipy.stats import chi2

    s = sample(sex)  # type: ignore[arg-type]
    cols = [COLUMNS.index(d) for d in BOUNDARY]
    x = s.values[:, cols]
    mean, sd = x.mean(axis=0), x.std(axis=0, ddof=1)
    lam, vec = np.linalg.eigh(np.corrcoef(x, rowvar=False))
    order = np.argsort(lam)[::-1][:components]
    lam, vec = lam[order], vec[:, order]
    # eigh's sign of a vector is arbitrary: fix it so the first loading is positive (the same family every run).
    vec = vec * np.where(vec[0] < 0, -1.0, 1.0)
    radius = math.sqrt(float(chi2.ppf(coverage, components)))
    points = np.vstack([np.zeros(components), radius * directions(components)])
    dims = mean + sd * ((points * np.sqrt(lam)) @ vec.T)
    out = []
    for k, row in enumerate(dims):
        name = f"{sex}_centre" if k == 0 else f"{sex}_boundary_{k:02d}"
        out.append(Member(name, {"sex": sex, **{d: round(float(v), 4) for d, v in zip(BOUNDARY, row, strict=True)}},
                          sex))
    return out


def key_dimensions(member: Member) -> dict[str, float]:
    """A member's stature, thumb-tip reach, sitting height and buttock-knee length [m] (as given or regressed)."""
    human = member.human
    if "ansur" in human:
        values = sample(member.sex).subject(human["ansur"]["subject"])  # type: ignore[arg-type]
    else:
        values, _ = sample(member.sex).predict(  # type: ignore[arg-type]
            {k: v for k, v in human.items() if k in COLUMNS})
    return {k: round(values[k], 4) for k in ("stature", "thumbtipreach", "sittingheight", "buttockkneelength")}
