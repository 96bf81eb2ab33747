"""Building a population: one atlas per member, in one folder with one manifest.

A config with ``population:`` (:mod:`oracles.bodies.population`) is built member by member: each member's config is
the config with the member's body (the config's ``posture``, ``seat`` and ``proportions`` kept), and its atlas goes to
``OUT/<member>/``. ``OUT/population.json`` lists the members (name, sex, weight, body, folder) and the population's
spec; it is written before the first member is built, so a killed build resumes (``--resume``) member by member and,
inside a member, tree by tree from the trees' checkpoints.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from reach.building.config import Config, parse_config
from reach.errors import ConfigError, StoreError, TreeError
from reach.maps.atlas import bounded_bytes

if TYPE_CHECKING:
    from oracles.bodies.population import Member

MANIFEST = "population.json"
MAX_WEIGHT = 1e12  # a member's weight: weights are relative; a sum of thousands of them must stay finite
FORMAT = 1


def members_of(config: Config) -> list[Member]:
    """The config's members (the config must have ``population:``)."""
    # loaded when a population is built or answered: ANSUR II's data are read only then
    from oracles.bodies.population import members

    if config.population is None:
        raise ConfigError(config.source, "population", "this config has no population")
    return members(config.population)


def member_config(config: Config, member: Member) -> Config:
    """The config of one member: the population's config with the member's body, named after the member."""
    data = {k: v for k, v in config.raw.items() if k != "population"}
    data["body"], data["name"] = member.body(config.raw.get("body")), member.name
    # the population's own default for motion graphs (none unless asked), which a config of one body would not take
    data["build"] = {**(data.get("build") or {}), "motion_graph": config.motion_graph}
    return parse_config(data, f"{config.source} (member {member.name})", member.name)


def write_manifest(out: Path, config: Config, members: list[Member]) -> None:
    """The population's manifest, written whole to a temporary file and renamed: never half written."""
    assert config.population is not None
    doc = {"format": FORMAT, "name": config.name, "source": config.source,
           "population": config.population.to_dict(),
           "members": [{"name": m.name, "sex": m.sex, "weight": m.weight, "body": m.body(config.raw.get("body")),
                        "atlas": m.name} for m in members]}
    tmp = out / (MANIFEST + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, out / MANIFEST)


def is_population(folder: str | Path) -> bool:
    return (Path(folder) / MANIFEST).is_file()


MAX_MANIFEST_BYTES = 64 * 2**20  # the whole survey's 6,068 members' manifest is about 12 MB
MAX_NAME = 255  # a member's name and atlas folder: a file name


def read_manifest(folder: str | Path) -> dict[str, Any]:
    """A population folder's manifest; errors name the file and what was expected."""
    path = Path(folder) / MANIFEST
    try:
        doc = json.loads(bounded_bytes(path, MAX_MANIFEST_BYTES, "a population's manifest"))
    except StoreError as exc:
        raise TreeError(str(exc)) from None
    except RecursionError:
        raise TreeError(f"{path}: nested too deeply: not a population manifest") from None
    except ValueError as exc:
        raise TreeError(f"{path}: not JSON ({str(exc)[:200]})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("members"), list):
        raise TreeError(f"{path}: expected a population manifest (format {FORMAT}, a members list)")
    for i, m in enumerate(doc["members"]):
        _check_member(path, i, m)
    return doc


def _check_member(path: Path, i: int, m: Any) -> None:
    """A manifest's member i: a name, an atlas folder name inside the population's folder, and a weight."""
    ok = isinstance(m, dict) and all(isinstance(m.get(k), str) and 0 < len(m[k]) <= MAX_NAME for k in ("name", "atlas"))
    if not ok or "/" in m["atlas"] or m["atlas"].startswith("."):
        raise TreeError(f"{path}: members[{i}]: expected a name and an atlas folder name (at most {MAX_NAME} "
                        "characters, no '/', not starting with '.'), a sex and a weight")
    weight = m.get("weight")
    # (json reads 1e999 as inf and 10**400 as an int no float holds)
    if (isinstance(weight, bool) or not isinstance(weight, (int, float)) or not 0 <= weight <= MAX_WEIGHT
            or not math.isfinite(weight)):
        raise TreeError(f"{path}: members[{i}]: weight: expected a number from 0 to {MAX_WEIGHT:g}, got "
                        f"{str(weight)[:40]}")


def build_population(config: Config, out: str | Path, build: Callable[[Config, Path], Any],
                     say: Callable[[str], None] = lambda _line: None, resume: bool = False) -> list[Member]:
    """Build every member's atlas with ``build(member_config, folder)``; progress lines to ``say``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    members = members_of(config)
    if is_population(out) and not resume:
        raise ConfigError(str(out), "", "a population is already built here: give --resume to keep its members and "
                                        "finish the others, or another --output")
    write_manifest(out, config, members)
    start, done = time.monotonic(), 0
    for k, person in enumerate(members, start=1):
        member = member_config(config, person)
        folder = out / person.name
        t0 = time.monotonic()
        build(member, folder)
        done += 1
        spent = time.monotonic() - start
        left = spent / done * (len(members) - k)
        say(f"member {k}/{len(members)} {person.name}: {len(member.strategies)} trees in "
            f"{time.monotonic() - t0:.0f} s; {spent:.0f} s so far, about {left:.0f} s left")
    return members

