"""A human body measured as ANSUR II measures people: each dimension by Pinocchio's forward kinematics of the model in
the survey's posture for it (Gordon et al. 2014, NATICK/TR-15/007, the dimensions' definitions).

What ``reach model`` prints as built and ``bench/validation.py`` compares with the survey and other published
figures. Lengths in metres. Seated dimensions are measured on the upright trunk, the hips where the body's seat
contact puts them (:class:`oracles.bodies.anthropometry.Placement`), without a seat's geometry.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from oracles.bodies.body import Body, load_body
from oracles.bodies.seat import _hip_above_pan
from oracles.errors import ModelError

# The dimensions measured on a model (ANSUR II's names), and what each one's posture and points are.
MEASURES = {
    "stature": "standing: the top of the head (vertex) above the floor",
    "acromialheight": "standing: the right acromion above the floor",
    "wristheight": "standing, arms hanging: the right wrist centre above the floor",
    "thumbtipreach": "standing, the right arm forward at shoulder height (flexion 90 deg): the thumb tip (pinch) ahead "
                     "of the wall behind the shoulders (the back frame)",
    "span": "standing, both arms out to the sides (abduction 90 deg): fingertip to fingertip",
    "sittingheight": "seated upright: the vertex above the seat",
    "eyeheightsitting": "seated upright: the eyes above the seat",
    "buttockkneelength": "seated, hips and knees at 90 deg: the buttocks' back (the pelvis capsule) to the front of "
                         "the knee",
    "overheadfingertipreachsitting": "seated upright, the right arm straight up (shoulder flexion 180 deg, the "
                                     "clavicle at its elevation limit): the middle fingertip above the seat",
    "grip": "the grip centre past the wrist centre, along the hand (ANSUR: hand length - (forearm-hand length - "
            "forearm-centre-of-grip length))",
    "trochanterionheight": "standing: the right hip centre above the floor (at the trochanterion's height)",
    "lateralfemoralepicondyleheight": "standing: the right knee centre above the floor (at the epicondyle's)",
    "lateralmalleolusheight": "standing: the right ankle centre above the floor (at the malleolus's)",
    "acromionradialelength": "standing, arms hanging: the right acromion above the elbow centre (at radiale), along "
                             "the arm, as the survey's beam caliper takes it",
    "radialestylionlength": "standing, arms hanging: the right elbow centre to the wrist centre (at stylion)",
    "handlength": "the right wrist centre to the middle fingertip",
    "footlength": "the right heel to the toe tip",
    # The rest, most of them no body is built from (docs/validation.md says which are inputs): where a landmark is
    # not a frame of the model, the capsule that stands for the flesh there is measured (its lowest, highest or
    # outermost point).
    "biacromialbreadth": "standing: the right acromion's tip to the left one's",
    "shoulderelbowlength": "standing, the upper arm hanging, the elbow flexed 90 deg: the acromion above the elbow's "
                           "underside (the elbow_rest frame)",
    "elbowrestheight": "seated upright, the upper arm hanging, the elbow flexed 90 deg: the elbow's underside (the "
                       "elbow_rest frame) above the seat",
    "poplitealheight": "seated, hips and knees at 90 deg, the foot flat: the thigh's underside at the knee (its "
                       "capsule's) above the sole",
    "kneeheightsitting": "seated, hips and knees at 90 deg, the foot flat: the knee's top (the knee centre and the "
                         "body's knee_front above it) above the sole",
    "buttockpopliteallength": "seated, hips and knees at 90 deg: the buttocks' back (the pelvis capsule) to the back "
                              "of the knee (the shank capsule's back at the knee)",
    "thighclearance": "seated, hips and knees at 90 deg: the thigh capsule's top above the seat",
    "hipbreadthsitting": "seated, hips and knees at 90 deg: the pelvis and thigh capsules' extent side to side",
    "crotchheight": "standing: the lowest point of the pelvis capsule above the floor",
    "tibialheight": "standing: the right knee centre above the floor (the model's tibial plateau)",
    "cervicaleheight": "standing: the neck's lower joint (C7) above the floor",
    "bideltoidbreadth": "standing, arms hanging: the upper arms' capsules' extent side to side",
    "forearmforearmbreadth": "standing, the upper arms hanging, both elbows flexed 90 deg: the upper arms' and "
                             "forearms' capsules' extent side to side",
    "interpupillarybreadth": "the right eye frame to the left one",
    "footbreadthhorizontal": "the right foot's inner ball corner to its outer one",
    "heelbreadth": "the right foot's inner heel corner to its outer one",
    "balloffootlength": "the right heel to the inner ball corner, along the foot",
}


def measure(body: Body) -> dict[str, float]:
    """The body's dimensions as ANSUR II measures them (:data:`MEASURES`) [m]; a generated human only. A seated body
    is measured as the survey measures its person: standing (the same person without the seat)."""
    anthro = body.anthropometry
    if anthro is None:
        raise ModelError("only a generated human is measured as ANSUR II measures people", source=body.source)
    human = body.spec.get("human") or {}
    if human.get("posture") == "seated":
        # each measure puts the model in the survey's posture from the standing reference (its stature was 1.08 m)
        standing = {k: v for k, v in human.items() if k not in ("posture", "seat")}
        return measure(load_body({**{k: v for k, v in body.spec.items() if k != "human"}, "human": standing}))
    place = anthro.place
    measured = anthro.proportions != "de_leva"
    # A de_leva body has no vertex, acromion, pinch or fingertip frames: its head ends at its stature, its one hand
    # frame stands for the thumb tip.
    pinch, tip = ("right_pinch", "right_fingertip") if measured else ("right_hand", "right_hand")
    stand = _points(body)
    hip = float(body.q_ref[2])
    vertex = float(stand["vertex"][2]) if measured else anthro.stature
    seat = (place.hip_above_seat if place.hip_above_seat is not None
            else _hip_above_pan({c.name: c for c in body.capsules}, 0.0))
    out = {
        "stature": vertex,
        "wristheight": float(stand["joint:right_wrist_flexion"][2]),
        "sittingheight": vertex - hip + seat,
        "eyeheightsitting": float(stand["eyes"][2]) - hip + seat,
    }
    if measured:
        out["acromialheight"] = float(stand["right_acromion"][2])
    forward = _points(body, right_shoulder_flexion=math.pi / 2)
    out["thumbtipreach"] = float(forward[pinch][0] - forward["back"][0])
    wide = _points(body, right_shoulder_abduction=math.pi / 2, left_shoulder_abduction=math.pi / 2)
    out["span"] = float(wide["left_" + tip.removeprefix("right_")][1] - wide[tip][1])
    out["overheadfingertipreachsitting"] = _highest(body, tip) - hip + seat
    if place.knee_front is not None:
        bent = {"right_hip_flexion": math.pi / 2, "right_knee_flexion": math.pi / 2}
        capsules = body.capsules_at(body.configuration(bent))
        pelvis = capsules[[c.name for c in body.collision.placed].index("pelvis")]
        back = min(pelvis[0], pelvis[3]) - pelvis[6]
        out["buttockkneelength"] = float(_points(body, **bent)["joint:right_knee_flexion"][0] + place.knee_front
                                         - back)
    for name, joint in (("trochanterionheight", "right_hip_flexion"),
                        ("lateralfemoralepicondyleheight", "right_knee_flexion"),
                        ("lateralmalleolusheight", "right_ankle_flexion")):
        out[name] = float(stand["joint:" + joint][2])
    elbow, wrist = stand["joint:right_elbow_flexion"], stand["joint:right_wrist_flexion"]
    out["radialestylionlength"] = float(np.linalg.norm(wrist - elbow))
    out["footlength"] = float(np.linalg.norm(stand["right_toe"] - stand["right_heel"]))
    if measured:
        out["acromionradialelength"] = float(stand["right_acromion"][2] - elbow[2])
        out["handlength"] = float(np.linalg.norm(stand["right_fingertip"] - wrist))
        out["grip"] = float(abs(stand["right_grip"][2] - wrist[2]))
        out.update(_unbuilt(body, stand, hip, seat, place.knee_front))
    return out


def _capsules(body: Body, **angles: float) -> dict[str, np.ndarray]:
    """Each collision capsule (a, b, radius as a row of 7) at the reference with angles set, by name."""
    rows = body.capsules_at(body.configuration(angles))
    return {c.name: row for c, row in zip(body.collision.placed, rows, strict=True)}


def _lowest(*capsules: np.ndarray) -> float:
    return float(min(min(c[2], c[5]) - c[6] for c in capsules))


def _extent(*capsules: np.ndarray) -> float:
    """The capsules' extent along y [m] (side to side)."""
    return float(max(max(c[1], c[4]) + c[6] for c in capsules) - min(min(c[1], c[4]) - c[6] for c in capsules))


def _unbuilt(body: Body, stand: dict[str, np.ndarray], hip: float, seat: float,
             knee_front: float | None) -> dict[str, float]:
    """The dimensions of :data:`MEASURES` taken on landmarks and capsules [m], most of them no body is built from
    (anthropometry.BUILT_FROM names the inputs): how the model meets what nobody gave it."""
    out = {"biacromialbreadth": float(np.linalg.norm(stand["right_acromion"] - stand["left_acromion"])),
           "interpupillarybreadth": float(np.linalg.norm(stand["right_eye"] - stand["left_eye"])),
           "footbreadthhorizontal": float(np.linalg.norm(stand["right_ball_outer"] - stand["right_ball_inner"])),
           "heelbreadth": float(np.linalg.norm(stand["right_heel_outer"] - stand["right_heel_inner"])),
           "balloffootlength": float(stand["right_ball_inner"][0] - stand["right_heel"][0]),
           "tibialheight": float(stand["joint:right_knee_flexion"][2]),
           "cervicaleheight": float(stand["joint:neck_flexion"][2])}
    upright = _capsules(body)
    out["crotchheight"] = _lowest(upright["pelvis"])
    out["bideltoidbreadth"] = _extent(upright["right_upper_arm"], upright["left_upper_arm"])
    bent = {"right_elbow_flexion": math.pi / 2, "left_elbow_flexion": math.pi / 2}
    elbows = _capsules(body, **bent)
    underside = float(_points(body, **bent)["right_elbow_rest"][2])
    out["shoulderelbowlength"] = float(stand["right_acromion"][2]) - underside
    out["elbowrestheight"] = underside - hip + seat
    out["forearmforearmbreadth"] = _extent(*(elbows[f"{side}_{part}"] for side in ("right", "left")
                                              for part in ("upper_arm", "forearm")))
    sitting = {f"{side}_{joint}_flexion": math.pi / 2 for side in ("right", "left") for joint in ("hip", "knee")}
    legs, points = _capsules(body, **sitting), _points(body, **sitting)
    # the heel frame lies on the sole (the right_sole frame is the ankle's)
    thigh, shank, sole = legs["right_thigh"], legs["right_shank"], float(points["right_heel"][2])
    knee = points["joint:right_knee_flexion"]
    out["poplitealheight"] = float(knee[2] - thigh[6]) - sole
    if knee_front is not None:
        out["kneeheightsitting"] = float(knee[2]) + knee_front - sole
    back = min(legs["pelvis"][0], legs["pelvis"][3]) - legs["pelvis"][6]
    out["buttockpopliteallength"] = float(knee[0] - shank[6] - back)
    out["thighclearance"] = float(max(thigh[2], thigh[5]) + thigh[6]) - (hip - seat)
    out["hipbreadthsitting"] = _extent(legs["pelvis"], legs["right_thigh"], legs["left_thigh"])
    return out


def _points(body: Body, **angles: float) -> dict[str, np.ndarray]:
    """World positions [m] of every frame, and of every joint as ``joint:NAME``, at the reference with angles set."""
    data = body.model.createData()
    pin.framesForwardKinematics(body.model, data, body.configuration(angles))
    out = {str(f.name): np.array(data.oMf[i].translation) for i, f in enumerate(body.model.frames)}
    for j in range(1, body.model.njoints):
        out["joint:" + str(body.model.names[j])] = np.array(data.oMi[j].translation)
    return out


OVERHEAD = ("right_clavicle_elevation", "right_clavicle_protraction", "right_shoulder_flexion",
            "right_shoulder_abduction", "right_elbow_flexion", "right_wrist_flexion")


def _highest(body: Body, frame: str) -> float:
    """The highest a frame goes [m] with the right shoulder girdle, arm and wrist free within their ranges, the rest at
    the reference: the overhead reach the model can make (the survey's subject raises the shoulder too)."""
    # scipy only where the overhead reach is measured
    from scipy.optimize import minimize

    limits = {n: (lo, hi) for n, lo, hi in body.limits()}
    data = body.model.createData()
    fid = body.frame_id(frame)

    def height(x: np.ndarray) -> float:
        q = body.configuration(dict(zip(OVERHEAD, map(float, x), strict=True)))
        pin.framesForwardKinematics(body.model, data, q)
        return -float(data.oMf[fid].translation[2])

    bounds = [limits[n] for n in OVERHEAD]
    # The arm raised by flexion, and by abduction with the girdle elevated: from one start alone the search can stop
    # in the other's local optimum (a 95th-percentile man's reach 64 mm short).
    starts = ([0.0, 0.0, math.pi - 0.1, 0.0, 0.0, 0.0], [math.pi / 4, 0.0, 0.0, 3 * math.pi / 4, 0.0, 0.0])
    best = min((minimize(height, np.clip(start, *np.array(bounds).T), bounds=bounds, method="L-BFGS-B")
                for start in starts), key=lambda r: float(r.fun))
    return -float(best.fun)
