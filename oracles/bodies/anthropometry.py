"""Anthropometric tables and their scaling to a body of given sex, stature and mass.

Sources, cited where each number is used:

* Segment lengths, masses and centre-of-mass positions: de Leva, P. (1996).
  *Adjustments to Zatsiorsky-Seluyanov's segment inertia parameters.*
  Journal of Biomechanics 29(9), 1223-1230, **Table 4** (lengths in mm of
  the reference subjects, masses in % of body mass, CoM in % of segment
  length from the proximal/cranial end point).
* Proportions de Leva does not give (ankle height, shoulder, hip and eye
  positions, foot breadth): Drillis, R. & Contini, R. (1966), *Body segment
  parameters*, Report 1166-03, New York University, as reproduced in Winter,
  D.A. (2009), *Biomechanics and Motor Control of Human Movement*, 4th ed.,
  **Figure 4.1** (segment lengths as fractions of stature H).
* Measured people: Gordon, C.C. et al. (2014), *2012 Anthropometric Survey
  of U.S. Army Personnel (ANSUR II)*, NATICK/TR-15/007, its public data
  carried in ``data/`` (:mod:`oracles.bodies.ansur`). A body is built from
  its dimensions (given, a subject's, or regressed on those given: by
  default on stature alone); each landmark's joint centre is set below.
  Stature at a percentile assumes a normal distribution (the report's mean
  and SD).
* Joint ranges of motion: American Academy of Orthopaedic Surgeons (1965),
  *Joint Motion: Method of Measuring and Recording*, as tabulated in Norkin,
  C.C. & White, D.J. (2016), *Measurement of Joint Motion*, 5th ed.,
  **Appendix A**; sternoclavicular ranges from Kapandji, I.A. (2007), *The
  Physiology of the Joints*, vol. 1 (clavicle elevation 45 deg, depression
  10 deg, protraction 15 deg, retraction 30 deg).

All lengths here are metres, angles radians, masses kilograms.

Two builds (``proportions``): ``ansur`` (the default) from measured
dimensions; ``de_leva``, the stature-scaled body of earlier versions (every
segment de Leva's reference scaled by stature), kept so that trees built
with it still refine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any, Literal

from oracles.bodies import ansur
from oracles.errors import ModelError

Sex = Literal["male", "female"]

# de Leva (1996) Table 4: reference subject stature [mm] and mass [kg].
REFERENCE = {"male": (1741.0, 73.0), "female": (1735.0, 61.9)}

# de Leva (1996) Table 4: segment -> (length [mm], mass [% body mass],
# CoM [% of length from the first named end point]).
# Trunk parts: upper (CERV-XYPH), middle (XYPH-OMPH), lower (OMPH-MIDH);
# head from VERT to CERV; hand from WJC to MET3; foot from HEEL to TTIP.
DE_LEVA: dict[str, dict[str, tuple[float, float, float]]] = {
    "male": {
        "head": (242.9, 6.94, 59.76),
        "upper_trunk": (242.1, 15.96, 29.99),
        "middle_trunk": (215.5, 16.33, 45.02),
        "lower_trunk": (145.7, 11.17, 61.15),
        "upper_arm": (281.7, 2.71, 57.72),
        "forearm": (268.9, 1.62, 45.74),
        "hand": (86.2, 0.61, 79.00),
        "thigh": (422.2, 14.16, 40.95),
        "shank": (434.0, 4.33, 44.59),
        "foot": (258.1, 1.37, 44.15),
    },
    "female": {
        "head": (243.7, 6.68, 58.94),
        "upper_trunk": (228.0, 15.45, 20.77),
        "middle_trunk": (205.3, 14.65, 45.12),
        "lower_trunk": (181.5, 12.47, 49.20),
        "upper_arm": (275.1, 2.55, 57.54),
        "forearm": (264.3, 1.38, 45.59),
        "hand": (78.0, 0.56, 74.74),
        "thigh": (368.5, 14.78, 36.12),
        "shank": (432.3, 4.81, 44.16),
        "foot": (228.3, 1.29, 40.14),
    },
}

# ANSUR II (Gordon et al. 2014): stature mean and SD [mm], mean body mass [kg].
ANSUR_STATURE = {"male": (1756.3, 68.6), "female": (1628.5, 64.2)}
ANSUR_MASS = {"male": 85.5, "female": 67.8}
# ANSUR II thumb-tip reach, mean and SD [mm] (the validation target).
ANSUR_THUMBTIP_REACH = {"male": (811.9, 43.7), "female": (744.0, 42.8)}

# ANSUR II (Gordon et al. 2014), summary statistics: means [mm] of the
# breadths, depths and circumferences that size the collision capsules
# (oracles.bodies.collision). Values rounded to the millimetre; they scale with
# stature like the lengths (isometric scaling).
ANSUR_GIRTHS: dict[str, dict[str, float]] = {
    "male": {
        "chest_breadth": 332.0, "chest_depth": 255.0, "waist_breadth": 320.0, "waist_depth": 235.0,
        "hip_breadth": 357.0, "biceps_circumference_flexed": 357.0, "forearm_circumference_flexed": 309.0,
        "wrist_circumference": 175.0, "thigh_circumference": 626.0, "calf_circumference": 394.0,
        "head_breadth": 156.0, "head_length": 200.0, "neck_circumference": 398.0, "hand_breadth": 89.0,
    },
    "female": {
        "chest_breadth": 299.0, "chest_depth": 238.0, "waist_breadth": 296.0, "waist_depth": 213.0,
        "hip_breadth": 354.0, "biceps_circumference_flexed": 310.0, "forearm_circumference_flexed": 257.0,
        "wrist_circumference": 152.0, "thigh_circumference": 612.0, "calf_circumference": 364.0,
        "head_breadth": 148.0, "head_length": 189.0, "neck_circumference": 331.0, "hand_breadth": 78.0,
    },
}

# Drillis & Contini (1966) / Winter (2009) Fig. 4.1: fractions of stature H.
ANKLE_HEIGHT = 0.039  # floor to lateral malleolus
EYE_HEIGHT = 0.936
FOOT_BREADTH = 0.055
# Modelling choices (not from the tables): lateral offsets of the joint
# centres and the depth of the shoulder behind which the back lies, as
# fractions of H. They set the shoulder breadth (0.20 H between shoulder
# centres) and hip breadth (0.10 H between hip centres).
SHOULDER_Y = 0.100
STERNOCLAVICULAR_Y = 0.015
SHOULDER_BELOW_CERV = 0.080
SHOULDER_BACK_DEPTH = 0.080  # back of the shoulders, behind the shoulder centre
HIP_Y = 0.050
EYE_FORWARD = 0.055
EYE_Y = 0.018
# de_leva bodies' grip (their one hand frame): beyond MET3 and palmar of the
# hand's long axis, 1.40 and 0.25 hand lengths (WJC-MET3) from the wrist: a
# pinch point more than a grip (docs/decisions/0015), kept for trees built with it.
GRIP_ALONG = 1.40
GRIP_PALMAR = 0.25
# Foot points, fractions of foot length from the heel: the ankle (LMAL)
# projects at 0.22, the ball (metatarsal heads) at 0.73, the toe tip at 1.
ANKLE_FROM_HEEL = 0.22
BALL_FROM_HEEL = 0.73


def _deg(lo: float, hi: float) -> tuple[float, float]:
    return (math.radians(lo), math.radians(hi))


# Joint ranges [rad], (lower, upper), positive in the anatomical direction
# the joint's name gives. AAOS (1965) via Norkin & White (2016) Appendix A,
# clavicle from Kapandji (2007). The thoraco-lumbar totals (flexion 80,
# extension 25, lateral bending 35, rotation 45 deg) are split between the
# lumbar and thoracic joints of the model.
RANGES: dict[str, tuple[float, float]] = {
    "lumbar_flexion": _deg(-15, 60),
    "lumbar_lateral": _deg(-35, 35),
    "thoracic_flexion": _deg(-10, 20),
    "thoracic_rotation": _deg(-45, 45),
    "neck_flexion": _deg(-45, 45),
    "neck_rotation": _deg(-60, 60),
    "clavicle_elevation": _deg(-10, 45),
    "clavicle_protraction": _deg(-30, 15),
    "shoulder_flexion": _deg(-60, 180),
    "shoulder_abduction": _deg(-30, 180),
    "shoulder_rotation": _deg(-90, 70),  # external (-) / internal (+)
    "elbow_flexion": _deg(0, 150),
    "forearm_pronation": _deg(-80, 80),  # supination (-) / pronation (+)
    "wrist_flexion": _deg(-70, 80),
    "wrist_deviation": _deg(-30, 20),  # ulnar (-) / radial (+)
    "hip_flexion": _deg(-30, 120),
    "hip_abduction": _deg(-30, 45),
    "hip_rotation": _deg(-45, 45),
    "knee_flexion": _deg(0, 135),
    "ankle_flexion": _deg(-50, 20),  # plantarflexion (-) / dorsiflexion (+)
    "ankle_inversion": _deg(-15, 35),
}


# -- measured bodies: landmark to joint centre ---------------------------------------------------------------------
# Knee: the flexion axis runs close to the femur's transepicondylar axis (Churchill, D.L. et al. 1998, "The
# transepicondylar axis approximates the optimal flexion axis of the knee", Clin. Orthop. 356:111-118; not read in
# its source here), so the knee centre is at ANSUR's lateral femoral epicondyle height.
# Ankle: the talocrural axis passes just below the tips of the malleoli (Inman, V.T. 1976, *The Joints of the
# Ankle*; not read in its source here): the ankle centre is at the lateral malleolus height.
# Hip: the tip of the greater trochanter lies level with the centre of the femoral head (the clinical landmark of hip
# arthroplasty; as quoted, not read in a source here): the hip centre is at ANSUR's trochanterion height.
# Shoulder: the glenohumeral centre 40 mm below the acromion. Of the survey's measures only the overhead fingertip
# reach sitting sets this depth (the thumb-tip reach, span and wrist height are met whatever it is): 40 mm brings the
# model's overhead reach, arm and shoulder girdle free within their ranges, within 12-20 mm of the survey's at the
# stature percentiles (bench/validation.py). Rab, G., Petuskey, K. & Bagley, A. (2002), Gait & Posture 15:113-119, put
# it 17 % of the biacromial breadth below the acromion marker (as quoted, not read in its source here): 71 mm for the
# 50th-percentile man, which left the overhead reach 59 mm short (docs/decisions/0015).
SJC_BELOW_ACROMION = 0.040  # [m]
# Elbow and wrist: the elbow centre at radiale, the wrist centre at stylion (modelling choices: both landmarks lie
# within about a centimetre of the joints' axes). The hanging arm then puts the wrist within 10 mm of ANSUR's mean
# wrist height (men 837 against 847.5 mm; computed from the carried data).
# Hand (wrist crease at the wrist centre): the grip centre, the axis of a rod held in the fist, lies hand length minus
# (forearm-hand length minus forearm-centre-of-grip length) past the wrist: ANSUR II's own measures (men 62 +- 7 mm,
# women 59 +- 7 mm, from the carried data). The pinch (thumb tip against the index finger) at 65 % of hand length
# (Drillis & Contini 1966, as quoted by a secondary source: not read in its source here); the middle fingertip at
# hand length.
PINCH_ALONG = 0.65
# The grip and pinch palmar of the hand's long axis by a quarter of the WJC-MET3 length (modelling choice: a rod's
# axis lies in the closed fist, in front of the metacarpals).
HAND_PALMAR = 0.25
# de Leva's hand (WJC to MET3, Table 4) as a share of hand length (wrist crease to fingertip): his reference subjects'
# 86.2 / 78.0 mm over ANSUR II's mean hand lengths 193.3 / 181.1 mm (men / women), for the palm's inertia only.
MET3_SHARE = {"male": 86.2 / 193.3, "female": 78.0 / 181.1}
# The capsules' sizes by ANSUR II's names (Anthropometry.girths keys).
GIRTH_NAMES = {
    "chest_breadth": "chestbreadth", "chest_depth": "chestdepth", "waist_breadth": "waistbreadth",
    "waist_depth": "waistdepth", "hip_breadth": "hipbreadth",
    "biceps_circumference_flexed": "bicepscircumferenceflexed",
    "forearm_circumference_flexed": "forearmcircumferenceflexed", "wrist_circumference": "wristcircumference",
    "thigh_circumference": "thighcircumference", "calf_circumference": "calfcircumference",
    "head_breadth": "headbreadth", "head_length": "headlength", "neck_circumference": "neckcircumference",
    "hand_breadth": "handbreadth",
}
PROPORTIONS = ("ansur", "de_leva")


@dataclass(frozen=True)
class Placement:
    """Where joint centres and frames sit, from the body's landmarks [m].

    ``sjc_below_cerv``: shoulder centres below C7 (cervicale); ``shoulder_y``: a shoulder centre's distance from
    the mid-plane; ``back_depth``: the back of the shoulders behind the shoulder centres (the wall of a thumb-tip
    reach); ``hip_y``: a hip centre from the mid-plane; ``eye_height``: standing; ``grip``, ``pinch``,
    ``fingertip``: along the hand from the wrist centre, ``palmar``: the grip's and pinch's depth in front of the
    hand's axis; ``hip_above_seat``: the hip centres above a hard flat seat, ``buttock_back``: the buttocks behind
    the hip centres, seated, ``knee_front``: the front of the knee ahead of its centre (None for de_leva bodies: their
    seat contact is their capsules'); ``acromion``: the acromion above the shoulder centre; ``acromion_y``: an
    acromion's lateral tip from the mid-plane, ``olecranon``: the elbow's underside (flexed 90 deg) below radiale
    (None for de_leva bodies: they have no acromion frames).
    """

    sjc_below_cerv: float
    shoulder_y: float
    back_depth: float
    hip_y: float
    eye_height: float
    grip: float
    pinch: float
    fingertip: float
    palmar: float
    acromion: float
    hip_above_seat: float | None = None
    buttock_back: float | None = None
    knee_front: float | None = None
    acromion_y: float | None = None
    olecranon: float | None = None


@dataclass(frozen=True)
class Anthropometry:
    """Segment dimensions [m] and masses [kg] of one body.

    ``lengths`` and ``com`` (fraction from the proximal end) are keyed by the
    de Leva segment names; ``masses`` likewise. ``dims``: every ANSUR II
    dimension as built (metres, ``weightkg`` in kg); ``asked``: those given;
    ``spread``: each dimension's residual SD given the asked ones (0 for an
    asked one).
    """

    sex: Sex
    stature: float
    mass: float
    lengths: dict[str, float]
    masses: dict[str, float]
    com: dict[str, float]
    girths: dict[str, float]  # [m]
    ankle_height: float
    place: Placement
    proportions: str
    dims: dict[str, float] = field(default_factory=dict)
    asked: dict[str, float] = field(default_factory=dict)
    spread: dict[str, float] = field(default_factory=dict)


def stature_at_percentile(sex: Sex, percentile: float) -> float:
    """Stature [m] at a percentile of the ANSUR II distribution (normal)."""
    if not 0.0 < percentile < 100.0:
        raise ModelError(f"percentile must be in (0, 100), got {percentile}", name="percentile")
    mean, sd = ANSUR_STATURE[sex]
    return NormalDist(mean, sd).inv_cdf(percentile / 100.0) / 1000.0


def anthropometry(sex: Sex = "male", stature: float | None = None, percentile: float | None = None,
                  mass: float | None = None, dims: dict[str, float] | None = None, subject: int | None = None,
                  proportions: str = "ansur") -> Anthropometry:
    """Dimensions of a body: measured (``proportions: ansur``) or scaled from de Leva's reference (``de_leva``).

    Args:
        sex: ``male`` or ``female``.
        stature: Standing height [m]; exclusive with percentile.
        percentile: Stature percentile of ANSUR II; default 50 when no stature, dimension or subject is given.
        mass: Body mass [kg] (ANSUR II's ``weightkg``).
        dims: ANSUR II dimensions by name [m] (:data:`oracles.bodies.ansur.COLUMNS`).
        subject: An ANSUR II subject id of that sex: its measures, under any given above.
        proportions: ``ansur`` or ``de_leva`` (stature and mass only).

    An ``ansur`` body's dimensions not given are ANSUR II's regression on those given (:mod:`oracles.bodies.ansur`);
    the URDF puts its joint centres where the landmarks imply (this module's constants, each with its source).
    """
    _check_asked(sex, stature, percentile, mass, proportions)
    if proportions == "de_leva":
        if dims or subject is not None:
            raise ModelError("de_leva proportions scale stature alone: no dimensions or subject",
                             key="human.proportions")
        return _de_leva(sex, stature, percentile, mass)
    survey = ansur.sample(sex)
    given: dict[str, float] = dict(survey.subject(subject)) if subject is not None else {}
    asked = _asked_dims(sex, stature, percentile, mass, dims or {}, subject is None)
    for name, value in asked.items():
        key = "stature" if name == "stature" else "mass" if name == ansur.MASS else name
        try:
            survey.check(name, value)
        except ModelError as exc:
            raise ModelError(str(exc).split(": ", 1)[-1], key=f"human.{key}") from None
    given.update(asked)
    dims_built, spread = survey.predict(given)
    return _measured(sex, dims_built, asked if subject is None else given, spread)


def _check_asked(sex: str, stature: Any, percentile: Any, mass: Any, proportions: str) -> None:
    """The sex, stature, percentile, mass and proportions asked for, or ModelError naming the key."""
    if sex not in DE_LEVA:
        raise ModelError(f"sex must be 'male' or 'female', got {sex!r}", name="sex")
    for key, value, unit in (("stature", stature, "m"), ("percentile", percentile, ""), ("mass", mass, "kg")):
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise ModelError(f"expected a number{' in ' + unit if unit else ''}, got {value!r}", key=f"human.{key}")
    if stature is not None and percentile is not None:
        raise ModelError("give stature or percentile, not both", name="stature")
    if proportions not in PROPORTIONS:
        raise ModelError(f"expected one of {', '.join(PROPORTIONS)}, got {proportions!r}", key="human.proportions")


def _asked_dims(sex: Sex, stature: float | None, percentile: float | None, mass: float | None,
                dims: dict[str, float], no_subject: bool) -> dict[str, float]:
    """The survey's dimensions asked for by name [m] (mass [kg]): the given ones, the stature (or its percentile's),
    and the median stature when nothing at all is given."""
    asked: dict[str, float] = {}
    for name, value in dims.items():
        if name not in ansur.COLUMNS or name == ansur.MASS:
            known = ", ".join(c for c in ansur.COLUMNS if c != ansur.MASS)
            raise ModelError(f"unknown dimension; ANSUR II's are {known} (and mass [kg])", key=f"human.{name}")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ModelError(f"expected a length in metres, got {value!r}", key=f"human.{name}")
        asked[name] = float(value)
    if percentile is not None:
        asked["stature"] = stature_at_percentile(sex, percentile)
    elif stature is not None:
        asked["stature"] = float(stature)
    if mass is not None:
        asked[ansur.MASS] = float(mass)
    if not asked and no_subject:
        asked["stature"] = stature_at_percentile(sex, 50.0)
    return asked


# The survey's dimensions a measured body is built from (what _measured reads; its capsules' girths aside): the rest
# of a body's measures are what nobody gave it (bench/validation.py).
BUILT_FROM = ("stature", "acromialheight", "biacromialbreadth", "shoulderelbowlength", "cervicaleheight",
              "trochanterionheight", "lateralfemoralepicondyleheight",
              "lateralmalleolusheight", "acromionradialelength", "radialestylionlength", "handlength", "grip",
              "thumbtipreach", "span", "sittingheight", "eyeheightsitting", "buttockkneelength", "kneeheightsitting",
              "footlength")


def _measured(sex: Sex, d: dict[str, float], asked: dict[str, float], spread: dict[str, float]) -> Anthropometry:
    """A body whose joint centres sit where its ANSUR II landmarks imply (see the constants above)."""
    H, mass = d["stature"], d[ansur.MASS]
    ankle, knee, hip = d["lateralmalleolusheight"], d["lateralfemoralepicondyleheight"], d["trochanterionheight"]
    table = DE_LEVA[sex]
    lengths = {k: v[0] / 1000.0 for k, v in table.items()}
    lengths["shank"], lengths["thigh"] = knee - ankle, hip - knee
    lengths["head"] = H - d["cervicaleheight"]
    # The trunk from the hip centres to C7, shared among de Leva's three parts as in his reference subjects.
    parts = ("lower_trunk", "middle_trunk", "upper_trunk")
    trunk = d["cervicaleheight"] - hip
    ref = sum(table[k][0] for k in parts)
    for k in parts:
        lengths[k] = trunk * table[k][0] / ref
    drop = SJC_BELOW_ACROMION
    lengths["upper_arm"] = d["acromionradialelength"] - drop
    lengths["forearm"] = d["radialestylionlength"]
    hand = d["handlength"]
    lengths["hand"] = MET3_SHARE[sex] * hand
    lengths["foot"] = d["footlength"]
    pinch = PINCH_ALONG * hand
    knee_front = d["kneeheightsitting"] - knee  # the thigh's top over the knee centre, seated (thigh level)
    place = Placement(
        sjc_below_cerv=d["cervicaleheight"] - (d["acromialheight"] - drop),
        # The shoulder centres' breadth: the span (arms out to the sides, fingertip to fingertip) less two arms. With
        # the arm as long as the overhead reach asks (SJC_BELOW_ACROMION) it puts them 43-60 mm (p05 women to p95
        # men) inside the acromions' lateral tips (biacromial breadth), more than the humeral head's radius: the
        # span's posture (against a wall) pulls the shoulders back, which the model's reference does not
        # (docs/validation.md).
        shoulder_y=0.5 * d["span"] - (lengths["upper_arm"] + lengths["forearm"] + hand),
        # The wall of a thumb-tip reach (the shoulder blades) behind the shoulder centre: the reach less the arm.
        back_depth=d["thumbtipreach"] - (lengths["upper_arm"] + lengths["forearm"] + pinch),
        hip_y=HIP_Y * H,
        eye_height=H - (d["sittingheight"] - d["eyeheightsitting"]),
        grip=hand - (d["forearmhandlength"] - d["forearmcenterofgriplength"]),
        pinch=pinch, fingertip=hand, palmar=HAND_PALMAR * lengths["hand"], acromion=drop,
        hip_above_seat=d["sittingheight"] - (H - hip),
        buttock_back=d["buttockkneelength"] - lengths["thigh"] - knee_front, knee_front=knee_front,
        # The survey's landmarks (Gordon et al. 2014's definitions): the acromions' lateral tips half the biacromial
        # breadth from the mid-plane; with the elbow flexed 90 deg, its underside (the olecranon) lies the
        # shoulder-elbow length less the acromion-radiale length below radiale (men 28.5 +- 4.9 mm, women 23.1 +- 5.7,
        # computed from the public files), both measured from the acromion along the upper arm.
        acromion_y=0.5 * d["biacromialbreadth"],
        olecranon=max(d["shoulderelbowlength"] - d["acromionradialelength"], 0.0),
    )
    total = sum(v[1] for v in table.values()) + sum(table[k][1]
                                                    for k in ("upper_arm", "forearm", "hand", "thigh", "shank", "foot"))
    masses = {k: mass * v[1] / total for k, v in table.items()}
    com = {k: v[2] / 100.0 for k, v in table.items()}
    girths = {k: d[v] for k, v in GIRTH_NAMES.items()}
    return Anthropometry(sex, H, mass, lengths, masses, com, girths, ankle, place, "ansur", d, asked, spread)


def _de_leva(sex: Sex, stature: float | None, percentile: float | None, mass: float | None) -> Anthropometry:
    """Dimensions of a body scaled from de Leva's reference subject (the body of earlier versions).

    Lengths scale with stature (isometric scaling); the vertical chain
    (shank, thigh, trunk, head) is then adjusted so that ankle height plus
    that chain equals the stature exactly. Masses are de Leva's percentages of
    the body mass; by default the ANSUR II mean mass scaled by (stature / mean
    stature)^2 (constant body-mass index).
    """
    if stature is None:
        stature = stature_at_percentile(sex, 50.0 if percentile is None else percentile)
    if not 1.0 <= stature <= 2.5:
        raise ModelError(f"stature must be in [1.0, 2.5] m, got {stature}", name="stature")
    mean_h = ANSUR_STATURE[sex][0] / 1000.0
    if mass is None:
        mass = ANSUR_MASS[sex] * (stature / mean_h) ** 2
    if not 20.0 <= mass <= 250.0:
        raise ModelError(f"mass must be in [20, 250] kg, got {mass}", name="mass")
    table = DE_LEVA[sex]
    scale = stature / (REFERENCE[sex][0] / 1000.0)
    lengths = {k: v[0] / 1000.0 * scale for k, v in table.items()}
    vertical = ("shank", "thigh", "upper_trunk", "middle_trunk", "lower_trunk", "head")
    fit = (stature * (1.0 - ANKLE_HEIGHT)) / sum(lengths[k] for k in vertical)
    for k in vertical:
        lengths[k] *= fit
    total = sum(v[1] for v in table.values()) + sum(table[k][1]
                                                    for k in ("upper_arm", "forearm", "hand", "thigh", "shank", "foot"))
    masses = {k: mass * v[1] / total for k, v in table.items()}
    com = {k: v[2] / 100.0 for k, v in table.items()}
    girths = {k: v / 1000.0 * stature / mean_h for k, v in ANSUR_GIRTHS[sex].items()}
    H = stature
    grip = GRIP_ALONG * lengths["hand"]
    place = Placement(SHOULDER_BELOW_CERV * H, SHOULDER_Y * H, SHOULDER_BACK_DEPTH * H, HIP_Y * H, EYE_HEIGHT * H,
                      grip, grip, grip, GRIP_PALMAR * lengths["hand"], 0.0)
    return Anthropometry(sex, stature, mass, lengths, masses, com, girths, ANKLE_HEIGHT * H, place, "de_leva")


def legacy_body(spec: Any) -> tuple[Any, str | None]:
    """A stored body spec as this version rebuilds the body it was written with, and a note when it changed.

    A human spec without ``proportions`` was written before bodies were built from ANSUR II measures
    (docs/decisions/0015): its body is the stature-scaled ``de_leva`` one, whose URDF this version still writes.
    """
    if not isinstance(spec, dict) or not isinstance(spec.get("human"), dict) or "proportions" in spec["human"]:
        return spec, None
    return ({**spec, "human": {**spec["human"], "proportions": "de_leva"}},
            "built with the stature-scaled human of earlier versions (proportions: de_leva: de Leva's segments scaled "
            "by stature, the hand frame 34-54 mm past the grip); it refines with that body. Rebuild for a body from "
            "ANSUR II measures (docs/bodies.md)")
