"""The generated human: a URDF written from anthropometric tables.

World frame (reference posture): z up, x forward, y to the body's left,
origin on the floor midway between the ankles; soles on z = 0, standing,
arms hanging with palms facing the thighs. Every link frame is parallel to
the world frame in that posture, so zero joint angles are the reference.

Joint angles are positive in the anatomical direction their names give
(flexion, abduction, internal rotation, pronation, radial deviation,
dorsiflexion, inversion, clavicle elevation and protraction; lateral bending
to the right; axial rotation of the spine and neck to the left).

Frames: ``right_hand``/``left_hand`` at the grip centre (the axis of a rod
held in the fist, where ANSUR II puts it), and the same point as
``right_grip``/``left_grip``; ``right_pinch``/``left_pinch`` at the thumb tip
pinching the index finger; ``right_fingertip``/``left_fingertip`` at the
middle fingertip; ``right_acromion``/``left_acromion`` and ``vertex`` (the
top of the head) where ANSUR II measures them; ``right_foot`` and
``left_foot`` at the ball of the foot on the sole; ``*_heel`` and ``*_toe``
and their ``_inner``/``_outer`` corners on the sole for the support polygon;
``eyes`` (cyclopean, x along the line of sight), ``left_eye``,
``right_eye``; ``right_shoulder``/``left_shoulder`` at the shoulder joint
centres; ``back`` on the back of the shoulders, on the mid-sagittal plane.

A ``de_leva`` body (``proportions: de_leva``, the body of earlier versions)
has its one hand frame ``right_hand`` 1.40 WJC-MET3 lengths past the wrist (a
pinch point more than a grip) and none of the grip, pinch, fingertip,
acromion or vertex frames: its URDF is the one its trees were built with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

from oracles.bodies import anthropometry as A
from oracles.bodies.anthropometry import Anthropometry
from oracles.bodies.collision import CAPSULE_PREFIX, Capsule

# Radii of limb capsules: a circumference's radius C / (2 pi), reduced where
# the circumference is the segment's largest (thigh at the gluteal furrow,
# flexed biceps, calf) so that the capsule fits the segment's mean girth.
# Modelling choices, not table values.
TAPER = {"upper_arm": 0.9, "thigh": 0.7, "shank": 0.85}
HAND_RADIUS = 0.3  # fist radius as a fraction of hand breadth (modelling choice)
# [m] how far a measured body's thigh capsule may sink into a hard seat (within the seat check's 5 mm): soft tissue
# that ANSUR's sitting height, measured on a hard seat, has already compressed (modelling choice).
SEAT_SINK = 0.004
# [m] the least gap between the floor and the shank capsule's lower sphere standing. The capsule's radius is the
# calf's girth, which the leg does not keep down to the ankle: where that radius passes the ankle's height (37 of
# ANSUR II's 6,068 subjects, by up to 6.2 mm) the sphere's centre is raised to leave this gap, so that the floor task
# holds in the reference posture and still holds with the shank turned 45 deg about the ankle, as in a crouch (the
# worst subject's sphere then clears the floor by 0.3 mm; modelling choice).
SHANK_FLOOR_GAP = 0.003


@dataclass
class _Urdf:
    """Accumulates links and joints; one revolute joint per anatomical axis."""

    name: str
    parts: list[str] = field(default_factory=list)
    frames: dict[str, tuple[str, tuple[float, float, float]]] = field(default_factory=dict)

    capsules: dict[str, list[Capsule]] = field(default_factory=dict)

    def link(self, name: str, mass: float = 0.0, com: tuple[float, float, float] = (0, 0, 0),
             length: float = 0.1) -> None:
        collisions = "".join(self.collision(c) for c in self.capsules.get(name, []))
        if mass <= 0.0:
            self.parts.append(f"<link name={quoteattr(name)}>{collisions}</link>" if collisions else "<link "
                f"name={quoteattr(name)}/>")
            return
        # Inertia of a solid cylinder of radius 0.15 L along z: an
        # approximation; static reach depends on masses and CoMs only.
        r = 0.15 * length
        ixx = mass * (3 * r * r + length * length) / 12.0
        izz = mass * r * r / 2.0
        self.parts.append(
            f'<link name={quoteattr(name)}><inertial><origin xyz="{_v(com)}" rpy="0 0 0"/><mass value="{mass:.6f}"/>'
            f'<inertia ixx="{ixx:.6g}" iyy="{ixx:.6g}" izz="{izz:.6g}" ixy="0" ixz="0" '
            f'iyz="0"/></inertial>{collisions}</link>'
        )

    def revolute(self, name: str, parent: str, child: str, xyz: tuple[float, float, float],
                 axis: tuple[float, float, float]) -> None:
        lo, hi = A.RANGES[_anatomical(name)]
        self.parts.append(
            f'<joint name={quoteattr(name)} type="revolute"><parent link={quoteattr(parent)}/><child '
            f'link={quoteattr(child)}/><origin xyz="{_v(xyz)}" rpy="0 0 0"/><axis xyz="{_v(axis)}"/>'
            f'<limit lower="{lo:.9f}" upper="{hi:.9f}" effort="1000" velocity="10"/></joint>'
        )

    def chain(self, joints: list[tuple[str, tuple[float, float, float]]], parent: str, child: str,
              xyz: tuple[float, float, float]) -> None:
        """Consecutive revolute joints at one point, joined by massless links."""
        for i, (jname, axis) in enumerate(joints):
            last = i == len(joints) - 1
            link = child if last else f"{jname}_link"
            if not last:
                self.link(link)
            self.revolute(jname, parent, link, xyz if i == 0 else (0.0, 0.0, 0.0), axis)
            parent = link

    def frame(self, name: str, link: str, xyz: tuple[float, float, float]) -> None:
        """A fixed frame: a massless link on a fixed joint."""
        self.frames[name] = (link, xyz)
        self.parts.append(f"<link name={quoteattr(name)}/>")
        self.parts.append(
            f'<joint name={quoteattr(name + "_fixed")} type="fixed"><parent link={quoteattr(link)}/>'
            f'<child link={quoteattr(name)}/><origin xyz="{_v(xyz)}" rpy="0 0 0"/></joint>'
        )

    @staticmethod
    def collision(capsule: Capsule) -> str:
        """A capsule as a URDF collision cylinder named capsule_<name> (URDF has no capsule)."""
        a, b = capsule.a, capsule.b
        d = [b[i] - a[i] for i in range(3)]
        length = sum(v * v for v in d) ** 0.5
        mid = (0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2]))
        # Orientation taking z onto the axis: pitch about y, then yaw about z.
        yaw = math.atan2(d[1], d[0]) if abs(d[0]) + abs(d[1]) > 1e-12 else 0.0
        pitch = math.atan2((d[0] ** 2 + d[1] ** 2) ** 0.5, d[2])
        return (
            f'<collision name={quoteattr(CAPSULE_PREFIX + capsule.name)}><origin xyz="{_v(mid)}" rpy="0 {pitch:.9f} '
            f'{yaw:.9f}"/><geometry><cylinder radius="{capsule.radius:.9f}" '
            f'length="{length:.9f}"/></geometry></collision>'
        )

    def xml(self) -> str:
        body = "\n  ".join(self.parts)
        return f'<?xml version="1.0"?>\n<robot name={quoteattr(self.name)}>\n  {body}\n</robot>\n'


def _v(xyz: tuple[float, float, float]) -> str:
    return " ".join(f"{c:.9f}" for c in xyz)


def _anatomical(joint: str) -> str:
    for side in ("right_", "left_"):
        if joint.startswith(side):
            return joint[len(side):]
    return joint


def human_urdf(body: Anthropometry, name: str = "human") -> str:
    """URDF text of the generated human (see the module docstring for frames)."""
    H, L, M, C, P = body.stature, body.lengths, body.masses, body.com, body.place
    measured = body.proportions != "de_leva"
    u = _Urdf(name)
    for c in human_capsules(body):
        u.capsules.setdefault(c.link, []).append(c)
    ankle_z = body.ankle_height
    hip_z = ankle_z + L["shank"] + L["thigh"]
    sjc_from_xyph = L["upper_trunk"] - P.sjc_below_cerv

    # Pelvis: the lower trunk (OMPH-MIDH), origin at mid-hip (MIDH).
    u.link("pelvis", M["lower_trunk"], (0, 0, (1 - C["lower_trunk"]) * L["lower_trunk"]), L["lower_trunk"])
    u.link("abdomen", M["middle_trunk"], (0, 0, (1 - C["middle_trunk"]) * L["middle_trunk"]), L["middle_trunk"])
    u.chain([("lumbar_flexion", (0, 1, 0)), ("lumbar_lateral", (1, 0, 0))], "pelvis", "abdomen",
            (0, 0, L["lower_trunk"]))
    u.link("thorax", M["upper_trunk"], (0, 0, (1 - C["upper_trunk"]) * L["upper_trunk"]), L["upper_trunk"])
    u.chain([("thoracic_flexion", (0, 1, 0)), ("thoracic_rotation", (0, 0, 1))], "abdomen", "thorax",
            (0, 0, L["middle_trunk"]))
    u.link("head", M["head"], (0, 0, (1 - C["head"]) * L["head"]), L["head"])
    u.chain([("neck_flexion", (0, 1, 0)), ("neck_rotation", (0, 0, 1))], "thorax", "head", (0, 0, L["upper_trunk"]))
    eye_z = P.eye_height - (hip_z + L["lower_trunk"] + L["middle_trunk"] + L["upper_trunk"])
    u.frame("eyes", "head", (A.EYE_FORWARD * H, 0.0, eye_z))
    u.frame("left_eye", "head", (A.EYE_FORWARD * H, A.EYE_Y * H, eye_z))
    u.frame("right_eye", "head", (A.EYE_FORWARD * H, -A.EYE_Y * H, eye_z))
    u.frame("back", "thorax", (-P.back_depth, 0.0, sjc_from_xyph))
    if measured:
        u.frame("vertex", "head", (0.0, 0.0, L["head"]))

    for side, s in (("right", -1.0), ("left", 1.0)):
        p = f"{side}_"
        # Arm: sternoclavicular joint, shoulder, elbow, forearm, wrist.
        u.link(f"{p}clavicle")
        u.chain(
            [(f"{p}clavicle_elevation", (s, 0, 0)), (f"{p}clavicle_protraction", (0, 0, -s))],
            "thorax", f"{p}clavicle", (0.0, s * A.STERNOCLAVICULAR_Y * H, sjc_from_xyph),
        )
        sjc = (0.0, s * (P.shoulder_y - A.STERNOCLAVICULAR_Y * H), 0.0)
        u.frame(f"{p}shoulder", f"{p}clavicle", sjc)
        if measured and P.acromion_y is not None:
            # the acromion's lateral tip, above the shoulder centre's height by P.acromion (the survey's landmark)
            u.frame(f"{p}acromion", f"{p}clavicle", (0.0, s * (P.acromion_y - A.STERNOCLAVICULAR_Y * H), P.acromion))
        u.link(f"{p}upper_arm", M["upper_arm"], (0, 0, -C["upper_arm"] * L["upper_arm"]), L["upper_arm"])
        u.chain(
            [(f"{p}shoulder_flexion", (0, -1, 0)), (f"{p}shoulder_abduction", (s, 0, 0)),
             (f"{p}shoulder_rotation", (0, 0, -s))],
            f"{p}clavicle", f"{p}upper_arm", sjc,
        )
        u.link(f"{p}forearm", M["forearm"], (0, 0, -C["forearm"] * L["forearm"]), L["forearm"])
        u.chain([(f"{p}elbow_flexion", (0, -1, 0)), (f"{p}forearm_pronation", (0, 0, -s))], f"{p}upper_arm",
                f"{p}forearm", (0, 0, -L["upper_arm"]))
        if measured and P.olecranon is not None:
            # the elbow's underside where elbow rest height is taken: behind the elbow centre on the ulna (the
            # flexion's link, which pronation does not turn), below it with the elbow flexed 90 deg
            u.frame(f"{p}elbow_rest", f"{p}elbow_flexion_link", (-P.olecranon, 0.0, 0.0))
        u.link(f"{p}palm", M["hand"], (0, 0, -C["hand"] * L["hand"]), L["hand"])
        u.chain([(f"{p}wrist_flexion", (-s, 0, 0)), (f"{p}wrist_deviation", (0, -1, 0))], f"{p}forearm", f"{p}palm",
                (0, 0, -L["forearm"]))
        # Palm faces the thigh in the reference posture: palmar is medial (-s).
        u.frame(f"{p}hand", f"{p}palm", (0.0, -s * P.palmar, -P.grip))
        if measured:
            u.frame(f"{p}grip", f"{p}palm", (0.0, -s * P.palmar, -P.grip))
            u.frame(f"{p}pinch", f"{p}palm", (0.0, -s * P.palmar, -P.pinch))
            u.frame(f"{p}fingertip", f"{p}palm", (0.0, 0.0, -P.fingertip))

        # Leg: hip, knee, ankle.
        u.link(f"{p}thigh", M["thigh"], (0, 0, -C["thigh"] * L["thigh"]), L["thigh"])
        u.chain(
            [(f"{p}hip_flexion", (0, -1, 0)), (f"{p}hip_abduction", (s, 0, 0)), (f"{p}hip_rotation", (0, 0, -s))],
            "pelvis", f"{p}thigh", (0.0, s * P.hip_y, 0.0),
        )
        u.link(f"{p}shank", M["shank"], (0, 0, -C["shank"] * L["shank"]), L["shank"])
        u.chain([(f"{p}knee_flexion", (0, 1, 0))], f"{p}thigh", f"{p}shank", (0, 0, -L["thigh"]))
        lf = L["foot"]
        heel_x = -A.ANKLE_FROM_HEEL * lf
        u.link(f"{p}sole", M["foot"], (heel_x + C["foot"] * lf, 0, -0.5 * ankle_z), lf)
        u.chain([(f"{p}ankle_flexion", (0, -1, 0)), (f"{p}ankle_inversion", (-s, 0, 0))], f"{p}shank", f"{p}sole",
                (0, 0, -L["shank"]))
        half = 0.5 * A.FOOT_BREADTH * H
        ball_x, toe_x = heel_x + A.BALL_FROM_HEEL * lf, heel_x + lf
        u.frame(f"{p}foot", f"{p}sole", (ball_x, 0.0, -ankle_z))
        u.frame(f"{p}heel", f"{p}sole", (heel_x, 0.0, -ankle_z))
        u.frame(f"{p}toe", f"{p}sole", (toe_x, 0.0, -ankle_z))
        # Medial (inner) is towards the body's midline: -s.
        for where, x, w in (("heel", heel_x, 0.6 * half), ("ball", ball_x, half), ("toe", toe_x, 0.7 * half)):
            u.frame(f"{p}{where}_inner", f"{p}sole", (x, -s * w, -ankle_z))
            u.frame(f"{p}{where}_outer", f"{p}sole", (x, s * w, -ankle_z))
    return u.xml()


def human_capsules(body: Anthropometry) -> list[Capsule]:
    """One capsule per segment, in its link's frame (the reference posture's axes: z up, x forward, y left).

    Sizes (ANSUR II girths: the body's own, or for a de_leva body
    :data:`oracles.bodies.anthropometry.ANSUR_GIRTHS` scaled by stature):
    the trunk's three parts are horizontal capsules across the body, of
    radius half the depth and total width the breadth (chest, waist; the
    pelvis takes the waist's, its bony width below the hips' soft tissue),
    set back so the thorax's back lies on the ``back`` frame; the head a
    capsule front to back of radius half the head breadth and length the
    head length, over a neck of the neck circumference; the limbs capsules
    along their segments of radius C / (2 pi) (see ``TAPER``); the hand a
    fist from the wrist past the grip centre; the foot a capsule heel to toe
    resting on the sole.
    """
    L, G, P = body.lengths, body.girths, body.place
    two_pi = 2.0 * math.pi
    out: list[Capsule] = []

    def across(name: str, link: str, z: float, breadth: float, depth: float, x: float = 0.0) -> None:
        r = 0.5 * depth
        half = max(0.5 * breadth - r, 0.0)
        out.append(Capsule(name, link, (x, -half, z), (x, half, z), r))

    # A measured body's buttocks lie where its buttock-knee length puts them (Placement.buttock_back).
    # Its pelvis no lower than its seat: ANSUR's sitting height puts the hip centres P.hip_above_seat over a hard seat.
    pelvis_x, pelvis_z = 0.0, 0.35 * L["lower_trunk"]
    if P.buttock_back is not None and P.hip_above_seat is not None:
        pelvis_x = 0.5 * G["waist_depth"] - P.buttock_back
        pelvis_z = max(pelvis_z, 0.5 * G["waist_depth"] - P.hip_above_seat)
    across("pelvis", "pelvis", pelvis_z, G["waist_breadth"], G["waist_depth"], pelvis_x)
    across("abdomen", "abdomen", 0.5 * L["middle_trunk"], G["waist_breadth"], G["waist_depth"])
    back = -P.back_depth
    across("thorax", "thorax", 0.5 * L["upper_trunk"], G["chest_breadth"], G["chest_depth"],
           back + 0.5 * G["chest_depth"])
    r_head = 0.5 * G["head_breadth"]
    head_half = max(0.5 * G["head_length"] - r_head, 0.0)
    z_head = L["head"] - r_head
    out.append(Capsule("head", "head", (-head_half, 0.0, z_head), (head_half, 0.0, z_head), r_head))
    r_neck = G["neck_circumference"] / two_pi
    out.append(Capsule("neck", "head", (0.0, 0.0, 0.0), (0.0, 0.0, max(z_head - r_head, 0.0)), r_neck))
    ankle_z = body.ankle_height
    for side, s in (("right", -1.0), ("left", 1.0)):
        p = f"{side}_"
        r_arm = TAPER["upper_arm"] * G["biceps_circumference_flexed"] / two_pi
        out.append(Capsule(f"{p}upper_arm", f"{p}upper_arm", (0.0, 0.0, 0.0), (0.0, 0.0, -L["upper_arm"]), r_arm))
        r_fore = 0.5 * (G["forearm_circumference_flexed"] + G["wrist_circumference"]) / two_pi
        out.append(Capsule(f"{p}forearm", f"{p}forearm", (0.0, 0.0, 0.0), (0.0, 0.0, -L["forearm"]), r_fore))
        r_hand = HAND_RADIUS * G["hand_breadth"]
        grip_y = -s * P.palmar
        # A measured hand's fist ends at the pinch (its surface a finger's radius past it); a de_leva hand's past its
        # grip by 0.2 WJC-MET3 lengths.
        end = P.pinch if body.proportions != "de_leva" else (A.GRIP_ALONG + 0.2) * L["hand"]
        out.append(Capsule(f"{p}hand", f"{p}palm", (0.0, 0.5 * grip_y, -r_hand), (0.0, grip_y, -end), r_hand))
        r_thigh = TAPER["thigh"] * G["thigh_circumference"] / two_pi
        if P.hip_above_seat is not None:  # compressed on a hard seat, as ANSUR measures sitting height
            r_thigh = min(r_thigh, P.hip_above_seat + SEAT_SINK)
        out.append(Capsule(f"{p}thigh", f"{p}thigh", (0.0, 0.0, 0.0), (0.0, 0.0, -L["thigh"]), r_thigh))
        r_shank = TAPER["shank"] * G["calf_circumference"] / two_pi
        lift = max(0.0, r_shank + SHANK_FLOOR_GAP - ankle_z)
        out.append(Capsule(f"{p}shank", f"{p}shank", (0.0, 0.0, 0.0), (0.0, 0.0, -L["shank"] + lift), r_shank))
        r_foot = 0.5 * ankle_z
        heel_x = -A.ANKLE_FROM_HEEL * L["foot"]
        z = -ankle_z + r_foot
        out.append(Capsule(f"{p}foot", f"{p}sole", (heel_x + r_foot, 0.0, z), (heel_x + L["foot"] - r_foot, 0.0, z),
                           r_foot))
    return out


def root_height(body: Anthropometry) -> float:
    """Height [m] of the pelvis origin (mid-hip) in the reference posture."""
    return body.ankle_height + body.lengths["shank"] + body.lengths["thigh"]
