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
* Stature distribution: Gordon, C.C. et al. (2014), *2012 Anthropometric
  Survey of U.S. Army Personnel (ANSUR II)*, NATICK/TR-15/007: stature mean
  and standard deviation, men and women, and mean body mass. Stature at a
  percentile assumes a normal distribution.
* Joint ranges of motion: American Academy of Orthopaedic Surgeons (1965),
  *Joint Motion: Method of Measuring and Recording*, as tabulated in Norkin,
  C.C. & White, D.J. (2016), *Measurement of Joint Motion*, 5th ed.,
  **Appendix A**; sternoclavicular ranges from Kapandji, I.A. (2007), *The
  Physiology of the Joints*, vol. 1 (clavicle elevation 45 deg, depression
  10 deg, protraction 15 deg, retraction 30 deg).

All lengths here are metres, angles radians, masses kilograms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Literal

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
# Grip centre: the axis of a gripped handle lies beyond MET3 and palmar of
# the hand's long axis: 1.40 and 0.25 hand lengths (WJC-MET3) from the wrist.
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


@dataclass(frozen=True)
class Anthropometry:
    """Segment dimensions [m] and masses [kg] of one body.

    ``lengths`` and ``com`` (fraction from the proximal end) are keyed by the
    de Leva segment names; ``masses`` likewise.
    """

    sex: Sex
    stature: float
    mass: float
    lengths: dict[str, float]
    masses: dict[str, float]
    com: dict[str, float]
    girths: dict[str, float] = field(default_factory=dict)  # ANSUR_GIRTHS scaled [m]

    @property
    def ankle_height(self) -> float:
        return ANKLE_HEIGHT * self.stature


def stature_at_percentile(sex: Sex, percentile: float) -> float:
    """Stature [m] at a percentile of the ANSUR II distribution (normal)."""
    if not 0.0 < percentile < 100.0:
        raise ModelError(f"percentile must be in (0, 100), got {percentile}", name="percentile")
    mean, sd = ANSUR_STATURE[sex]
    return NormalDist(mean, sd).inv_cdf(percentile / 100.0) / 1000.0


def anthropometry(sex: Sex = "male", stature: float | None = None, percentile: float | None = None,
                  mass: float | None = None) -> Anthropometry:
    """Dimensions of a body scaled from de Leva's reference subject.

    Args:
        sex: ``male`` or ``female``.
        stature: Standing height [m]; exclusive with percentile.
        percentile: Stature percentile of ANSUR II; default 50.
        mass: Body mass [kg]; default the ANSUR II mean mass scaled by
            (stature / mean stature)^2 (constant body-mass index).

    Lengths scale with stature (isometric scaling); the vertical chain
    (shank, thigh, trunk, head) is then adjusted so that ankle height plus
    that chain equals the stature exactly. Masses are de Leva's percentages of
    the body mass.
    """
    if sex not in DE_LEVA:
        raise ModelError(f"sex must be 'male' or 'female', got {sex!r}", name="sex")
    if stature is not None and percentile is not None:
        raise ModelError("give stature or percentile, not both", name="stature")
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
    return Anthropometry(sex, stature, mass, lengths, masses, com, girths)
