"""The generated human against published figures: one JSON line a row, and docs/validation.md's tables.

Rows, each with its source:

* the shipped stature-percentile bodies (p05 women, p50 and p95 men), built from ANSUR II measures (``ansur``) and
  as earlier versions built them (``de_leva``), each dimension measured on the model as the survey measures it
  (:mod:`oracles.bodies.measure`) against ANSUR II's regression of that dimension on stature, with its residual SD
  (Gordon et al. 2014; the regression fitted on the public data the project carries);
* the wrist-to-grip offset against ANSUR II's (hand length - (forearm-hand length - forearm-centre-of-grip length)),
  mean and SD by sex;
* Pheasant's shoulder-grip length (British adults 19-65) for the percentile bodies: the percentile of that sex's
  distribution, and its SD (see :data:`PHEASANT`);
* MIL-STD-1472G's functional and extended functional reach for the 5th-percentile woman and 95th-percentile man
  (see :data:`MIL_STD`);
* the 95th-percentile man's seat position in the car examples' seat (the hip joint, the H-point, behind the heel
  point) against SAE J1517's 95th-percentile line at his H30 (:func:`oracles.bodies.seat.j1517_x95`), within the
  25 mm allowed; the other drivers' positions are printed beside it (J1517's other lines were not read);
* N ANSUR II subjects of each sex drawn at random (``--seed``): bodies built from each subject's record, every
  measured dimension against the subject's own; and bodies built from the 14 dimensions that set reach alone, the
  rest regressed, against the subject's own (how well the regression predicts what was not given).

Verdict: ``within`` when the deviation is within the published scatter (1 SD, or the stated tolerance), ``outside``
otherwise; every ``outside`` row is explained in docs/validation.md.

Run: ``.venv/bin/python bench/validation.py [--subjects 20] [--seed 51] [--markdown docs/validation.md]``.
"""

from __future__ import annotations

import argparse
import csv
import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import pinocchio as pin

from oracles.bodies import ansur
from oracles.bodies.anthropometry import BUILT_FROM, stature_at_percentile
from oracles.bodies.body import human_body
from oracles.bodies.measure import MEASURES, measure
from oracles.bodies.measure import _points as measure_points

BODIES = (("female", 5), ("male", 50), ("male", 95))
# The dimensions that set reach: a body built from these alone.
GIVEN = ansur.REACH
CHECKED = ("thumbtipreach", "acromialheight", "sittingheight", "buttockkneelength")  # the subject check
TOLERANCE = 0.015  # [m] p95 of a subject body's errors (a choice; its measurement not found again)
# Dimensions the public files give in tenths of a millimetre (interpupillary breadth: 550-750 there, people's
# 55-75 mm; the files' README names the tenths of a kilogram of weightkg alone).
TENTHS = {"interpupillarybreadth": 10.0}
GRIP = ("handlength", "forearmhandlength", "forearmcenterofgriplength")  # the grip's offset's three lengths
# The survey's public files, every dimension of every subject (the repository's shared data).
PUBLIC = Path(__file__).resolve().parents[2] / "shared" / "data" / "ansur2"
# Shoulder-grip length [mm], "from the acromion to the centre of an object gripped in the hand, with the elbow and
# wrist straight": Pheasant's *Bodyspace* (British adults aged 19-65, dimension 25), as reproduced by A.H.S. Chan's
# *Online Anthropometry* (City University of Hong Kong, Chapter 2, dimension 25; read there, not in the book, whose
# edition the stored page does not name). Men 5th / 50th / 95th percentile 610 / 665 / 715, SD 32; women 555 /
# 600; the stored page ends before the women's 95th percentile and SD, so their SD is taken as (50th - 5th) / 1.645
# = 27 mm (a normal distribution's), marked so. The page's figure of the posture was not seen: the model is measured
# with the arm hanging, as ANSUR II measures its arm lengths (raised forward it is 39 mm shorter: the shoulder
# centre lies 40 mm below the acromion).
# MIL-STD-1472G, Appendix B (DoD 2012), general forces, as quoted by NUREG-0700 Rev. 3, Table 11.4 (read there, not
# in the standard) [mm]: functional reach, "from wall to tip of right index finger, with arm extended horizontal to
# floor, both shoulders against wall", 5th-percentile woman 677, 95th-percentile man 886; extended functional reach,
# "as stated above, except right shoulder extended as ..." (the stored page ends there), 735 and 942. The functional
# reach's figures are ANSUR II's thumb-tip reach (the thumb tip against the index finger) at those percentiles:
# 674.2 and 886.0 mm in the carried data. So the model's thumb tip (right_pinch) is measured, the arm horizontal at
# shoulder height; for the extended reach the right shoulder girdle and the arm's direction are free, the hand kept
# at that height (the end of the definition was not read: the trunk is not turned). The table gives no SD: the scatter
# is ANSUR II's SD of the sex's thumb-tip reach.
MIL_STD = {("female", 5): (677.0, 735.0), ("male", 95): (886.0, 942.0)}
EXTENDED = ("right_clavicle_elevation", "right_clavicle_protraction", "right_shoulder_flexion",
            "right_shoulder_abduction", "right_shoulder_rotation")
PHEASANT = {("male", 50): (665.0, 32.0, "SD read"), ("male", 95): (715.0, 32.0, "SD read"),
            ("female", 5): (555.0, 27.4, "SD derived from the 5th and 50th percentiles")}


def grip_offsets(sex: str) -> np.ndarray:
    s = ansur.sample(sex)  # type: ignore[arg-type]
    return s.column("handlength") - (s.column("forearmhandlength") - s.column("forearmcenterofgriplength"))


def percentile_rows() -> list[dict]:
    rows = []
    for sex, pct in BODIES:
        stature = stature_at_percentile(sex, pct)  # type: ignore[arg-type]
        expected, spread = ansur.sample(sex).predict({"stature": stature})  # type: ignore[arg-type]
        built = {p: measure(human_body(sex, percentile=pct, proportions=p)) for p in ("de_leva", "ansur")}
        for name in MEASURES:
            if name in ("stature", "grip") or name not in expected:  # (the dimensions the carried data hold)
                continue
            row = {"table": "percentile", "body": f"{sex} p{pct:g}", "dimension": name,
                   "published_mm": round(1000 * expected[name], 1), "sd_mm": round(1000 * spread[name], 1),
                   "source": "ANSUR II (Gordon et al. 2014): regression on stature, residual SD"}
            for p, m in built.items():
                if name in m:
                    dev = 1000 * (m[name] - expected[name])
                    row[f"{p}_mm"] = round(1000 * m[name], 1)
                    row[f"{p}_dev_mm"] = round(dev, 1)
                    row[f"{p}_verdict"] = "within" if abs(dev) <= 1000 * spread[name] else "outside"
            rows.append(row)
        offsets = grip_offsets(sex)
        m = built["ansur"]["grip"]
        dev = 1000 * (m - offsets.mean())
        old = human_body(sex, percentile=pct, proportions="de_leva").anthropometry
        old_grip = 1.40 * old.lengths["hand"]  # the de_leva hand frame's distance along the hand
        rows.append({"table": "percentile", "body": f"{sex} p{pct:g}", "dimension": "grip",
                     "published_mm": round(1000 * offsets.mean(), 1), "sd_mm": round(1000 * offsets.std(), 1),
                     "source": "ANSUR II: hand length - (forearm-hand length - forearm-centre-of-grip length), "
                               "sex's mean and SD",
                     "de_leva_mm": round(1000 * old_grip, 1),
                     "de_leva_dev_mm": round(1000 * (old_grip - offsets.mean()), 1),
                     "de_leva_verdict": "within" if abs(old_grip - offsets.mean()) <= offsets.std() else "outside",
                     "ansur_mm": round(1000 * m, 1), "ansur_dev_mm": round(dev, 1),
                     "ansur_verdict": "within" if abs(dev) <= 1000 * offsets.std() else "outside"})
    return rows


def pheasant_rows() -> list[dict]:
    """The percentile bodies' shoulder-grip length (acromion to grip centre, the arm hanging straight) against
    Pheasant's British adults at the same percentile of their sex."""
    rows = []
    for (sex, pct), (published, sd, note) in PHEASANT.items():
        body = human_body(sex, percentile=pct)
        data = body.model.createData()
        pin.framesForwardKinematics(body.model, data, body.q_ref)
        acromion, grip = (data.oMf[body.frame_id(n)].translation for n in ("right_acromion", "right_grip"))
        m = 1000 * float(acromion[2] - grip[2])  # along the hanging arm, as a length is taken from the acromion's tip
        rows.append({"table": "percentile", "body": f"{sex} p{pct:g}", "dimension": "shouldergriplength",
                     "published_mm": published, "sd_mm": sd, "ansur_mm": round(m, 1),
                     "ansur_dev_mm": round(m - published, 1),
                     "ansur_verdict": "within" if abs(m - published) <= sd else "outside",
                     "source": "Pheasant (Bodyspace), British adults 19-65, dimension 25, via "
                               f"Chan's Online Anthropometry (CityU); {note}"})
    return rows


def extended_reach(body) -> tuple[float, float]:  # noqa: ANN001
    """Thumb-tip reach from the wall behind the shoulders [m], the arm horizontal forward; and the farthest with the
    right shoulder girdle and the arm's direction free, the thumb tip kept at that height (scipy's SLSQP)."""
    from scipy.optimize import minimize

    straight = measure_points(body, right_shoulder_flexion=np.pi / 2)
    wall, height = straight["back"][0], straight["right_pinch"][2]
    limits = {n: (lo, hi) for n, lo, hi in body.limits()}
    data, fid = body.model.createData(), body.frame_id("right_pinch")

    def tip(x: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(body.model, data, body.configuration(dict(zip(EXTENDED, map(float, x),
                                                                                   strict=True))))
        return np.asarray(data.oMf[fid].translation)

    best = minimize(lambda x: -tip(x)[0], np.array([0.0, 0.0, np.pi / 2, 0.0, 0.0]),
                    bounds=[limits[n] for n in EXTENDED], method="SLSQP",
                    constraints=[{"type": "eq", "fun": lambda x: tip(x)[2] - height}])
    return float(straight["right_pinch"][0] - wall), float(tip(best.x)[0] - wall)


def mil_std_rows() -> list[dict]:
    """The 5th-percentile woman's and the 95th-percentile man's functional and extended functional reach."""
    rows = []
    for (sex, pct), published in MIL_STD.items():
        sd = 1000 * float(ansur.sample(sex).column("thumbtipreach").std())  # type: ignore[arg-type]
        for name, pub, m in zip(("functionalreach", "extendedfunctionalreach"), published,
                                extended_reach(human_body(sex, percentile=pct)), strict=True):
            dev = 1000 * m - pub
            rows.append({"table": "percentile", "body": f"{sex} p{pct:g}", "dimension": name, "published_mm": pub,
                         "sd_mm": round(sd, 1), "ansur_mm": round(1000 * m, 1), "ansur_dev_mm": round(dev, 1),
                         "ansur_verdict": "within" if abs(dev) <= sd else "outside",
                         "source": "MIL-STD-1472G Appendix B (general forces) via NUREG-0700 Rev. 3 Table 11.4; SD: "
                                   "ANSUR II thumb-tip reach"})
    return rows


def seat_rows() -> list[dict]:
    """The drivers' H-points behind the heel point in the car seat; the 95th-percentile man's against J1517."""
    from oracles.bodies.body import load_body
    from oracles.bodies.seat import j1517_x95

    rows = []
    for sex, pct in BODIES:
        body = load_body({"human": {"sex": sex, "percentile": pct, "posture": "seated", "seat": {"kind": "car"}}})
        f = body.frame_positions(body.q_ref, ["right_hip_flexion", "right_heel"])
        hip, heel = f["right_hip_flexion"], f["right_heel"]
        behind, h30 = 1000 * float(heel[0] - hip[0]), float(hip[2] - heel[2])
        row = {"table": "percentile", "body": f"{sex} p{pct:g}", "dimension": "seat_hpoint_behind_ahp",
               "ansur_mm": round(behind, 1), "h30_mm": round(1000 * h30, 1)}
        if (sex, pct) == ("male", 95):
            published = 1000 * j1517_x95(h30)
            row.update(published_mm=round(published, 1), sd_mm=25.0, ansur_dev_mm=round(behind - published, 1),
                       ansur_verdict="within" if abs(behind - published) <= 25.0 else "outside",
                       source="SAE J1517 Class A 95th-percentile seat position line at the body's H30 (equations via "
                              "a public packaging script, a secondary source); tolerance: 25 mm")
        else:
            row.update(published_mm="-", sd_mm="-", ansur_dev_mm="-", ansur_verdict="-",
                       source="J1517's other percentile lines and J4004's stature model not read: no figure")
        rows.append(row)
    return rows


@lru_cache(maxsize=2)
def records(sex: str) -> dict[int, dict[str, float]]:
    """Every subject's whole ANSUR II record [m] by id, from the public files beside the repository (``PUBLIC``):
    the carried data hold the dimensions bodies are built from, not all those a body can be measured on."""
    rows: dict[int, dict[str, float]] = {}
    with open(PUBLIC / f"ANSUR_II_{sex.upper()}_Public.csv", newline="", encoding="latin-1") as f:
        for row in csv.DictReader(f):
            # (the men's file names its id column subjectid, the women's SubjectId)
            rows[int(row.get("subjectid") or row["SubjectId"])] = {
                k: float(row[k]) / (1000.0 * TENTHS.get(k, 1.0)) for k in (*MEASURES, *GRIP) if k != "grip"}
    for r in rows.values():  # the grip's offset (see grip_offsets)
        r["grip"] = r["handlength"] - (r.pop("forearmhandlength") - r.pop("forearmcenterofgriplength"))
    return rows


def stature_lines(rows: dict[int, dict[str, float]]) -> dict[str, tuple[float, float, float]]:
    """Each dimension's least-squares line on stature over the whole sex (slope, intercept, residual SD) [m]."""
    stature = np.array([r["stature"] for r in rows.values()])
    out = {}
    for name in next(iter(rows.values())):
        y = np.array([r[name] for r in rows.values()])
        slope, intercept = np.polyfit(stature, y, 1)
        out[name] = (float(slope), float(intercept), float(np.std(y - (slope * stature + intercept), ddof=2)))
    return out


def subject_rows(count: int, seed: int) -> list[dict]:
    """``count`` subjects of each sex drawn with ``seed``: each one's body built from the whole record and from the
    14 reach dimensions alone, every measured dimension against the subject's record and a line on stature."""
    rng = np.random.default_rng(seed)
    rows = []
    for sex in ("female", "male"):
        s = ansur.sample(sex)  # type: ignore[arg-type]
        record = records(sex)
        lines = stature_lines(record)
        for subject in rng.choice(s.ids, size=count, replace=False):
            own = record[int(subject)]
            whole = measure(human_body(ansur={"sex": sex, "subject": int(subject)}))
            carried = s.subject(int(subject))
            given = {k: carried[k] for k in GIVEN}
            dims = {k: v for k, v in given.items() if k not in ("stature", "weightkg")}
            partial = measure(human_body(sex, stature=given["stature"], mass=given["weightkg"], dims=dims))
            for name, value in whole.items():
                if name not in own:
                    continue
                slope, intercept, _ = lines[name]
                rows.append({"table": "subject", "sex": sex, "subject": int(subject), "dimension": name,
                             "own_mm": round(1000 * own[name], 1),
                             "record_err_mm": round(1000 * (value - own[name]), 2),
                             "given14_err_mm": round(1000 * (partial[name] - own[name]), 2),
                             "line_err_mm": round(1000 * (slope * own["stature"] + intercept - own[name]), 2)})
    return rows


def summary(rows: list[dict]) -> list[dict]:
    """Per sex and dimension: the model's error (mean, SD, p95 of |error|) beside the stature line's, and item 2's
    verdict for a dimension no body is built from (``meets``: p95 at most the line's, the mean within a third of the
    line's residual SD)."""
    out = []
    for sex in ("female", "male"):
        lines = stature_lines(records(sex))
        for name in MEASURES:
            errs = [r for r in rows if r["sex"] == sex and r["dimension"] == name]
            if not errs:
                continue
            model = np.array([r["record_err_mm"] for r in errs])
            line = np.array([r["line_err_mm"] for r in errs])
            part = np.abs([r["given14_err_mm"] for r in errs])
            sd_line = 1000 * lines[name][2]
            p95, p95_line = float(np.percentile(np.abs(model), 95)), float(np.percentile(np.abs(line), 95))
            if name in BUILT_FROM:
                verdict = ("within" if p95 <= 1000 * TOLERANCE else "outside") if name in CHECKED else "input"
            else:
                verdict = "meets" if p95 <= p95_line and abs(model.mean()) <= sd_line / 3 else "misses"
            out.append({"table": "subjects", "sex": sex, "dimension": name, "n": len(errs),
                        "input": name in BUILT_FROM,
                        "mean_mm": round(float(model.mean()), 1), "sd_mm": round(float(model.std()), 1),
                        "p95_mm": round(p95, 1), "line_mean_mm": round(float(line.mean()), 1),
                        "line_sd_mm": round(sd_line, 1), "line_p95_mm": round(p95_line, 1),
                        "given14_p95_mm": round(float(np.percentile(part, 95)), 1), "verdict": verdict})
    return out


def _signed(value: object) -> str:
    return f"{value:+}" if isinstance(value, int | float) else str(value)


def markdown(percentile: list[dict], subjects: list[dict], count: int, seed: int) -> str:
    lines = ["| body | dimension | published [mm] | SD [mm] | de_leva (before) [mm] | dev | verdict | ansur (now) "
             "[mm] | dev | verdict |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in percentile:
        before = (f"{r['de_leva_mm']} | {r['de_leva_dev_mm']:+} | {r['de_leva_verdict']}" if "de_leva_mm" in r
                  else "no such frame | - | -")
        lines.append(f"| {r['body']} | `{r['dimension']}` | {r['published_mm']} | {r['sd_mm']} | {before} | "
                     f"{r['ansur_mm']} | {_signed(r['ansur_dev_mm'])} | {r['ansur_verdict']} |")
    lines += ["", f"{count} subjects of each sex drawn with seed {seed}, each body built from the subject's whole "
              "record: model minus record [mm], its mean, SD and p95 of |error|; beside it a line on stature alone, "
              "fitted over the whole sex (its mean, residual SD and p95), and the p95 of a body built from the 14 "
              "dimensions that set reach alone (the rest regressed). `input`: a dimension the body is built from "
              f"(within {1000 * TOLERANCE:g} mm checked for {', '.join(CHECKED)}); otherwise `meets` when the model's "
              "p95 is at most the line's and its mean within a third of the line's residual SD.", "",
              "| sex | dimension | model: mean / SD / p95 | stature line: mean / SD / p95 | the 14 given: p95 "
              "| verdict |",
              "| --- | --- | --- | --- | --- | --- |"]
    for r in subjects:
        lines.append(f"| {r['sex']} | `{r['dimension']}` | {r['mean_mm']:+} / {r['sd_mm']} / {r['p95_mm']} | "
                     f"{r['line_mean_mm']:+} / {r['line_sd_mm']} / {r['line_p95_mm']} | {r['given14_p95_mm']} | "
                     f"{r['verdict']} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", type=int, default=200, help="subjects of each sex drawn from ANSUR II")
    parser.add_argument("--seed", type=int, default=51)
    parser.add_argument("--markdown", type=Path, help="write the tables to this file's generated section")
    args = parser.parse_args()
    percentile = percentile_rows() + pheasant_rows() + mil_std_rows() + seat_rows()
    subjects = subject_rows(args.subjects, args.seed)
    summaries = summary(subjects)
    for row in percentile + summaries:
        print(json.dumps(row))
    if args.markdown:
        begin = "<!-- generated by bench/validation.py: begin -->"
        end = "<!-- generated by bench/validation.py: end -->"
        text = args.markdown.read_text() if args.markdown.exists() else f"{begin}\n{end}\n"
        head, rest = text.split(begin, 1)
        tail = rest.split(end, 1)[1]
        args.markdown.write_text(f"{head}{begin}\n{markdown(percentile, summaries, args.subjects, args.seed)}{end}"
                                 f"{tail}")


if __name__ == "__main__":
    main()
