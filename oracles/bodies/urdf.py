"""A body's model files: a URDF checked and parsed into a Pinocchio model with a floating root, the spec's ranges,
frames, orientation and reference posture set on it, and an SRDF's pairs of links that never collide.

Every error is a ModelError naming the file and the key or the link or joint (see :mod:`oracles.bodies.body` for the
spec's keys).
"""

from __future__ import annotations

import fnmatch
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from oracles.errors import ModelError

ROOT = "root"
MAX_DEPTH = 100  # levels of elements a URDF may nest (robot, link, visual, geometry, mesh: 5; Gazebo's tags a few more)


def no_doctype(text: str, source: Any, kind: str) -> None:
    """Refuse a document type declaration: its entities could name local files or expand without bound, and a URDF
    or SRDF needs none (neither is resolved: the file is refused before any parser sees it)."""
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise ModelError(f"a document type declaration (<!DOCTYPE ...> or <!ENTITY ...>): refused, never resolved; "
                         f"a {kind} needs none", source=source)


def _check_xml(urdf: str, source: str) -> None:
    """What urdfdom accepts silently or reports over many lines: not XML, a negative or non-finite mass, a zero
    joint axis. Each is one line naming the link or joint."""
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as exc:
        raise ModelError(f"not a valid URDF (XML: {exc})", source=source) from None
    if _depth(root) > MAX_DEPTH:
        # urdfdom's parser (tinyxml2) stops at 500 levels, over three lines of its own on stderr
        raise ModelError(f"elements nested over {MAX_DEPTH} levels deep: not a URDF", source=source)
    for link in root.iter("link"):
        mass = link.find("inertial/mass")
        if mass is not None and not _number_at_least(mass.get("value", "nan"), 0.0):
            raise ModelError(f"link {link.get('name')!r}: mass {mass.get('value')!r}; expected a finite number "
                             ">= 0 [kg]", source=source)
    for joint in root.iter("joint"):
        axis = joint.find("axis")
        if axis is not None and joint.get("type") in ("revolute", "continuous", "prismatic") and not _axis(
                axis.get("xyz", "1 0 0")):
            raise ModelError(f"joint {joint.get('name')!r}: axis {axis.get('xyz')!r}; expected three finite "
                             "numbers, not all zero", source=source)


def _depth(root: ET.Element) -> int:
    """How deep an XML tree's elements nest (without recursion: a hostile file nests 100,000 deep)."""
    deepest, stack = 0, [(root, 1)]
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        stack.extend((child, depth + 1) for child in node)
    return deepest


def _number_at_least(text: str, least: float) -> bool:
    try:
        value = float(text)
    except ValueError:
        return False
    return math.isfinite(value) and value >= least


def _axis(text: str) -> bool:
    """Whether a URDF axis is three finite numbers, not all zero."""
    try:
        xyz = [float(v) for v in text.split()]
    except ValueError:
        return False
    return len(xyz) == 3 and all(math.isfinite(v) for v in xyz) and math.hypot(*xyz) >= 1e-9


def parse(urdf: str, source: str, ours: bool = False) -> pin.Model:
    """The URDF's Pinocchio model, with a free-flyer root named ``root``; ModelError for what it cannot be. ``ours``:
    a URDF this package wrote (the generated human), not read again for a user's mistakes (4.5 ms of a population
    member's 37)."""
    if not ours:
        _check_xml(urdf, source)
    try:
        return pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer(), ROOT)
    except (RuntimeError, ValueError, IndexError) as exc:
        raise ModelError(f"not a valid URDF ({exc})", source=source) from exc


def apply_ranges(model: pin.Model, ranges: dict[str, Any], source: str) -> None:
    """The spec's ``ranges``: joint name or glob pattern -> [lower, upper] [rad or m] or {scale: f}, set on the
    model's limits."""
    names = [str(n) for n in model.names[2:]]
    for pattern, value in ranges.items():
        hits = [n for n in names if fnmatch.fnmatchcase(n, pattern)]
        if not hits:
            raise ModelError(f"no joint matches; joints are: {', '.join(names)}", source=source,
                             key=f"ranges.{pattern}")
        for n in hits:
            jm = model.joints[model.getJointId(n)]
            if jm.nq != 1:
                raise ModelError(f"joint {n!r} has {jm.nq} coordinates; only 1-coordinate joints take ranges",
                                 source=source, key=f"ranges.{pattern}")
            i = jm.idx_q
            lower, upper = _range(value, float(model.lowerPositionLimit[i]), float(model.upperPositionLimit[i]))
            if lower is None:
                raise ModelError(f"expected [lower, upper] in radians or {{scale: f}} with 0 < f <= 1, got {value!r}",
                                 source=source, key=f"ranges.{pattern}")
            model.lowerPositionLimit[i], model.upperPositionLimit[i] = lower, upper


def _range(value: Any, lower: float, upper: float) -> tuple[float, float] | tuple[None, None]:
    """A joint's range as ``ranges`` gives it, from its limits now: (None, None) for a value that is neither."""
    if (isinstance(value, dict) and set(value) == {"scale"} and isinstance(value["scale"], (int, float))
            and 0 < value["scale"] <= 1):
        return lower * value["scale"], upper * value["scale"]
    if (isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value)
            and value[0] <= value[1]):
        return float(value[0]), float(value[1])
    return None, None


def check_limits(model: pin.Model, source: str) -> None:
    """Every one-coordinate joint's limits are numbers with lower <= upper (a URDF may say otherwise)."""
    for j in range(2, model.njoints):
        jm = model.joints[j]
        if jm.nq != 1:
            continue
        lo, hi = float(model.lowerPositionLimit[jm.idx_q]), float(model.upperPositionLimit[jm.idx_q])
        if np.isnan(lo) or np.isnan(hi) or lo > hi:
            name = str(model.names[j])
            raise ModelError(f"joint {name!r} has limits lower {lo} > upper {hi}; expected lower <= upper [rad or m]",
                             source=source, name=name)


# A model's own axes, as ``up`` and ``forward`` name them.
AXES = {"x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
        "z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}


def numbers(value: Any, n: int, key: str, unit: str, source: str) -> np.ndarray:
    """n finite numbers [unit], or ModelError naming the key."""
    if (not isinstance(value, (list, tuple)) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)):
        raise ModelError(f"expected {n} numbers [{unit}], got {value!r}", source=source, key=key)
    return np.array(value, float)


def root_rotation(spec: dict[str, Any], source: str) -> np.ndarray:
    """The root's orientation: the model's ``up`` onto the world's z and its ``forward`` onto x, then ``root_rpy``."""
    up = spec.get("up", "z")
    if up not in AXES:
        raise ModelError(f"expected one of {', '.join(AXES)} (the model's own up axis), got {up!r}", source=source,
                         key="up")
    u = np.array(AXES[up])
    # By default the model's x stays forward, or its z for a model whose x is up.
    forward = spec.get("forward", "x" if up not in ("x", "-x") else "z")
    if forward not in AXES or abs(float(np.dot(AXES[forward], u))) > 0.5:
        raise ModelError(f"expected one of {', '.join(a for a in AXES if abs(float(np.dot(AXES[a], u))) < 0.5)} (the "
                         f"model's own forward axis, perpendicular to up {up}), got {forward!r}", source=source,
                         key="forward")
    f = np.array(AXES[forward])
    turn = np.stack([f, np.cross(u, f), u])  # rows: model axes that become the world's x, y, z
    rpy = numbers(spec.get("root_rpy", [0, 0, 0]), 3, "root_rpy", "rad", source)
    return np.asarray(pin.rpy.rpyToMatrix(*rpy) @ turn)


def add_frames(model: pin.Model, frames: Any, source: str) -> None:
    """Frames the spec adds on existing ones (fixed placements: grip points, tool centre points, sole corners)."""
    if not isinstance(frames, dict):
        raise ModelError(f"expected a mapping of name to {{parent, xyz, rpy}}, got {frames!r}", source=source,
                         key="frames")
    for name, raw in frames.items():
        key = f"frames.{name}"
        if not isinstance(raw, dict) or "parent" not in raw or set(raw) - {"parent", "xyz", "rpy"}:
            raise ModelError(f"expected {{parent: FRAME, xyz: [x, y, z], rpy: [r, p, y]}}, got {raw!r}",
                             source=source, key=key)
        if model.existFrame(str(name)):
            raise ModelError(f"the model already has a frame {name!r}; choose another name", source=source, key=key)
        parent = raw["parent"]
        if not isinstance(parent, str) or not model.existFrame(parent):
            known = sorted({str(f.name) for f in model.frames} - {"universe"})
            raise ModelError(f"no frame {parent!r}; frames are: {', '.join(known)}", source=source, key=f"{key}.parent")
        xyz = numbers(raw.get("xyz", [0, 0, 0]), 3, f"{key}.xyz", "m", source)
        rpy = numbers(raw.get("rpy", [0, 0, 0]), 3, f"{key}.rpy", "rad", source)
        pid = model.getFrameId(parent)
        on = model.frames[pid]
        placement = on.placement * pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)
        model.addFrame(pin.Frame(str(name), on.parentJoint, pid, placement, pin.FrameType.OP_FRAME))


def set_reference(model: pin.Model, q: np.ndarray, reference: Any, source: str) -> list[str]:
    """Set q's joints to the reference posture; the notes say which joints zero had to be clipped for."""
    if reference is None or reference in ("zero", "middle", "auto"):
        given: dict[str, Any] = {}
    elif isinstance(reference, dict):
        given = dict(reference)
    else:
        raise ModelError("expected zero, middle, auto or a mapping of joint name to value [rad or m], got "
                         f"{reference!r}", source=source, key="reference")
    names = [str(n) for n in model.names[2:]]
    for name in given:
        if name not in names:
            raise ModelError(f"no such joint; joints are: {', '.join(names)}", source=source, key=f"reference.{name}")
    notes = []
    lower, upper = model.lowerPositionLimit, model.upperPositionLimit
    for j in range(2, model.njoints):
        name, jm = str(model.names[j]), model.joints[j]
        i = jm.idx_q
        if name in given:
            _set_given(q, jm, given[name], lower[i], upper[i], source, name)
        elif jm.nq == 1 and reference in ("middle", "auto"):
            q[i] = 0.5 * (lower[i] + upper[i])
        elif jm.nq == 1 and not lower[i] <= q[i] <= upper[i]:
            clipped = float(np.clip(q[i], lower[i], upper[i]))
            notes.append(f"reference: joint {name!r} at 0 is outside its range [{lower[i]:.6g}, {upper[i]:.6g}]; "
                         f"it stands at {clipped:.6g} (give body.reference to choose)")
            q[i] = clipped
    return notes


def _set_given(q: np.ndarray, jm: Any, value: Any, lower: float, upper: float, source: str, name: str) -> None:
    """One joint's reference value as ``reference`` gives it [rad or m], within its range."""
    i = jm.idx_q
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ModelError(f"expected a number [rad or m], got {value!r}", source=source, key=f"reference.{name}")
    if jm.nq == 2:  # an unbounded revolute, stored as (cos, sin)
        q[i:i + 2] = np.cos(value), np.sin(value)
    elif jm.nq == 1 and not lower - 1e-9 <= value <= upper + 1e-9:
        raise ModelError(f"{value} is outside the joint's range [{lower:.6g}, {upper:.6g}]",
                         source=source, key=f"reference.{name}")
    elif jm.nq == 1:
        q[i] = value


SRDF_MAX_BYTES = 16 * 1024 * 1024  # an SRDF's XML (example-robot-data's are under 100 kB)


def disabled_pairs(srdf: str | Path, model: pin.Model) -> frozenset[frozenset[str]]:
    """The pairs of links an SRDF's ``<disable_collisions link1=... link2=...>`` elements name (MoveIt's convention:
    adjacent links, links that never or always collide), each a link of the model."""
    path = Path(srdf)
    try:
        if path.exists() and not path.is_file():
            raise ModelError("not a regular file: an SRDF is an XML file", source=path, key="srdf")
        if path.stat().st_size > SRDF_MAX_BYTES:
            raise ModelError(f"larger than {SRDF_MAX_BYTES} bytes: not an SRDF", source=path, key="srdf")
        text = path.read_text(encoding="utf-8")
        no_doctype(text, path, "SRDF")
        root = ET.fromstring(text)
    except OSError as exc:
        raise ModelError(f"cannot read the SRDF ({exc.strerror or exc})", source=path, key="srdf") from exc
    except (ET.ParseError, UnicodeDecodeError) as exc:
        raise ModelError(f"not an SRDF (not well-formed XML in UTF-8: {exc})", source=path, key="srdf") from None
    links = {str(f.name) for f in model.frames if f.type == pin.FrameType.BODY}
    out: set[frozenset[str]] = set()
    for k, element in enumerate(root.iter("disable_collisions")):
        pair = [element.get("link1") or "", element.get("link2") or ""]
        for name in pair:
            if name not in links:
                raise ModelError(f"disable_collisions #{k + 1} names link {name!r}, which the URDF does not have "
                                 f"(links: {', '.join(sorted(links))})", source=path, key="srdf")
        out.add(frozenset(pair))
    return frozenset(out)
