"""The seat of a seated human: its dimensions, the seated reference posture, and its boxes.

``body: {human: {sex: female, percentile: 5, posture: seated, seat: {...}}}``.
The seat's keys (metres, degrees), with defaults by ``kind``:

* ``kind``: ``chair`` (an office chair), ``wheelchair`` (a manual wheelchair:
  feet on a footrest, rear wheels beside the pan) or ``car`` (a driver's
  seat: low pan, reclined back, heels forward on the car's floor);
* ``height``: the pan's top above the floor [m], or ``fit`` (a chair's
  default): the body's own, so that the shank falls 10 deg forward of
  vertical to the feet (an adjustable chair set for its sitter, as ANSI/HFES
  100-2007 asks chairs to adjust); ``depth``: front edge to
  backrest [m], or ``fit`` (a chair's default): 5 cm short of the back of
  the knee; ``width`` [m]; ``thickness`` [m] of pan and backrest;
* ``back_angle`` [deg]: the backrest's recline from vertical;
  ``back_height`` [m]: its length up from the pan;
* ``feet``: ``height`` [m] of the surface the soles rest on (a footrest;
  ``fit``, a wheelchair's default: the footrest set so the shank falls 10 deg
  forward), ``x`` [m]: the heels' distance forward of the backrest's foot
  (a driver's heel point; ``fit``, a car's default: where the knee flexes
  35 deg, the angle that seats the 95th-percentile man on SAE J1517's
  95th-percentile seat position line, :func:`j1517_x95`; left out, the shank
  falls from the knee to the floor), ``ankle``
  [deg]: the ankle's flexion with ``x`` (left out, the soles lie flat).

World frame of a seated body: z up, x forward, y to the left, metres; the
origin on the floor (z = 0, where the soles rest unless ``feet.height``
raises them) below the seat's reference point, the line where pan and
backrest meet, on the mid-plane. The pan's top is z = ``height`` for
0 <= x <= ``depth``; the backrest rises from x = 0, leaning back by
``back_angle``.

The seated reference posture (a modelling choice): the trunk lies against
the backrest (reclined by ``back_angle``, the nearest of its capsules
touching the backrest's face), the buttocks rest on the pan (the lowest of
the pelvis's and thighs' capsules touches it), the thighs run level,
forward, at hip width, the shanks fall to the feet (or reach the heel
point, knees up), the head is upright, the upper arms hang 11 deg forward
of vertical with the forearms level over the lap, the elbows 11 deg out.
Frames added: ``right_ischium``/``left_ischium`` on the
pan below each hip joint centre (the pelvis's contact with the seat),
``right_thigh_rest``/``left_thigh_rest`` under the thighs near the pan's
front edge, ``sternum`` on the chest's front on the mid-plane (where a
shoulder belt crosses it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from oracles.bodies import anthropometry as A
from oracles.bodies.anthropometry import Anthropometry
from oracles.bodies.collision import Capsule
from oracles.bodies.environment import Box, turned
from oracles.bodies.human import SEAT_SINK, human_capsules
from oracles.errors import ModelError

# Defaults by kind. chair: ANSI/HFES 100-2007, ch. 8 (seat height adjustable
# within 38-56 cm, depth at most 43 cm, width at least 45 cm, a backrest
# reclining at least 15 deg from vertical). wheelchair: the 1991 ADA
# Accessibility Guidelines, Fig. A3 "Dimensions of adult-sized wheelchairs"
# (seat 19 in = 485 mm high, 26 in = 660 mm wide over the rear wheels), with
# the usual adult seat of 16 in (406 mm) depth and 18 in (457 mm) width, a
# back of 16 in (406 mm) and footrests 2 in (51 mm) above the floor (wheelchair
# fitting guidance, e.g. "Standard wheelchair dimensions", orthopaedicprinciples.com).
# car: a mid-size saloon's driver's seat, chosen, not measured: pan 0.20 m over
# the heel plane (H-point near 0.27 m, SAE J1100's H30), back 23 deg (SAE J1100's
# A40 is typically 22-25 deg), heels 0.85 m forward.
KINDS: dict[str, dict[str, Any]] = {
    "chair": {"height": "fit", "depth": "fit", "width": 0.48, "back_angle": 15.0, "back_height": 0.50, "feet": {}},
    "wheelchair": {"height": 0.485, "depth": 0.406, "width": 0.457, "back_angle": 10.0, "back_height": 0.406,
                   "feet": {"height": "fit"}},
    "car": {"height": 0.20, "depth": 0.50, "width": 0.50, "back_angle": 23.0, "back_height": 0.60,
            "feet": {"x": "fit", "ankle": -10.0}},
}
SEAT_KEYS = {"kind", "height", "depth", "width", "thickness", "back_angle", "back_height", "feet"}
FEET_KEYS = {"height", "x", "ankle"}
SHANK_FORWARD = math.radians(10.0)  # the shank's lean forward of vertical where a seat is fitted (modelling choice)
# Knee flexion where a car's heel point is fitted. SAE J1517's Class A driver-selected seat position lines give where
# drivers put the H-point, by percentile of a 50:50 population, against the seat height H30 (j1517_x95). At the car
# seat's H30 (274-277 mm for the shipped bodies) the 95th-percentile line lies 853 mm behind the heel point; the
# 95th-percentile man's hip joint (the H-point) lies on it with the knee flexed 35 deg (bench/validation.py): the angle
# every driver is fitted with. It was 60 deg before (a modelling choice): the drivers sat 85-105 mm closer
# ("drivers sit about 10 cm too close"). Only the 95th-percentile line could be read (j1517_x95), and the
# 95th percentile of a 50:50 population's seat positions is about, not exactly, the 95th-percentile man's; a shorter
# driver is placed by the same knee angle, not by a line of her own (J4004's stature model was not readable here).
DRIVER_KNEE = math.radians(35.0)
# A driver whose calf would press into the cushion's front edge at DRIVER_KNEE (a short thigh on the car's 0.50 m pan:
# two of the female boundary manikins, by 6 and 10 mm) is fitted with the knee flexed KNEE_STEP more at a time, up to
# KNEE_MOST: a short-thighed driver sits closer (modelling choices; 60 deg was the earlier fit).
KNEE_STEP, KNEE_MOST = math.radians(5.0), math.radians(60.0)
# Between the pan's front edge and the back of the knee, where a seat's depth is fitted: about
# three fingers' breadth, the clearance wheelchair fitting guides ask for (2 in, orthopaedicprinciples.com).
POPLITEAL_CLEARANCE = 0.05
FIT = float("nan")  # a dimension fitted to the body (see ``fit``)
# a 24 in rear wheel, the usual adult size (ADAAG Fig. A3's 26 in overall width fits two beside an 18 in seat)
WHEEL_DIAMETER = 0.61
ARM_FORWARD = 0.2  # [rad] upper arm forward of vertical in the seated reference (modelling choice)
ARM_OUT = 0.2  # [rad] upper arm abducted so that it hangs clear of the reclined abdomen (modelling choice)
ELBOW = 1.3  # [rad] elbow flexion in the seated reference: forearm about level over the lap (modelling choice)


def j1517_x95(h30: float) -> float:
    """SAE J1517's Class A 95th-percentile driver-selected seat position [m]: the H-point's distance behind the
    accelerator heel point (AHP) at a seat height ``h30`` [m] (the H-point above the AHP).

    The line is X95 = 913.7 + 0.672316 z - 0.0019553 z^2 [mm] behind the ball-of-foot reference point, z = H30 [mm];
    the ball of foot lies 203 cos(PPA) mm ahead of the heel, the pedal plane's angle PPA = 78.96 - 0.15 z' - 0.0173 z'^2
    [deg], z' = H30 [cm]. The equations as quoted by a public vehicle-packaging script (github.com/Commuter-Cars/
    CodeMonkeys, Primary_18.m, citing J1517): a secondary source; the standard itself was not read here. It gives
    857 mm at H30 = 271 mm, the figure another secondary source gives.
    """
    z = 1000.0 * h30
    ppa = math.radians(78.96 - 0.15 * (z / 10.0) - 0.0173 * (z / 10.0) ** 2)
    return (913.7 + 0.672316 * z - 0.0019553 * z * z - 203.0 * math.cos(ppa)) / 1000.0


@dataclass(frozen=True)
class Seat:
    """A seat's dimensions [m, rad] (see the module docstring)."""

    kind: str = "chair"
    height: float = 0.45
    depth: float = 0.43
    width: float = 0.48
    back_angle: float = math.radians(15.0)
    back_height: float = 0.50
    thickness: float = 0.06
    feet_height: float = 0.0
    feet_x: float | None = None
    ankle: float | None = None
    knee: float = DRIVER_KNEE  # [rad] the knee's flexion where a heel point is fitted (feet_x: fit)


@dataclass(frozen=True)
class Seated:
    """The seated reference posture: root position [m] and pitch [rad], joint values [rad], frames to add
    (name -> (parent frame, world point [m])) and the seat's boxes."""

    root: np.ndarray
    pitch: float
    joints: dict[str, float]
    frames: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)
    furniture: tuple[Box, ...] = ()
    thigh_under: float = 0.0  # [m] the thigh capsules moved this far to the thigh's back, onto the pan

    def capsules(self, capsules: list[Capsule]) -> list[Capsule]:
        """The body's capsules as it sits: the thighs' moved ``thigh_under`` to their back (the thigh link's -x)."""
        back = np.array([-self.thigh_under, 0.0, 0.0])
        return [replace(c, a=tuple(np.add(c.a, back)), b=tuple(np.add(c.b, back)))  # type: ignore[arg-type]
                if c.name.endswith("_thigh") else c for c in capsules]


def _number(value: Any, key: str, lo: float, hi: float, unit: str) -> float:
    if value == "fit":
        return FIT
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise ModelError(f"expected a number in [{lo}, {hi}] {unit} or fit, got {value!r}", source="human", key=key)
    return float(value)


def parse_seat(raw: Any) -> Seat:
    """A seat from ``human.seat`` (a mapping; None for a chair's defaults)."""
    raw = {} if raw is None else raw
    if not isinstance(raw, dict) or set(raw) - SEAT_KEYS:
        raise ModelError(f"expected a mapping with keys among {sorted(SEAT_KEYS)}, got {raw!r}", source="human",
                         key="human.seat")
    kind = raw.get("kind", "chair")
    if kind not in KINDS:
        raise ModelError(f"expected one of {', '.join(KINDS)}, got {kind!r}", source="human", key="human.seat.kind")
    given = {**KINDS[kind], **{k: v for k, v in raw.items() if k != "feet"}}
    feet = {**KINDS[kind]["feet"], **(raw.get("feet") or {})}
    if not isinstance(raw.get("feet", {}), dict) or set(feet) - FEET_KEYS:
        raise ModelError(f"expected a mapping with keys among {sorted(FEET_KEYS)}, got {raw.get('feet')!r}",
                         source="human", key="human.seat.feet")
    k = "human.seat."
    return Seat(
        kind, _number(given["height"], k + "height", 0.05, 1.2, "m"),
        _number(given["depth"], k + "depth", 0.2, 0.8, "m"),
        _number(given["width"], k + "width", 0.3, 1.0, "m"),
        math.radians(_number(given["back_angle"], k + "back_angle", 0.0, 40.0, "deg")),
        _number(given["back_height"], k + "back_height", 0.1, 1.0, "m"),
        _number(given.get("thickness", 0.06), k + "thickness", 0.01, 0.2, "m"),
        _number(feet.get("height", 0.0), k + "feet.height", 0.0, 0.5, "m"),
        None if feet.get("x") is None else _number(feet["x"], k + "feet.x", 0.1, 1.5, "m"),
        None if feet.get("ankle") is None
        else math.radians(_number(feet["ankle"], k + "feet.ankle", -50.0, 20.0, "deg")),
    )


def _pitch(angle: float) -> np.ndarray:
    """Rotation about y by ``angle`` [rad] (a positive angle takes +z towards +x)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _down_angle(v: np.ndarray) -> float:
    """Angle [rad] of a sagittal vector from straight down, positive forward."""
    return math.atan2(float(v[0]), float(-v[2]))


def seated(body: Anthropometry, seat: Seat) -> Seated:
    """The seated reference posture of a body on a seat (see the module docstring)."""
    L = body.lengths
    caps = {c.name: c for c in human_capsules(body)}
    seat = fit(body, seat, caps)
    beta = seat.back_angle
    up = np.array([-math.sin(beta), 0.0, math.cos(beta)])  # along the backrest, upwards
    normal = np.array([math.cos(beta), 0.0, math.sin(beta)])  # out of the backrest, forwards
    trunk = _pitch(-beta)
    # The trunk's back: the deepest of its capsules behind the pelvis's axis.
    hip_z = seat.height + _hip_above_pan(caps, beta, body.place)
    thigh = caps["right_thigh"]
    hip_x = _hip_forward(caps, L, seat, body.place)
    hip = np.array([hip_x, 0.0, hip_z])
    lt, ls, lf = L["thigh"], L["shank"], L["foot"]
    ankle_z = body.ankle_height
    heel_to_ankle = np.array([A.ANKLE_FROM_HEEL * lf, 0.0, ankle_z])

    def legs(ankle: np.ndarray) -> tuple[float, float]:
        """Thigh and shank angles from straight down [rad], knee up."""
        d = ankle - hip
        dist = float(np.linalg.norm(d))
        if dist > lt + ls - 1e-3:
            raise ModelError(f"the heels {seat.feet_x} m forward are out of this body's reach from the seat (hip to "
                             f"ankle {dist:.3f} m, legs {lt + ls:.3f} m): bring human.seat.feet.x back",
                             source="human", key="human.seat.feet.x")
        alpha = math.acos(max(-1.0, min(1.0, (lt * lt + dist * dist - ls * ls) / (2 * lt * dist))))
        e = d / dist
        knee_dir = np.array([e[0] * math.cos(alpha) - e[2] * math.sin(alpha), 0.0,
                             e[0] * math.sin(alpha) + e[2] * math.cos(alpha)])
        knee = hip + lt * knee_dir
        return _down_angle(knee - hip), _down_angle(ankle - knee)

    sole_z = seat.feet_height
    if seat.feet_x is None:
        drop = hip_z - (sole_z + ankle_z)
        if drop > ls:
            raise ModelError(f"the pan {seat.height} m high is above this body's lower leg (the shank, {ls:.3f} m, "
                             f"would leave the feet {drop - ls:.3f} m above their rest): lower human.seat.height or "
                             "raise human.seat.feet.height", source="human", key="human.seat.height")
        theta_t, theta_s = math.pi / 2, math.asin(math.sqrt(max(ls * ls - drop * drop, 0.0)) / ls)
        ankle_flex = -theta_s
        heel = hip + np.array([lt + ls * math.sin(theta_s), 0.0, -ls * math.cos(theta_s)]) - heel_to_ankle
    else:
        # The sole pitches toe-up by the shank's angle plus the ankle's flexion, which moves the ankle about the heel:
        # iterate.
        ankle_flex = 0.0 if seat.ankle is None else seat.ankle
        # The knee flexed seat.knee where the heel point is fitted: hip to ankle is the triangle's third side.
        reach = math.sqrt(lt * lt + ls * ls + 2 * lt * ls * math.cos(seat.knee))
        heel = np.array([0.0 if math.isnan(seat.feet_x) else seat.feet_x, 0.0, sole_z])
        toe_up = 0.0
        for _ in range(50):
            to_ankle = _pitch(-toe_up) @ heel_to_ankle
            if math.isnan(seat.feet_x):
                rise = hip_z - (sole_z + to_ankle[2])
                if reach <= rise:
                    raise ModelError(f"the pan {seat.height} m high is too high to fit a heel point with the knee "
                                     f"flexed {math.degrees(seat.knee):g} deg: "
                                     "give human.seat.feet.x", source="human", key="human.seat.feet.x")
                heel[0] = hip_x + math.sqrt(reach * reach - rise * rise) - to_ankle[0]
            theta_t, theta_s = legs(heel + to_ankle)
            if seat.ankle is None:
                ankle_flex = -theta_s
            toe_up = theta_s + ankle_flex
    hip_flex, knee_flex = theta_t - beta, theta_t - theta_s
    joints = {"neck_flexion": beta}
    for side in ("right", "left"):
        joints.update({f"{side}_hip_flexion": hip_flex, f"{side}_knee_flexion": knee_flex,
                       f"{side}_ankle_flexion": ankle_flex,
                       f"{side}_shoulder_flexion": ARM_FORWARD - beta, f"{side}_shoulder_abduction": ARM_OUT,
                       f"{side}_elbow_flexion": ELBOW})
    for name, value in joints.items():
        lo, hi = A.RANGES[name.removeprefix("right_").removeprefix("left_")]
        if not lo - 1e-9 <= value <= hi + 1e-9:
            raise ModelError(f"seated on this seat, {name} would be {math.degrees(value):.1f} deg, outside its range "
                             f"[{math.degrees(lo):.0f}, {math.degrees(hi):.0f}] deg: change human.seat's back_angle, "
                             "height or feet", source="human", key="human.seat")

    thigh_dir = np.array([math.sin(theta_t), 0.0, -math.cos(theta_t)])
    under = np.array([thigh_dir[2], 0.0, -thigh_dir[0]])  # the thigh's underside, perpendicular to it
    # The thighs rest on the pan: where the capsule's radius (the thigh's mean girth) is less than the hips' height
    # over it, the soft tissue a hard seat spreads lies under the thigh, not around it, and the capsule moves to the
    # thigh's back by the gap (ANSUR II: 31 of 50 subjects' thighs floated over 5 mm, up to 52 mm).
    thigh_under = max(_thigh_gap(hip, thigh_dir, thigh.radius, lt, seat) / max(-under[2], 0.1), 0.0)
    along = min(0.75 * lt, max(seat.depth - 0.03 - hip_x, 0.05) / max(thigh_dir[0], 0.1))
    frames: dict[str, tuple[str, np.ndarray]] = {}
    for side, s in (("right", -1.0), ("left", 1.0)):
        y = s * body.place.hip_y
        frames[f"{side}_ischium"] = ("pelvis", np.array([hip_x, y, seat.height]))
        frames[f"{side}_thigh_rest"] = (f"{side}_thigh", hip + along * thigh_dir + (thigh.radius + thigh_under) * under
                                        + np.array([0.0, y, 0.0]))
    chest = body.girths["chest_depth"]
    sternum_local = np.array([-body.place.back_depth + chest, 0.0,
                              L["lower_trunk"] + L["middle_trunk"] + 0.5 * L["upper_trunk"]])
    frames["sternum"] = ("thorax", hip + trunk @ sternum_local)
    return Seated(hip, -beta, joints, frames, furniture(seat, up, normal, heel), thigh_under)


def _thigh_gap(hip: np.ndarray, direction: np.ndarray, radius: float, length: float, seat: Seat) -> float:
    """How far [m] the thigh capsule's underside stays above the pan where it lies over it (its axis from the hip
    along ``direction`` for ``length``)."""
    along = np.linspace(0.0, length, 101)
    x, z = hip[0] + along * direction[0], hip[2] + along * direction[2]
    over = (x >= 0.0) & (x <= seat.depth)
    return float(z[over].min() - radius - seat.height) if over.any() else 0.0


def _hip_above_pan(caps: dict[str, Any], beta: float, place: A.Placement | None = None) -> float:
    """The hip joint centres' height [m] above the pan: a measured body's where its sitting height puts them, a
    de_leva body's where the lowest of the pelvis's and thighs' capsules rests on it."""
    pelvis, thigh = caps["pelvis"], caps["right_thigh"]
    lowest_pelvis = float((_pitch(-beta) @ np.asarray(pelvis.a))[2]) - pelvis.radius
    if place is not None and place.hip_above_seat is not None:
        # Reclined, the pelvis rolls back onto the sacrum: its capsule may lift the hips above their upright height.
        return max(place.hip_above_seat, -lowest_pelvis - SEAT_SINK)
    return max(thigh.radius, -lowest_pelvis)


def _hip_forward(caps: dict[str, Any], lengths: dict[str, float], seat: Seat, place: A.Placement) -> float:
    """The hip joint centres' distance [m] forward of the backrest's foot where the trunk's capsules touch the
    backrest's
    front face (a segment in the mid-plane; the trunk's capsules lie across the body): bisection on the least gap."""
    above = _hip_above_pan(caps, seat.back_angle, place)
    base = {"pelvis": 0.0, "abdomen": lengths["lower_trunk"],
            "thorax": lengths["lower_trunk"] + lengths["middle_trunk"]}
    trunk = _pitch(-seat.back_angle)
    up = np.array([-math.sin(seat.back_angle), 0.0, math.cos(seat.back_angle)])
    foot = np.array([0.0, 0.0, seat.height])
    circles = [(trunk @ (0.5 * (np.asarray(c.a) + np.asarray(c.b)) + np.array([0.0, 0.0, base[c.link]])), c.radius)
               for c in caps.values() if c.link in base]

    def gap(x: float) -> float:
        hip = np.array([x, 0.0, seat.height + above])
        out = np.inf
        for centre, r in circles:
            p = hip + centre
            t = min(max(float((p - foot) @ up), 0.0), seat.back_height)
            out = min(out, float(np.linalg.norm(p - foot - t * up)) - r)
        return out

    lo, hi = -0.2, 0.6
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap(mid) < 0.0 else (lo, mid)
    return hi


def fit(body: Anthropometry, seat: Seat, caps: dict[str, Any] | None = None) -> Seat:
    """The seat with its ``fit`` dimensions set for this body (see the module docstring)."""
    caps = caps or {c.name: c for c in human_capsules(body)}
    ls, lt, ankle_z = body.lengths["shank"], body.lengths["thigh"], body.ankle_height
    above = _hip_above_pan(caps, seat.back_angle, body.place)
    drop = ls * math.cos(SHANK_FORWARD) + ankle_z  # hip to sole with level thighs and the shank 10 deg forward
    if math.isnan(seat.height):
        seat = replace(seat, height=round(seat.feet_height + drop - above, 4))
    if math.isnan(seat.depth):
        popliteal = _hip_forward(caps, body.lengths, seat, body.place) + lt - caps["right_shank"].radius
        seat = replace(seat, depth=round(popliteal - POPLITEAL_CLEARANCE, 4))
    if math.isnan(seat.feet_height):
        rest = seat.height + above - drop
        if rest < 0.0:
            raise ModelError(f"the pan {seat.height} m high is below this body's lower leg (the feet would rest "
                             f"{-rest:.3f} m under the floor): "
                             "raise human.seat.height", source="human", key="human.seat.height")
        seat = replace(seat, feet_height=round(rest, 4))
    return seat


def furniture(seat: Seat, up: np.ndarray, normal: np.ndarray, heel: np.ndarray) -> tuple[Box, ...]:
    """The seat's boxes: pan and backrest, and for a wheelchair its rear wheels and footrest."""
    t, w = seat.thickness, 0.5 * seat.width
    boxes = [Box((0.0, -w, seat.height - t), (seat.depth, w, seat.height), name="seat_pan")]
    centre = np.array([0.0, 0.0, seat.height]) + 0.5 * seat.back_height * up - 0.5 * t * normal
    half = np.array([0.5 * t, w, 0.5 * seat.back_height])
    boxes.append(turned(centre - half, centre + half, (0.0, -seat.back_angle, 0.0), "backrest"))
    if seat.kind == "wheelchair":
        r = 0.5 * WHEEL_DIAMETER
        for side, s in (("right", -1.0), ("left", 1.0)):
            inner = w + 0.04
            lo, hi = sorted((s * inner, s * (inner + 0.03)))
            boxes.append(Box((-r, lo, 0.0), (r, hi, 2 * r), name=f"{side}_wheel"))
        top = seat.feet_height
        boxes.append(Box((float(heel[0]) - 0.05, -w, top - 0.02), (float(heel[0]) + 0.30, w, top), name="footrest"))
    return tuple(boxes)
